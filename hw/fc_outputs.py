"""Tendon servos on the flight controller's spare outputs, over MAVLink; spec ``fc:`` (or ``fc:ardupilot``, ``fc:px4``).

Sends COMMAND_LONG through a pymavlink connection handed in (anything with
``.mav.command_long_send``, e.g. ``mavutil.mavlink_connection(...)``):

- ArduPilot: MAV_CMD_DO_SET_SERVO, param1 = servo output number (1-based, SERVOn),
  param2 = pulse in us. ArduPilot only obeys it on an output whose ``SERVOn_FUNCTION``
  is 0 (Disabled), 1 (RCPassThru) or 51..66 (RCIN1..RCIN16); otherwise it answers
  "Channel n is already in use" and refuses. Set ``SERVOn_FUNCTION = 0`` on each
  tendon output (with passthrough functions a moving RC stick would take it back).
- PX4: MAV_CMD_DO_SET_ACTUATOR, params 1..6 = values -1..1 of "Peripheral via Actuator
  Set 1..6", NaN = leave unchanged, param7 = 0 (PX4 handles only the first set). Here
  ``channel`` is the actuator set number 1..6. In QGroundControl's Actuators page
  assign "Peripheral via Actuator Set N" to the tendon output and give it the same
  PWM min/max as ``pulse_range`` here: -1 maps to ``pulse_range[0]``, +1 to ``[1]``.

Pulses are clamped to the channel's safe range, and a command is only sent when the
pulse moved by at least 1 us since the last one sent, or ``keepalive_s`` has passed.
Feed the FC's COMMAND_ACK messages to ``handle_ack`` to have refusals reported by
``poll_errors`` (bit n set = MAV_RESULT n). A refused output is refused again at every
command, so at least once per keep-alive; ``poll_errors`` holds a refusal for
``ERROR_HOLD_KEEPALIVES`` keep-alive periods, so that a poll that falls between two refusals
(or runs late on a busy computer) does not read the episode as over.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from warpbridge.hw.base import check_pulse
from warpbridge.hw.errors import DeviceError

log = logging.getLogger(__name__)

AUTOPILOTS = ("ardupilot", "px4")
MIN_CHANGE_US = 1.0
PX4_ACTUATOR_SETS = 6
ERROR_HOLD_KEEPALIVES = 2.5  # a refusal counts as current this many keep-alive periods after it came


def _command_sender(connection: Any) -> Any:
    """The object whose ``command_long_send`` to call: ``connection.mav`` or ``connection``."""
    mav = getattr(connection, "mav", None)
    if mav is not None and hasattr(mav, "command_long_send"):
        return mav
    if hasattr(connection, "command_long_send"):
        return connection
    raise TypeError(f"{type(connection).__name__} has no .mav.command_long_send: not a MAVLink connection")


class FcOutputs:
    """ServoOutput on the FC's spare outputs (ArduPilot DO_SET_SERVO or PX4 DO_SET_ACTUATOR)."""

    name = "fc"

    def __init__(
        self,
        connection: Any,
        target_system: int = 1,
        target_component: int = 1,
        autopilot: str = "ardupilot",
        *,
        pulse_range: tuple[float, float] = (1000.0, 2000.0),
        limits: dict[int, tuple[float, float]] | None = None,
        keepalive_s: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if autopilot not in AUTOPILOTS:
            raise ValueError(f"autopilot must be one of {AUTOPILOTS}, got {autopilot!r}")
        lo, hi = float(pulse_range[0]), float(pulse_range[1])
        if not 0 < lo < hi:
            raise ValueError(f"pulse_range must satisfy 0 < min < max, got {pulse_range}")
        if keepalive_s <= 0:
            raise ValueError(f"keepalive_s must be > 0, got {keepalive_s}")
        self._mav = _command_sender(connection)
        self.target_system = target_system
        self.target_component = target_component
        self.autopilot = autopilot
        self.pulse_range = (lo, hi)
        self.limits: dict[int, tuple[float, float]] = {}
        for ch, (cl, ch_hi) in (limits or {}).items():
            self.set_limits(ch, cl, ch_hi)
        self.keepalive_s = keepalive_s
        self._clock = clock
        self._sent: dict[int, tuple[float, float]] = {}  # channel -> (pulse, time) last sent
        self._refused: dict[int, float] = {}  # MAV_RESULT -> time of its latest refusal
        self.commands_sent = 0

    def _check_channel(self, channel: int) -> None:
        if self.autopilot == "px4" and not 1 <= channel <= PX4_ACTUATOR_SETS:
            raise ValueError(f"PX4 actuator set must be 1..{PX4_ACTUATOR_SETS}, got {channel}")
        if self.autopilot == "ardupilot" and not 1 <= channel <= 32:
            raise ValueError(f"ArduPilot servo output must be 1..32, got {channel}")

    def set_limits(self, channel: int, min_us: float, max_us: float) -> None:
        """Safe pulse range of ``channel`` (within ``pulse_range``)."""
        self._check_channel(channel)
        lo, hi = self.pulse_range
        if not lo <= min_us < max_us <= hi:
            raise ValueError(f"limits of output {channel} must lie within {self.pulse_range}, got {(min_us, max_us)}")
        self.limits[channel] = (float(min_us), float(max_us))

    def clamp(self, channel: int, pulse_us: float) -> float:
        """``pulse_us`` clamped to the safe range of ``channel``."""
        lo, hi = self.limits.get(channel, self.pulse_range)
        return min(max(pulse_us, lo), hi)

    def actuator_value(self, pulse_us: float) -> float:
        """PX4 actuator value -1..1 for ``pulse_us`` over ``pulse_range``."""
        lo, hi = self.pulse_range
        return 2.0 * (pulse_us - lo) / (hi - lo) - 1.0

    def set_pulse(self, channel: int, pulse_us: float) -> None:
        """Command ``pulse_us`` on output ``channel`` (rate-limited, see module docstring)."""
        self._check_channel(channel)
        pulse = self.clamp(channel, check_pulse(pulse_us))
        now = self._clock()
        last = self._sent.get(channel)
        if last is not None and abs(pulse - last[0]) < MIN_CHANGE_US and now - last[1] < self.keepalive_s:
            return
        if self.autopilot == "ardupilot":
            params = [float(channel), float(round(pulse)), 0.0, 0.0, 0.0, 0.0, 0.0]
            command = mavlink.MAV_CMD_DO_SET_SERVO
        else:
            params = [math.nan] * 6 + [0.0]
            params[channel - 1] = self.actuator_value(pulse)
            command = mavlink.MAV_CMD_DO_SET_ACTUATOR
        try:
            self._mav.command_long_send(self.target_system, self.target_component, command, 0, *params)
        except OSError as exc:  # serial.SerialException is an OSError subclass too
            raise DeviceError(f"cannot send to the flight controller: {exc}", self.name) from exc
        self._sent[channel] = (pulse, now)
        self.commands_sent += 1

    def handle_ack(self, msg: Any) -> None:
        """Take a COMMAND_ACK from the FC; refusals of our commands become error bits."""
        if msg.command not in (mavlink.MAV_CMD_DO_SET_SERVO, mavlink.MAV_CMD_DO_SET_ACTUATOR):
            return
        if msg.result not in (mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_IN_PROGRESS):
            now = self._clock()
            if msg.result not in self._current(now):
                log.warning("fc outputs: FC refused command %d: result %d", msg.command, msg.result)
            self._refused[msg.result] = now

    def _current(self, now: float) -> dict[int, float]:
        """The refusals of the last ``ERROR_HOLD_KEEPALIVES`` keep-alive periods (older ones dropped)."""
        hold = ERROR_HOLD_KEEPALIVES * self.keepalive_s
        self._refused = {r: t for r, t in self._refused.items() if now - t <= hold}
        return self._refused

    def poll_errors(self) -> int:
        """Bits ``1 << MAV_RESULT`` of the refusals of the last ``ERROR_HOLD_KEEPALIVES`` keep-alive periods."""
        return sum(1 << r for r in self._current(self._clock()))

    def error_names(self, bits: int) -> list[str]:
        """MAV_RESULT names of the set bits."""
        names = mavlink.enums["MAV_RESULT"]
        return [names[b].name if b in names else f"bit {b}" for b in range(bits.bit_length()) if bits & (1 << b)]

    def close(self) -> None:
        """The connection belongs to the caller: nothing to release."""
