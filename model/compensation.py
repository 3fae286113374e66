"""Feed-forward through an augmented model: the effects that can be inverted exactly are inverted.

``Compensator`` wraps the inverse Bouc-Wen model (warp setpoint -> tendon) with
the inverse of each static effect a MODEL.json may carry:

- aero_load: the wing loses w (g q) + c q of warp, so the model is asked for
  (w_sp + c q) / (1 - g q), q the dynamic pressure of the current airspeed;
- friction: the model runs with az scaled (the loop is wider or narrower);
- pretension: the sheath sees gain (u - offset), so the command is u / gain + offset;
- backlash: the slack is taken up ahead of the motion (u +- width / 2 by the
  direction of the last move, held through pauses).

Delay, slew-rate limit and sensor lag cannot be undone causally without a
prediction of the setpoint; they are left to the PI trim. Drift concerns the
sensor, not the command. Same results one step at a time as the plant's
operators, so an augmented model and its compensator cancel exactly.
"""

from __future__ import annotations

from model.boucwen import Stepper
from model.effects import dynamic_pressure_kpa
from model.plant import Plant

#: the effects a feed-forward can cancel exactly
INVERTIBLE = ("aero_load", "friction", "pretension", "backlash")


class Compensator:
    """Stateful feed-forward: ``step(w_sp, airspeed) -> u_cmd`` (deg, m/s -> mm)."""

    def __init__(self, plant: Plant, w0: float = 0.0, z0: float = 0.0) -> None:
        self.plant = plant
        self.model = Stepper(plant.core_params(), w0=w0, z0=z0)
        self._dir = 1.0
        self._u_prev: float | None = None

    def model_warp(self, w_sp: float, airspeed: float | None) -> float:
        """Warp to ask of the Bouc-Wen model so that the loaded wing reaches w_sp."""
        e = self.plant.effects
        if airspeed is None or (e.aero_gain_per_kpa == 0.0 and e.aero_deg_per_kpa == 0.0):
            return w_sp
        q = float(dynamic_pressure_kpa(airspeed))
        k = 1.0 - e.aero_gain_per_kpa * q
        return (w_sp + e.aero_deg_per_kpa * q) / k if k > 0.05 else w_sp / 0.05

    def step(self, w_sp: float, airspeed: float | None = None) -> float:
        e = self.plant.effects
        u_model = self.model.inverse_step(self.model_warp(w_sp, airspeed))
        x = u_model
        if e.pretension_gain != 1.0 or e.pretension_offset_mm != 0.0:
            x = x / e.pretension_gain + e.pretension_offset_mm
        if e.backlash_mm > 0.0:
            if self._u_prev is not None and x != self._u_prev:
                self._dir = 1.0 if x > self._u_prev else -1.0
            self._u_prev = x
            x = x + self._dir * 0.5 * e.backlash_mm
        return x

    def reset(self, w0: float = 0.0, z0: float = 0.0) -> None:
        self.model.reset(w0, z0)
        self._u_prev = None
        self._dir = 1.0
