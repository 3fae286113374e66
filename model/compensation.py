"""Feed-forward through an augmented model: the effects that can be inverted exactly are inverted.

``Compensator`` wraps the inverse Bouc-Wen model (warp setpoint -> tendon) with
the inverse of each static effect a MODEL.json may carry:

- aero_load: the wing loses w (g q) + c q of warp, so the model is asked for
  (w_sp + c q) / (1 - g q), q the dynamic pressure of the current airspeed;
- friction and pretension: folded into the model's parameters (``model.effects.core_params``: the
  band of z scaled, the backbone moved), which the inverse then runs;
- backlash and the capstan stall of friction: the slack is taken up ahead of
  the motion (u +- the play's half-width at the command, by the direction of
  the last move, held through pauses);
- the servo's position loop (``servo_lag``, identify's servo): the command that
  brings the servo to the model's travel by the next step through its lag, from
  its dead band's edge (``ServoInverse``; what its speed cap holds back is made
  up as the lag allows, never by overshooting).

Delay, slew-rate limit and sensor lag cannot be undone causally without a
prediction of the setpoint; they are left to the PI trim. Drift concerns the
sensor, not the command. Same results one step at a time as the plant's
operators, so an augmented model and its compensator cancel exactly.
"""

from __future__ import annotations

import math

from warpbridge.model.boucwen import Stepper
from warpbridge.model.effects import Effects, dynamic_pressure_kpa
from warpbridge.model.plant import Plant

#: the effects a feed-forward can cancel exactly
INVERTIBLE = ("aero_load", "friction", "pretension", "backlash", "servo_lag")


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


class ServoInverse:
    """The command that brings the servo (``effects.servo_move``: a first-order approach of ``servo_tau_s`` to the
    near edge of its ``servo_deadband_mm`` about the command, capped at ``servo_rate_mm_s``) from the last travel
    asked of it to travel ``x`` one step of ``dt`` later, through its lag alone: where the cap holds the servo
    back, the command asks for less, so the servo never passes ``x`` (one that overshoots comes back to the far
    edge of its band, and the hysteresis keeps the overshoot's warp). The band's edge is held on the side of the
    last move, as ``SlackInverse`` holds a play's."""

    def __init__(self, effects: Effects) -> None:
        self.tau, self.half = effects.servo_tau_s, 0.5 * effects.servo_deadband_mm
        self.active = effects.has_servo
        self._x: float | None = None  # the last travel asked: where the servo's lag alone has brought it
        self._dir = 0.0

    def step(self, x: float, dt: float) -> float:
        """The command for travel ``x`` (mm) at the next step, ``dt`` s away (the loop's last period)."""
        if not self.active:
            return x
        if self._x is None or not (dt > 0 and math.isfinite(dt)):
            self._x = x if self._x is None else self._x
            return x + self._dir * self.half
        e = x - self._x
        if e != 0.0:
            self._dir = math.copysign(1.0, e)
        self._x = x
        lead = e / -math.expm1(-dt / self.tau) if self.tau > 0 else e
        return x - e + lead + self._dir * self.half


class Compensator:
    """Stateful feed-forward: ``step(w_sp, airspeed) -> u_cmd`` (deg, m/s -> mm)."""

    def __init__(self, plant: Plant, w0: float = 0.0, z0: float = 0.0) -> None:
        self.plant = plant
        self.model = Stepper(plant.core_params(), w0=w0, z0=z0)
        self.slack = SlackInverse(plant.effects)
        self.servo = ServoInverse(plant.effects)

    def step(self, w_sp: float, airspeed: float | None = None, dt: float = 0.0) -> float:
        """``dt``: s to the next step (the servo's inverse needs it; 0: the servo is not led)."""
        u = self.model.inverse_step(aero_inverse(w_sp, self.plant.effects, airspeed))
        return self.servo.step(self.slack.step(u), dt)

    def reset(self, w0: float = 0.0, z0: float = 0.0) -> None:
        self.model.reset(w0, z0)
        self.slack = SlackInverse(self.plant.effects)
        self.servo = ServoInverse(self.plant.effects)
