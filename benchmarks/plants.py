"""Plants for the blind diagnosis benchmark: Bouc-Wen away from the paper's, and two other structures.

Every plant maps a tendon command u(t) (mm) and airspeed (m/s) to measured warp
(deg) through the same effect operators as ``model.plant.Plant`` (input side:
delay, rate limit, backlash, pre-tension; output side: aero load, sensor lag,
drift), around a hysteretic core that differs per plant:

- ``BoucWenPlant``: the generalized Bouc-Wen forward map with parameters drawn
  around the paper's (friction scales az, as in ``Plant``).
- ``PrandtlIshlinskiiPlant``: a weighted sum of play operators with a quadratic
  output, w = c0 + c1 y + c2 y^2, y = sum_i p_i play_{r_i}(u) (friction scales
  the play radii).
- ``DahlPlant``: a rate-independent Dahl friction element in series with a
  stiffening spring, w = c0 + k (u - h) + k2 (u - h)^2, dh/du = (1 - h/hc sgn(du))^a
  (friction scales hc).

``draw_plants(seed)`` returns a list of them; ``magnitude_for`` finds the effect
size that changes the warp by a given RMS on a given log.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numba import njit

from warpbridge.model.boucwen import BoucWenParams, forward, inverse
from warpbridge.model.effects import EFFECT_FIELDS, Effects, apply_input_effects, apply_output_effects


class BenchPlant:
    """Common interface: ``simulate(t, u, airspeed, effects) -> (w_true, w_meas)`` and the tendon span."""

    name: str = "plant"
    u_lo: float
    u_hi: float

    def core(self, x: np.ndarray, friction_scale: float) -> np.ndarray:
        raise NotImplementedError

    def simulate(self, t, u, airspeed, effects: Effects) -> tuple[np.ndarray, np.ndarray]:
        t = np.ascontiguousarray(t, dtype=np.float64)
        x = apply_input_effects(effects, t, np.ascontiguousarray(u, dtype=np.float64))
        w = self.core(x, effects.friction_scale)
        return apply_output_effects(effects, t, w, airspeed)


@dataclass
class BoucWenPlant(BenchPlant):
    params: BoucWenParams
    u_lo: float = 0.0
    u_hi: float = 1.0
    name: str = "bouc-wen"

    def core(self, x, friction_scale):
        p = self.params if friction_scale == 1.0 else replace(self.params, az=self.params.az * friction_scale)
        w, _, _ = forward(p, x)
        return w


@njit(cache=True)
def _pi_output(u, radii, weights, y0s):
    n = u.shape[0]
    out = np.zeros(n)
    for i in range(radii.shape[0]):
        r = radii[i]
        y = y0s[i]
        for k in range(n):
            if u[k] - r > y:
                y = u[k] - r
            elif u[k] + r < y:
                y = u[k] + r
            out[k] += weights[i] * y
    return out


@dataclass
class PrandtlIshlinskiiPlant(BenchPlant):
    radii: np.ndarray
    weights: np.ndarray
    c: tuple[float, float, float]
    u_lo: float = 0.0
    u_hi: float = 1.0
    name: str = "prandtl-ishlinskii"

    def core(self, x, friction_scale):
        r = self.radii * friction_scale
        y = _pi_output(np.ascontiguousarray(x), r, self.weights, x[0] - r)  # start as if loading
        c0, c1, c2 = self.c
        return c0 + c1 * y + c2 * y * y


@njit(cache=True)
def _dahl(u, hc, a, h0):
    n = u.shape[0]
    out = np.empty(n)
    h = h0
    up = u[0]
    for k in range(n):
        du = u[k] - up
        # sub-steps keep the explicit update accurate for large increments
        m = int(abs(du) / (0.02 * hc)) + 1
        d = du / m
        for _ in range(m):
            s = 1.0 if d > 0 else -1.0
            g = 1.0 - h / hc * s
            if g < 0.0:
                g = 0.0
            h += d * g ** a
        up = u[k]
        out[k] = h
    return out


@dataclass
class DahlPlant(BenchPlant):
    hc: float
    a: float
    k: float
    k2: float
    c0: float
    u_lo: float = 0.0
    u_hi: float = 1.0
    name: str = "dahl"

    def core(self, x, friction_scale):
        hc = self.hc * friction_scale
        h = _dahl(np.ascontiguousarray(x), hc, self.a, -hc)
        e = x - h
        return self.c0 + self.k * e + self.k2 * e * e


def _bw_span(p: BoucWenParams, w_lo: float, w_hi: float) -> tuple[float, float]:
    leg = np.linspace(max(0.0, w_lo - 1.0), w_hi, 200)
    u_leg, _ = inverse(p, np.concatenate([leg, leg[::-1], leg]))
    return float(np.interp(w_lo, leg, u_leg[-leg.size:])), float(u_leg[-1])


def _bw_ok(p: BoucWenParams) -> bool:
    """Saturating, monotone on the working range, a loop of sensible width."""
    try:
        hi, lo = p.z_saturation(1.0)
    except (ValueError, ZeroDivisionError):
        return False
    if not (math.isfinite(hi) and math.isfinite(lo)):
        return False
    width = abs(p.az) * (hi - lo)
    if not 0.2 < width < 3.0:
        return False
    u_lo, u_hi = _bw_span(p, 2.0, 12.0)
    if not u_hi > u_lo + 1.0:
        return False
    t = np.linspace(0, 20, 4000)
    u = 0.5 * (u_lo + u_hi) + 0.5 * (u_hi - u_lo) * np.sin(2 * np.pi * 0.3 * t) * (0.4 + 0.6 * t / 20)
    w, _, flagged = forward(p, u)
    return flagged == 0 and bool(np.all(np.isfinite(w))) and float(np.ptp(w)) > 5.0


def draw_bouc_wen(rng: np.random.Generator) -> BoucWenPlant:
    """Bouc-Wen parameters drawn around the paper's, kept only if the plant is well behaved."""
    base = BoucWenParams.paper().canonical()
    for _ in range(200):
        n = rng.uniform(2.2, 4.0)
        c = rng.uniform(0.5, 1.6)  # overall loop-width scale
        b = tuple(x * rng.uniform(0.8, 1.25) for x in base.b)
        p = BoucWenParams(a1=base.a1 * rng.uniform(0.3, 1.5), a2=base.a2 * rng.uniform(0.75, 1.35),
                          a3=base.a3 + rng.uniform(-0.4, 0.4), az=1.0, A=base.A * rng.uniform(0.6, 1.6), n=n,
                          b=b)
        # keep the saturation level of the paper's loop times c despite the new n
        hi, _ = p.z_saturation(1.0)
        hi0, _ = base.z_saturation(1.0)
        if not (math.isfinite(hi) and hi > 0):
            continue
        s = (c * hi0 / hi) ** (-n)  # z_sat ~ (A / psi)^(1/n): scale psi to move it
        p = replace(p, b=tuple(x * s for x in p.b))
        if _bw_ok(p):
            u_lo, u_hi = _bw_span(p, 2.0, 12.0)
            return BoucWenPlant(p, u_lo, u_hi)
    raise RuntimeError("could not draw a well-behaved Bouc-Wen plant")


