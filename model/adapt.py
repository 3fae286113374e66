"""Online estimation of the tendon's pre-tension (offset, gain) and the warp sensor's zero drift.

The wing is modelled as the Bouc-Wen map behind a command-side rigging
(``model.effects.fold_rigging``) plus a sensor zero error::

    w_meas = F(gain * (u - offset)) + drift

where F is the forward Bouc-Wen map of the controller's model and u the tendon
command actually sent. The feed-forward compensates the estimate exactly by
transforming the inverse model's output, ``u_cmd = offset + u_ff / gain``
(``PretensionEstimator.apply``), and the PI sees ``w_meas - drift``.

``PretensionEstimator.update`` runs once per control cycle. It advances the
forward model with the current estimates and two shadow copies whose input is
shifted (offset) or scaled (gain) by a small step: their difference is the exact
sensitivity of the predicted warp to each parameter along the path actually
flown, hysteresis memory included (a local slope would be wrong in the dead
zones after a reversal). The residual between measured and predicted warp is
regressed on those sensitivities (and on 1 for the drift) with exponential
forgetting; every ``update_s`` the estimate takes a Gauss-Newton step restricted
to the directions the window actually excites (eigenvalues of the information
matrix above ``pe_min``: a persistence-of-excitation test per direction), limited
in rate and projected onto the bounds. It freezes (keeps its estimates) while
the sensor is unhealthy, while no direction is excited, and while the residual
is beyond ``gate_deg`` (a sensor fault or a change the bounds cannot explain).

Identifiability: with one-sided warp an input offset and a sensor zero shift
differ only through the curvature of the model (a1) and the gain through the
spread of u, so drift estimation is off by default and needs wide excitation;
the PE test keeps an unexcited combination where it is. The model sees the
command through a first-order lag (``input_tau_s``, the servo's): fed the raw
command, the PI's noise-driven jitter would make every sample a tiny reversal
and bias the prediction.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from warpbridge.model import _jit
from warpbridge.model import kernels as K
from warpbridge.model.boucwen import BoucWenParams, rest_warp
from warpbridge.model.effects import fold_rigging

SHIFT_MM = 0.05  # input shift of the offset shadow model
SCALE = 0.01  # relative input scaling of the gain shadow model
PARAM_SCALE = (1.0, 0.1, 1.0)  # natural units of (offset mm, gain, drift deg) for the PE test


class AdaptState(enum.IntEnum):
    """What the estimator did on the last update (also its telemetry code)."""

    OFF = 0  # switched off: estimates held (or returning to neutral)
    ADAPTING = 1  # at least one direction excited: estimates moving
    POOR_EXCITATION = 2  # nothing excited enough to tell: frozen
    SENSOR = 3  # sensor missing or unhealthy: frozen
    RESIDUAL = 4  # residual beyond the gate for too long: frozen (fault or out of bounds)


@dataclass(frozen=True)
class AdaptConfig:
    """Bounds and speeds of the estimator (mm, deg, s)."""

    max_offset_mm: float = 2.0  # |offset| <= this
    max_gain_dev: float = 0.25  # gain in [1 / (1 + m), 1 + m]
    max_drift_deg: float = 1.0  # |drift| <= this
    rate_mm_s: float = 0.02  # offset moves at most this fast
    rate_gain_s: float = 0.004  # gain moves at most this fast (per s)
    rate_drift_deg_s: float = 0.01
    tau_s: float = 20.0  # forgetting time constant of the regression window
    update_s: float = 0.5  # how often the estimate steps
    estimate_drift: bool = False  # also estimate the sensor's zero drift
    pe_min: float = 0.02  # least regressor power (deg^2 per natural unit^2) of an excited direction
    min_window_s: float = 5.0  # no step before this much data is in the window
    gate_deg: float = 2.0  # a residual beyond this is not used
    fault_s: float = 1.0  # gated this long in a row -> RESIDUAL state
    step_frac: float = 0.5  # fraction of the Gauss-Newton step taken per update
    input_tau_s: float = 0.03  # the servo's lag: the model sees the command through it (PI jitter filtered)

    def __post_init__(self) -> None:
        for name in ("max_offset_mm", "max_gain_dev", "max_drift_deg", "rate_mm_s", "rate_gain_s",
                     "rate_drift_deg_s", "pe_min", "min_window_s", "input_tau_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a finite number >= 0")
        for name in ("tau_s", "update_s", "gate_deg", "fault_s", "step_frac"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be positive")

    @property
    def gain_bounds(self) -> tuple[float, float]:
        return 1.0 / (1.0 + self.max_gain_dev), 1.0 + self.max_gain_dev


@dataclass(frozen=True)
class Estimate:
    """Pre-tension offset (mm), gain and sensor zero drift (deg), and the estimator's state."""

    offset: float = 0.0
    gain: float = 1.0
    drift: float = 0.0
    state: AdaptState = AdaptState.OFF
    residual_rms: float = math.nan  # over the window, deg
    excited: int = 0  # number of excited directions at the last step

    def apply(self, u_ff: float) -> float:
        """Tendon command compensating the pre-tension for the model's u_ff (mm)."""
        return self.offset + u_ff / self.gain


