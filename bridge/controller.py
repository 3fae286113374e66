"""One wing's warp controller: warp setpoint (deg) + measured warp -> tendon command (mm).

Modes (``MODES``; ``WB_MODE`` 0..3 in this order):

- ``open``: the straight line u = slope w + offset fitted to the model over [0, max warp];
- ``pi``: the paper's "PI only", no model: u = Kp e + Ki integral(e), the integrator carries
  the whole command (limited by the tendon limits);
- ``ff``: feed-forward, the inverse Bouc-Wen model (``Stepper.inverse_step``) on the setpoint;
- ``ff+pi``: feed-forward plus PI trim; the integrator is limited to +-``i_max`` mm.

Units: e in deg, Kp in mm per deg, Ki in mm per deg*s, u in mm. (The paper's Kp = 7, Ki = 1 come
without units; docs/field-tuning.md, "PI gains", converts them.)
The model and the error see the setpoint through a play (backlash) of half-width
``deadband`` deg: FC PWM jitter of a few us would otherwise feed the hysteresis
model tiny reversals, each one a jump of the loop width. The bridge sizes it from
the PWM resolution (``Mixer`` ``jitter_deadband``: +-jitter us times the wing's
deg per us), so the jitter never reverses the model but every real move passes,
with a lag of at most that half-width. Anti-windup: the integrator
does not integrate while the command is saturated in the error's direction, and is
clamped. A missing measurement (None or NaN) drops pi/ff+pi to ``ff`` with the
integrator held. Any change (mode, gains, model, sensor fallback) is bumpless: a
requested mode change re-initialises the integrator so the command does not jump,
and whatever it cannot absorb decays from the old command with ``transfer_s``.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from warpbridge.model.boucwen import BoucWenParams, Stepper, inverse
from warpbridge.model.compensation import ServoInverse, SlackInverse, aero_inverse
from warpbridge.model.effects import Effects

MODES = ("open", "pi", "ff", "ff+pi")


class Flags(enum.Flag):
    NONE = 0
    SATURATED = enum.auto()  # the command hit a tendon limit
    SENSOR_MISSING = enum.auto()  # no measurement: running feed-forward only
    I_HELD = enum.auto()  # the integrator was not updated this step
    TRANSFER = enum.auto()  # a bumpless-transfer offset is still decaying


@dataclass(frozen=True)
class Command:
    setpoint: float  # deg, as asked
    ff: float  # mm, model (ff, ff+pi) or straight line (open); 0 in pi
    pi: float  # mm, everything added to ff (PI and transfer offset): u_cmd = clamp(ff + pi)
    u_cmd: float  # mm, within the tendon limits
    measured: float | None  # deg
    mode: str  # the mode that ran (may differ from the requested one when the sensor is missing)
    flags: Flags


def straight_line(params: BoucWenParams, w_max: float) -> tuple[float, float]:
    """Least-squares line u = slope w + offset through the model's loop over [0, w_max] (mm, deg)."""
    leg = np.linspace(0.0, w_max, 100)
    w = np.concatenate([leg, leg[::-1], leg[1:], leg[::-1][1:]])
    u, _ = inverse(params, w, w0=0.0)
    n = 2 * leg.size - 1  # fit the second (settled) loop
    slope, offset = np.polyfit(w[-n:], u[-n:], 1)
    return float(slope), float(offset)