def draw_prandtl_ishlinskii(rng: np.random.Generator) -> PrandtlIshlinskiiPlant:
    """Ten play operators with decaying weights and a hardening quadratic output; u spans 0..8 mm."""
    m = 10
    radii = np.linspace(0.0, rng.uniform(0.8, 1.6), m)
    weights = np.exp(-rng.uniform(1.0, 3.0) * np.linspace(0, 1, m))
    weights /= weights.sum()
    u_lo, u_hi = 0.5, 8.0
    # output: warp 2..12 deg over the loading branch, with some curvature
    y_lo, y_hi = u_lo - radii @ weights, u_hi - radii @ weights
    curv = rng.uniform(-0.25, 0.25)
    span = y_hi - y_lo
    c1 = 10.0 / span * (1 - curv)
    c2 = 10.0 / span ** 2 * curv
    c0 = 2.0 - c1 * y_lo - c2 * y_lo ** 2
    if c1 + 2 * c2 * y_lo <= 0 or c1 + 2 * c2 * y_hi <= 0:
        curv = 0.0
        c1, c2 = 10.0 / span, 0.0
        c0 = 2.0 - c1 * y_lo
    return PrandtlIshlinskiiPlant(radii, weights, (float(c0), float(c1), float(c2)), u_lo, u_hi)


