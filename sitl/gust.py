"""Gusty flow like the paper's wind tunnel: airspeed fluctuation and warp buffeting.

The paper put the wing 600 mm behind a bluff body in 7 and 12 m/s flow; the
body shed vortices at about 110 Hz (CFD, 7 m/s) and the membrane "oscillated
vigorously". The paper cites turbulence intensities of 34-38 % in tropical
thunderstorms and calls its tunnel flow at least as severe, so the default
intensity is 0.3. Here the airspeed at the wing is::

    V(t) = V_mean (1 + I n(t)),   n = sqrt(s) n_shed + sqrt(1 - s) n_broad

with unit-variance parts: ``n_shed`` narrow-band around the shedding frequency
(it scales with V at fixed Strouhal number, ``shedding_hz(V)``), ``n_broad`` a
Dryden-like low-pass spectrum with corner ``V / (2 pi L)`` for a wake length
scale L. ``wind(t)`` is that airspeed, what a hot-wire at the wing reads. The
wing's load cannot follow it at once: unsteady aerodynamics attenuates a gust's
lift by the Sears function, here in Liepmann's approximation
``|S(k)|^2 = 1 / (1 + 2 pi k)`` at reduced frequency ``k = pi f c / V`` (chord c
0.19 m, the paper's wing). ``airspeed(t)`` is the wind with every component so
attenuated: the airspeed the load follows, handed to the plant's ``aero_load``
effect as q = rho V^2 / 2. Besides, the membrane buffets: a warp
disturbance of the same two-part spectrum (own seeded phases) with RMS
``buffet_deg_per_kpa * q_mean`` deg (0.09 deg at 12 m/s by default), added to
the true warp (the sensor sees it too).

Both are sums of seeded random-phase sinusoids, so they can be evaluated at any
time (array or scalar), are reproducible, and need no state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from warpbridge.model.effects import dynamic_pressure_kpa

PAPER_SHEDDING_HZ = 110.0  # at the paper's 7 m/s
PAPER_SHEDDING_AT_MS = 7.0


def shedding_hz(airspeed_ms: float) -> float:
    """Vortex shedding frequency behind the paper's bluff body at this speed (fixed Strouhal)."""
    return PAPER_SHEDDING_HZ * airspeed_ms / PAPER_SHEDDING_AT_MS


@dataclass(frozen=True)
class GustSpec:
    """Gusty flow at one mean speed; see the module docstring for the model."""

    mean_ms: float
    intensity: float = 0.3
    shedding_hz: float | None = None  # None = from mean_ms at the paper's Strouhal number
    shedding_share: float = 0.5  # fraction of the fluctuation variance in the shedding band
    shedding_width_hz: float = 4.0  # spread of the shedding frequency (1 sigma)
    length_scale_m: float = 0.15  # wake turbulence length scale (bluff body size)
    buffet_deg_per_kpa: float = 1.0
    chord_m: float = 0.19
    seed: int = 0

    def __post_init__(self) -> None:
        if self.mean_ms < 0 or self.intensity < 0 or not 0 <= self.shedding_share <= 1:
            raise ValueError("gust needs mean speed >= 0, intensity >= 0 and shedding share in [0, 1]")

    @property
    def f_shed(self) -> float:
        return shedding_hz(self.mean_ms) if self.shedding_hz is None else self.shedding_hz


class Gust:
    """A seeded realisation of ``GustSpec``: ``airspeed(t)``, ``buffet_deg(t)``."""

    N_SHED = 24
    N_BROAD = 160

    def __init__(self, spec: GustSpec) -> None:
        self.spec = spec
        rng = np.random.default_rng(spec.seed)
        # narrow band: frequencies spread around the shedding frequency, equal power
        fs = np.abs(rng.normal(spec.f_shed, spec.shedding_width_hz, self.N_SHED))
        a_s = np.full(self.N_SHED, math.sqrt(2.0 / self.N_SHED))
        # broad band: log-spaced frequencies with Dryden weights, normalised to unit variance
        fb = np.geomspace(0.05, 60.0, self.N_BROAD) * np.exp(rng.uniform(-0.02, 0.02, self.N_BROAD))
        fc = max(spec.mean_ms, 0.1) / (2 * math.pi * spec.length_scale_m)
        df = np.gradient(fb)
        psd = 1.0 / (1.0 + (fb / fc) ** 2)
        a_b = np.sqrt(2.0 * psd * df / np.sum(psd * df))
        share = spec.shedding_share
        self._f = np.concatenate([fs, fb])
        self._a = np.concatenate([math.sqrt(share) * a_s, math.sqrt(1.0 - share) * a_b])
        self._phi = rng.uniform(0.0, 2 * math.pi, self._f.size)
        self._phi_buffet = rng.uniform(0.0, 2 * math.pi, self._f.size)
        self._q_mean = float(dynamic_pressure_kpa(spec.mean_ms))
        k = math.pi * self._f * spec.chord_m / max(spec.mean_ms, 0.1)
        self._sears = 1.0 / np.sqrt(1.0 + 2 * math.pi * k)

    def fluctuation(self, t, phases=None, gains=None):
        """n(t): the unit-variance normalised airspeed fluctuation (array or float)."""
        tt = np.asarray(t, dtype=np.float64)
        arg = 2 * math.pi * np.multiply.outer(tt, self._f) + (self._phi if phases is None else phases)
        return np.sin(arg) @ (self._a if gains is None else self._a * gains)

    def wind(self, t):
        """Airspeed at the wing (m/s) as a hot-wire reads it, never negative."""
        v = self.spec.mean_ms * (1.0 + self.spec.intensity * self.fluctuation(t))
        return np.maximum(v, 0.0)

    def airspeed(self, t):
        """The airspeed the wing's load follows (m/s): the wind through the Sears attenuation."""
        v = self.spec.mean_ms * (1.0 + self.spec.intensity * self.fluctuation(t, gains=self._sears))
        return np.maximum(v, 0.0)

    def buffet_deg(self, t, airspeed=None):
        """Warp disturbance (deg) of the buffeting membrane (``airspeed`` is not needed)."""
        return self.spec.buffet_deg_per_kpa * self._q_mean * self.fluctuation(t, self._phi_buffet)
