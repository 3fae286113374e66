"""Feed-forward through an augmented model: the effects that can be inverted exactly are inverted.

``Compensator`` wraps the inverse Bouc-Wen model (warp setpoint -> tendon) with
the inverse of each static effect a MODEL.json may carry:

- aero_load: the wing loses w (g q) + c q of warp, so the model is asked for
  (w_sp + c q) / (1 - g q), q the dynamic pressure of the current airspeed;
- friction and pretension: folded into the model's parameters (``model.effects.core_params``: the
  band of z scaled, the backbone moved), which the inverse then runs;
- backlash and the capstan stall of friction: the slack is taken up ahead of
  the motion (u +- the play's half-width at the command, by the direction of
  the last move, held through pauses).

Delay, slew-rate limit and sensor lag cannot be undone causally without a
prediction of the setpoint; they are left to the PI trim. Drift concerns the
sensor, not the command. Same results one step at a time as the plant's
operators, so an augmented model and its compensator cancel exactly.
"""

from __future__ import annotations

from warpbridge.model.boucwen import Stepper
from warpbridge.model.effects import Effects, dynamic_pressure_kpa
from warpbridge.model.plant import Plant

#: the effects a feed-forward can cancel exactly
INVERTIBLE = ("aero_load", "friction", "pretension", "backlash")


def aero_inverse(w_sp: float, effects: Effects, airspeed: float | None) -> float:
    """Warp to ask of the unloaded model so that the aerodynamically loaded wing reaches w_sp."""
    if airspeed is None or (effects.aero_gain_per_kpa == 0.0 and effects.aero_deg_per_kpa == 0.0):
        return w_sp
    q = float(dynamic_pressure_kpa(airspeed))
    k = max(1.0 - effects.aero_gain_per_kpa * q, 0.05)
    return (w_sp + effects.aero_deg_per_kpa * q) / k


class SlackInverse:
    """Takes up the slack of the effects' play (``model.effects.slack_play``: backlash plus capstan stall)
    ahead of the motion: the command x whose play edge in the last direction of motion is u."""

    def __init__(self, effects: Effects) -> None:
        self.r0, self.pull, self.release, self.zero = effects.slack_args
        self.active = effects.has_slack
        self._dir = 1.0
        self._prev: float | None = None

    def step(self, u: float) -> float:
        if not self.active:
            return u
        if self._prev is not None and u != self._prev:
            self._dir = 1.0 if u > self._prev else -1.0
        self._prev = u
        x = u + self._dir * self.r0  # at or below the slack travel only the fixed half-width is left
        if x > self.zero:  # x - r0 - pull (x - zero) = u pulling, x + r0 + release (x - zero) = u releasing
            c = self.pull if self._dir > 0 else -self.release
            x = (x - c * self.zero) / (1.0 - c)
        return x


class Compensator:
    """Stateful feed-forward: ``step(w_sp, airspeed) -> u_cmd`` (deg, m/s -> mm)."""

    def __init__(self, plant: Plant, w0: float = 0.0, z0: float = 0.0) -> None:
        self.plant = plant
        self.model = Stepper(plant.core_params(), w0=w0, z0=z0)
        self.slack = SlackInverse(plant.effects)

    def step(self, w_sp: float, airspeed: float | None = None) -> float:
        u = self.model.inverse_step(aero_inverse(w_sp, self.plant.effects, airspeed))
        return self.slack.step(u)

    def reset(self, w0: float = 0.0, z0: float = 0.0) -> None:
        self.model.reset(w0, z0)
        self.slack = SlackInverse(self.plant.effects)