def draw_dahl(rng: np.random.Generator) -> DahlPlant:
    """A Dahl friction element (exponent 0.5..2) in series with a stiffening spring; u spans 1..9 mm."""
    hc = rng.uniform(0.3, 0.8)
    a = rng.uniform(0.5, 2.0)
    u_lo, u_hi = 1.0, 9.0
    k2 = rng.uniform(0.0, 0.08)
    e_lo, e_hi = u_lo + hc, u_hi - hc
    k = (10.0 - k2 * (e_hi ** 2 - e_lo ** 2)) / (e_hi - e_lo)
    c0 = 2.0 - k * e_lo - k2 * e_lo ** 2
    return DahlPlant(hc, a, float(k), float(k2), float(c0), u_lo, u_hi)


def draw_plants(seed: int, n_bouc_wen: int = 3) -> list[BenchPlant]:
    """``n_bouc_wen`` Bouc-Wen plants, one Prandtl-Ishlinskii and one Dahl plant."""
    rng = np.random.default_rng(seed)
    plants: list[BenchPlant] = [draw_bouc_wen(rng) for _ in range(n_bouc_wen)]
    plants.append(draw_prandtl_ishlinskii(rng))
    plants.append(draw_dahl(rng))
    for i, p in enumerate(plants):
        p.name = f"{p.name}-{i}"
    return plants


# ---- effect magnitudes -------------------------------------------------------------------------

def effect_of_size(name: str, s: float, shape: tuple[float, float], span: float) -> Effects:
    """Effect ``name`` at size s >= 0 (0 = neutral), with a drawn ``shape`` (sign / mix, in [-1, 1])."""
    a, b = shape
    if name == "delay":
        return Effects(delay_s=0.2 * s)
    if name == "rate_limit":
        return Effects(rate_mm_s=math.inf) if s <= 0 else Effects(rate_mm_s=span * 4.0 / s)
    if name == "backlash":
        return Effects(backlash_mm=0.2 * span * s)
    if name == "friction":
        return Effects(friction_scale=math.exp(math.copysign(s, a)))
    if name == "pretension":
        th = math.pi * a
        return Effects(pretension_offset_mm=0.2 * span * s * math.cos(th),
                       pretension_gain=math.exp(0.5 * s * math.sin(th)))
    if name == "sensor_lag":
        return Effects(sensor_tau_s=0.2 * s)
    if name == "drift":
        return Effects(drift_deg_s=math.copysign(0.05 * s, a))
    if name == "aero_load":
        mix = 0.5 * (b + 1.0)  # share of the proportional part
        return Effects(aero_gain_per_kpa=4.0 * s * mix, aero_deg_per_kpa=40.0 * s * (1.0 - mix))
    raise ValueError(name)


def magnitude_for(plant: BenchPlant, name: str, target_rms: float, shape, t, u, airspeed) -> Effects:
    """The effect whose RMS change of the measured warp on this log is ``target_rms`` (bisection on size)."""
    span = plant.u_hi - plant.u_lo
    _, w0 = plant.simulate(t, u, airspeed, Effects())

    def rms(s):
        eff = effect_of_size(name, s, shape, span)
        _, w1 = plant.simulate(t, u, airspeed, eff)
        v = float(np.sqrt(np.mean((w1 - w0) ** 2)))
        return v if math.isfinite(v) else math.inf

    lo, hi = 0.0, 0.02
    while rms(hi) < target_rms and hi < 50:
        lo, hi = hi, hi * 2
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        if rms(mid) < target_rms:
            lo = mid
        else:
            hi = mid
    return effect_of_size(name, 0.5 * (lo + hi), shape, span)


def describe(eff: Effects) -> str:
    parts = []
    for name in eff.active():
        vals = ":".join(f"{getattr(eff, f):.4g}" for f in EFFECT_FIELDS[name][0])
        parts.append(f"{name}={vals}")
    return ",".join(parts) or "none"


__all__ = ["BenchPlant", "BoucWenPlant", "DahlPlant", "PrandtlIshlinskiiPlant", "describe", "draw_plants",
           "effect_of_size", "magnitude_for"]
