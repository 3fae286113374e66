"""The augmented tendon-sheath plant: Bouc-Wen forward map wrapped in the effects chain.

``Plant.simulate`` runs a whole log (tendon command u(t), optional airspeed)
and returns true and measured warp; ``PlantStepper`` does the same one sample
at a time for lock-step simulation and gives identical results.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from warpbridge.model import kernels as K
from warpbridge.model.boucwen import BoucWenParams, forward, rest_warp
from warpbridge.model.effects import (
    PULLED,
    Effects,
    apply_input_effects,
    apply_output_effects,
    core_params,
    drift_shape,
    dynamic_pressure_kpa,
    servo_move,
    slack_start,
    slack_step,
)
from warpbridge.model.model_error import ErrorModel


@dataclass(frozen=True)
class Plant:
    """A Bouc-Wen tendon-sheath model plus unmodelled effects."""

    params: BoucWenParams
    effects: Effects = field(default_factory=Effects)
    error_model: ErrorModel | None = None  # the bench-learned correction added to the core's warp, if any
    slack_side: float = PULLED  # where the play stands at the first sample (``effects.slack_start``)

    def core_params(self) -> BoucWenParams:
        """Bouc-Wen parameters with pre-tension and friction folded in (``model.effects.core_params``)."""
        return core_params(self.params, self.effects)

    def simulate(self, t, u, airspeed=None, z0: float = 0.0, sent=None) -> tuple[np.ndarray, np.ndarray]:
        """(w_true, w_meas) in deg for tendon command u (mm) sampled at times t (s); ``sent``: when each command
        reached the servo, s after its row (``effects.servo_travel``; None: at the row's time)."""
        t = np.ascontiguousarray(t, dtype=np.float64)
        u = np.ascontiguousarray(u, dtype=np.float64)
        if t.shape != u.shape:
            raise ValueError("t and u must have the same length")
        if t.size == 0:
            return np.empty(0), np.empty(0)
        x = apply_input_effects(self.effects, t, u, self.slack_side, sent)
        w, _, _ = forward(self.core_params(), x, z0=z0)
        if self.error_model is not None:
            w = self.error_model.corrected(t, x, w, self.effects.band_scale)
        return apply_output_effects(self.effects, t, w, airspeed)


class PlantStepper:
    """Per-sample version of ``Plant.simulate`` (same operators, same order)."""

    def __init__(self, plant: Plant, t0: float, u0: float, z0: float = 0.0) -> None:
        if plant.error_model is not None:
            raise ValueError("the per-sample plant does not run a model-error correction (it needs whole-log "
                             "features): simulate the log with Plant.simulate")
        if plant.effects.extra:
            raise ValueError("the per-sample plant runs the built-in effects only; effects added at run time "
                             "act on whole arrays: simulate the log with Plant.simulate")
        self.plant = plant
        self._p = plant.core_params().to_array()
        e = plant.effects
        self._hist: deque[tuple[float, float]] = deque()
        self._t_prev = float(t0)
        self._t0 = float(t0)
        self._u0 = float(u0)
        self._rate_y = float(u0)
        self._servo_y = self._servo_c = float(u0)  # settled on the first command
        self._slack = e.slack_args  # fixed for the plant's life: not rebuilt every sample
        self._play_y = slack_start(e, float(u0), plant.slack_side)
        x0 = self._play_y if e.has_slack else float(u0)
        self.w = rest_warp(plant.core_params(), x0, z0)
        self.z = float(z0)
        self._zn = -1.0  # |z|^n carried between samples, as the array map does
        self._lag_taus = e.sensor_taus
        self._lag_y: list[float] | None = None  # each sensor stage's output, as effects.sensor_filtered

    def _delayed(self, t: float, u: float) -> float:
        d = self.plant.effects.delay_s
        self._hist.append((t, u))
        if d <= 0:
            return u
        tk = t - d
        h = self._hist
        if tk <= self._t0:
            return self._u0
        # drop history no longer needed (keep one sample at or before tk)
        while len(h) >= 2 and h[1][0] < tk:
            h.popleft()
        if len(h) == 1:
            return h[0][1]
        (ta, ua), (tb, ub) = h[0], h[1]
        a = (tk - ta) / (tb - ta) if tb > ta else 1.0
        return ua + a * (ub - ua)

    def step(self, t: float, u: float, airspeed: float | None = None) -> tuple[float, float]:
        """Advance to time t with command u; returns (w_true, w_meas)."""
        e = self.plant.effects
        x = self._delayed(float(t), float(u))
        if e.has_servo:  # the servo's position loop, as effects.servo_follow: it holds the previous command
            self._servo_y = servo_move(self._servo_y, self._servo_c, float(t) - self._t_prev, e.servo_tau_s,
                                       e.servo_rate_mm_s, 0.5 * e.servo_deadband_mm)
            self._servo_c, x = x, self._servo_y
        if math.isfinite(e.rate_mm_s):
            step = e.rate_mm_s * (t - self._t_prev)
            d = min(max(x - self._rate_y, -step), step)
            self._rate_y += d
            x = self._rate_y
        if e.has_slack:
            self._play_y = slack_step(x, self._play_y, *self._slack)
            x = self._play_y
        w, z, zn, _ = K.forward_step_zn(self._p, self.w, self.z, self._zn, x)
        self.w, self.z, self._zn = float(w), float(z), float(zn)
        w_true = self.w
        if (e.aero_gain_per_kpa != 0.0 or e.aero_deg_per_kpa != 0.0) and airspeed is not None:
            q = float(dynamic_pressure_kpa(airspeed))
            w_true = w_true * (1.0 - e.aero_gain_per_kpa * q) - e.aero_deg_per_kpa * q
        w_meas = w_true
        if self._lag_taus:
            if self._lag_y is None:
                self._lag_y = [w_true] * len(self._lag_taus)
            for i, tau in enumerate(self._lag_taus):
                a = math.exp(-(t - self._t_prev) / tau)
                self._lag_y[i] = w_meas = a * self._lag_y[i] + (1.0 - a) * w_meas
        if e.drift_deg_s != 0.0:
            w_meas = w_meas + e.drift_deg_s * float(drift_shape(t - self._t0, e.drift_tau_s))
        self._t_prev = float(t)
        return w_true, w_meas