class WingController:
    """Per-wing controller; ``step(setpoint_deg, measured_deg | None, dt) -> Command``."""

    def __init__(self, params: BoucWenParams, *, mode: str = "ff+pi", kp: float = 0.5, ki: float = 10.0,
                 i_max: float = 2.0, u_min: float = -5.0, u_max: float = 15.0, w_max: float = 8.0,
                 deadband: float = 0.0, transfer_s: float = 0.5, w0: float = 0.0) -> None:
        self.set_mode(mode)
        self.kp, self.ki, self.i_max = float(kp), float(ki), float(i_max)
        self.set_limits(u_min, u_max)
        self.deadband, self.transfer_s = float(deadband), float(transfer_s)
        self._model = Stepper(params, w0=w0)
        self._w_max = float(w_max)
        self._line = straight_line(params, self._w_max)
        self._r = float(w0)  # the setpoint after the play
        self._i = 0.0  # integrator, mm
        self._bump = 0.0  # decaying transfer offset, mm
        self._u_prev: float | None = None
        self._ran: tuple[str, str] | None = None  # (requested, effective) mode of the last step
        self._retune = False
        self._pt_offset, self._pt_gain = 0.0, 1.0  # pre-tension compensation: u = offset + u_model / gain
        self._effects = Effects()  # a model file's aero load, slack and servo, inverted in the feed-forward
        self._slack = SlackInverse(self._effects)
        self._servo = ServoInverse(self._effects)

    @property
    def last_u(self) -> float:
        """The last command (mm); the model's output before the first step."""
        return self._model.u if self._u_prev is None else self._u_prev

    def start_state(self, w: float, z: float) -> None:
        """Start the feed-forward's hysteresis state at warp ``w`` (deg) with state ``z`` (the model's units),
        e.g. from a measured warp and the tendon position (``model.initial_state.algebraic_z0``), instead of
        at rest. Only before the first step: later it would move the command without a bumpless transfer."""
        if self._u_prev is not None:
            raise RuntimeError("start_state only before the first step")
        if not (math.isfinite(w) and math.isfinite(z)):
            raise ValueError("start state must be finite")
        self._model.reset(w0=float(w), z0=float(z))
        self._r = float(w)

    def set_mode(self, mode: str) -> None:
        if mode not in MODES:
            raise ValueError(f"unknown mode {mode!r} (one of {', '.join(MODES)})")
        self.mode = mode

    def set_gains(self, kp: float | None = None, ki: float | None = None, i_max: float | None = None) -> None:
        self.kp = self.kp if kp is None else float(kp)
        self.ki = self.ki if ki is None else float(ki)
        self.i_max = self.i_max if i_max is None else float(i_max)
        self._retune = True

    def set_deadband(self, deadband: float) -> None:
        """Half-width (deg) of the setpoint play; the played setpoint is kept where it is."""
        if not deadband >= 0:
            raise ValueError("deadband must be >= 0")
        self.deadband = float(deadband)

    def set_limits(self, u_min: float, u_max: float) -> None:
        if not u_min < u_max:
            raise ValueError("u_min must be below u_max")
        self.u_min, self.u_max = float(u_min), float(u_max)

    def set_model(self, params: BoucWenParams, w_max: float | None = None) -> None:
        """New model parameters and/or working range, applied without a bump."""
        self._w_max = self._w_max if w_max is None else float(w_max)
        self._model.set_params(params)
        self._line = straight_line(params, self._w_max)
        self._retune = True

    def set_pretension(self, offset: float, gain: float) -> None:
        """Compensate a pre-tension change (``model.effects`` ``pretension``) on the model's output:
        ``ff = offset + u_model / gain`` (open and ff modes). Meant for small, slow changes (online
        adaptation): applied as is, no bumpless transfer."""
        if not (math.isfinite(offset) and math.isfinite(gain) and gain > 0):
            raise ValueError("pre-tension offset must be finite and gain positive")
        self._pt_offset, self._pt_gain = float(offset), float(gain)

    def set_effects(self, effects: Effects) -> None:
        """Invert a model file's aerodynamic load (needs the airspeed given to ``step``), tendon slack
        (backlash and the capstan stall of friction) and servo (its lag, speed cap and dead band: the command
        that brings it to the model's travel by the next step) in the feed-forward; the friction scale and
        pre-tension are folded into the model's parameters instead."""
        self._effects = effects
        self._slack = SlackInverse(effects)
        self._servo = ServoInverse(effects)

    def step(self, setpoint: float, measured: float | None, dt: float, airspeed: float | None = None) -> Command:
        if math.isfinite(setpoint):  # play: the model and the error see r, which ignores jitter
            if setpoint > self._r + self.deadband:
                self._r = setpoint - self.deadband
            elif setpoint < self._r - self.deadband:
                self._r = setpoint + self.deadband
        r = self._r
        # always advanced, so switching into ff finds it current
        u_model = self._model.inverse_step(aero_inverse(r, self._effects, airspeed))
        u_model = self._servo.step(self._slack.step(self._pt_offset + u_model / self._pt_gain), dt)
        have_meas = measured is not None and math.isfinite(measured)
        flags = Flags.NONE if have_meas else Flags.SENSOR_MISSING
        mode = self.mode if have_meas or self.mode in ("open", "ff") else "ff"
        use_pi = mode in ("pi", "ff+pi")
        line = self._pt_offset + (self._line[0] * r + self._line[1]) / self._pt_gain
        base = {"open": line, "ff": u_model, "ff+pi": u_model, "pi": 0.0}[mode]
        e = r - measured if have_meas else 0.0
        i_lo, i_hi = (self.u_min, self.u_max) if mode == "pi" else (-self.i_max, self.i_max)
        self._i = min(i_hi, max(i_lo, self._i))

        if self._u_prev is not None and (self._ran != (self.mode, mode) or self._retune):
            if use_pi and self._ran is not None and self._ran[0] != self.mode:  # asked-for switch
                self._i = min(i_hi, max(i_lo, self._u_prev - base - self.kp * e))
            self._bump = self._u_prev - (base + (self.kp * e + self._i if use_pi else 0.0))
        self._ran, self._retune = (self.mode, mode), False

        if use_pi and dt > 0 and math.isfinite(dt):
            i_new = self._i + self.ki * e * dt
            u_try = base + self.kp * e + i_new + self._bump
            if (u_try > self.u_max and e > 0) or (u_try < self.u_min and e < 0):
                flags |= Flags.I_HELD  # conditional integration: saturated in the error's direction
            else:
                self._i = min(i_hi, max(i_lo, i_new))
        else:
            flags |= Flags.I_HELD
        pi = (self.kp * e + self._i if use_pi else 0.0) + self._bump
        if self._bump != 0.0:
            flags |= Flags.TRANSFER
            self._bump *= math.exp(-max(dt, 0.0) / self.transfer_s) if self.transfer_s > 0 else 0.0
            if abs(self._bump) < 1e-3:  # mm: a micron is nothing
                self._bump = 0.0
        u = base + pi
        if not self.u_min <= u <= self.u_max:
            flags |= Flags.SATURATED
            u = min(self.u_max, max(self.u_min, u))
        self._u_prev = u
        return Command(setpoint, base, pi, u, measured if have_meas else None, mode, flags)