class PretensionEstimator:
    """Slow, bounded estimator of pre-tension and sensor drift; see the module docstring."""

    def __init__(self, params: BoucWenParams, config: AdaptConfig | None = None, *, u0: float | None = None,
                 offset: float = 0.0, gain: float = 1.0, drift: float = 0.0) -> None:
        self.config = config or AdaptConfig()
        self.enabled = True
        self._p = _jit.vector(params.to_array())
        self.params = params
        self._theta = np.array([offset, gain, drift], dtype=np.float64)
        self._project()
        self._u_last = u0
        self._started = False
        self._reset_window()
        self.state = AdaptState.ADAPTING
        self._gated_s = 0.0
        self._since_step = 0.0
        self._excited = 0

    # ------------------------------------------------------------------ set-up

    def _reset_window(self) -> None:
        self._R = np.zeros((3, 3))
        self._b = np.zeros(3)
        self._n = 0.0
        self._ee = 0.0
        self._window_s = 0.0  # seconds of data in the window (exponentially weighted)

    def set_config(self, config: AdaptConfig) -> None:
        """New bounds/speeds; the estimate is projected onto the new bounds."""
        self.config = config
        if not config.estimate_drift:
            self._theta[2] = 0.0
        self._project()

    def set_model(self, params: BoucWenParams) -> None:
        """A new base model (e.g. after calibration): estimates back to neutral, window cleared."""
        self._p = _jit.vector(params.to_array())
        self.params = params
        self._theta[:] = (0.0, 1.0, 0.0)
        self._started = False
        self._reset_window()

    def set_estimate(self, offset: float | None = None, gain: float | None = None,
                     drift: float | None = None) -> None:
        """Overwrite estimates (e.g. from a parameter); projected onto the bounds, window cleared."""
        for i, v in enumerate((offset, gain, drift)):
            if v is not None:
                if not math.isfinite(v):
                    raise ValueError("estimates must be finite")
                self._theta[i] = float(v)
        self._project()
        self._reset_window()

    def relax(self, dt: float) -> None:
        """Move the estimates towards neutral (0, 1, 0) at the rate limits (used while switched off)."""
        c = self.config
        target = np.array([0.0, 1.0, 0.0])
        rates = np.array([c.rate_mm_s, c.rate_gain_s, c.rate_drift_deg_s]) * max(dt, 0.0)
        self._theta += np.clip(target - self._theta, -rates, rates)

    def _project(self) -> None:
        c = self.config
        lo, hi = c.gain_bounds
        self._theta[0] = min(max(self._theta[0], -c.max_offset_mm), c.max_offset_mm)
        self._theta[1] = min(max(self._theta[1], lo), hi)
        d = c.max_drift_deg if c.estimate_drift else 0.0
        self._theta[2] = min(max(self._theta[2], -d), d)

    # ------------------------------------------------------------------ the estimate

    @property
    def estimate(self) -> Estimate:
        o, g, d = (float(x) for x in self._theta)
        rms = math.sqrt(self._ee / self._n) if self._n > 0 else math.nan
        return Estimate(o, g, d, self.state, rms, self._excited)

    def apply(self, u_ff: float) -> float:
        """``offset + u_ff / gain``: the command that makes the rigged wing do what the model's u_ff would."""
        return float(self._theta[0] + u_ff / self._theta[1])

    def _start(self, u: float) -> None:
        o, g, _ = self._theta
        x = g * (u - o)
        w = rest_warp(self.params, x)
        self._wm = self._wo = self._wg = w
        self._zm = self._zo = self._zg = 0.0
        self._started = True

    def predict(self) -> float:
        """Predicted measured warp (deg) after the last update."""
        return self._wm + self._theta[2] if self._started else math.nan

    def update(self, u: float, measured: float | None, dt: float, *, healthy: bool = True) -> Estimate:
        """One control cycle: ``u`` the tendon command sent (mm), ``measured`` warp (deg) or None."""
        if not math.isfinite(u):
            return self.estimate
        if not self._started:
            self._start(u)
            self._uf = u
        a = math.exp(-max(dt, 0.0) / self.config.input_tau_s) if self.config.input_tau_s > 0 else 0.0
        self._uf = u = a * self._uf + (1.0 - a) * u
        o, g, d = (float(v) for v in self._theta)
        x = g * (u - o)
        p = self._p
        wm, zm, _ = K.forward_step(p, self._wm, self._zm, x)
        wo, zo, _ = K.forward_step(p, self._wo, self._zo, x + SHIFT_MM)
        wg, zg, _ = K.forward_step(p, self._wg, self._zg, x * (1.0 + SCALE))
        self._wm, self._zm, self._wo, self._zo, self._wg, self._zg = wm, zm, wo, zo, wg, zg
        if not self.enabled:
            self.state = AdaptState.OFF
            return self.estimate
        if measured is None or not math.isfinite(measured) or not healthy:
            self.state = AdaptState.SENSOR
            return self.estimate
        c = self.config
        e = measured - (wm + d)
        if abs(e) > c.gate_deg:
            self._gated_s += dt
            if self._gated_s >= c.fault_s:
                self.state = AdaptState.RESIDUAL
            return self.estimate
        self._gated_s = 0.0
        if self.state == AdaptState.RESIDUAL:  # the residual is back: start a fresh window
            self._reset_window()
            self.state = AdaptState.POOR_EXCITATION
        s_o = -g * (wo - wm) / SHIFT_MM
        s_g = (wg - wm) / (SCALE * g)
        phi = np.array([s_o * PARAM_SCALE[0], s_g * PARAM_SCALE[1], PARAM_SCALE[2] if c.estimate_drift else 0.0])
        lam = math.exp(-max(dt, 0.0) / c.tau_s)
        self._R = lam * self._R + np.outer(phi, phi)
        self._b = lam * self._b + phi * e
        self._n = lam * self._n + 1.0
        self._window_s = lam * self._window_s + dt
        self._ee = lam * self._ee + e * e
        self._since_step += dt
        if self._since_step >= c.update_s:
            self._step(self._since_step)
            self._since_step = 0.0
        return self.estimate

    def _step(self, elapsed: float) -> None:
        c = self.config
        if self._window_s < min(c.min_window_s, 0.5 * c.tau_s):
            self.state = AdaptState.POOR_EXCITATION
            self._excited = 0
            return
        M = self._R / self._n
        mu, V = np.linalg.eigh(M)
        keep = mu >= c.pe_min
        self._excited = int(keep.sum())
        if not keep.any():
            self.state = AdaptState.POOR_EXCITATION
            return
        coef = (V[:, keep].T @ self._b) / (mu[keep] * self._n)
        step = c.step_frac * (V[:, keep] @ coef)  # scaled units
        delta = step * np.array(PARAM_SCALE)
        rates = np.array([c.rate_mm_s, c.rate_gain_s, c.rate_drift_deg_s]) * elapsed
        if not c.estimate_drift:
            delta[2] = 0.0
        over = np.max(np.abs(delta) / np.maximum(rates, 1e-12))
        if over > 1.0:  # rate limit: shorten the step, keep its direction
            delta /= over
        old = self._theta.copy()
        self._theta += delta
        self._project()
        applied = (self._theta - old) / np.array(PARAM_SCALE)
        self._b -= self._R @ applied  # the window's residuals as if they had been made with the new estimate
        self.state = AdaptState.ADAPTING


def fold_pretension(params: BoucWenParams, offset: float, gain: float, az_scale: float = 1.0) -> BoucWenParams:
    """The Bouc-Wen parameters of the rigged wing ``u = offset + f(w) / gain`` (hysteresis width scaled by
    ``az_scale`` about its middle); see ``model.effects.fold_rigging``."""
    return fold_rigging(params, offset, gain, az_scale)
