"""Is each wing's source channel really an aileron output? Ask the FC, and watch the output in flight.

The FC knows what each of its outputs does; a wrong ``source_channel`` otherwise
leaves the wings at neutral without a word. ``OutputFunctionCheck`` reads the
output-function parameters with the MAVLink parameter protocol
(PARAM_REQUEST_READ -> PARAM_VALUE from the FC, component 1):

- ArduPilot: ``SERVOn_FUNCTION`` for output n (1..32); 4 = Aileron. Flaperons
  (24, 25), elevons (77, 78), differential spoilers (16, 17, 86, 87) and the
  roll output (124) carry roll mixed with something else. Values as in
  ArduPilot's ``SRV_Channel::Aux_servo_function_t``.
- PX4 (control allocation, v1.14 on): ``PWM_MAIN_FUNCn`` for outputs 1..16,
  ``PWM_AUX_FUNCn`` for 17..32 (SERVO_OUTPUT_RAW port 1); 201.. = Servo 1..15
  (``src/lib/mixer_module/output_functions.yaml``), and servo k is control
  surface k-1 while k <= ``CA_SV_CS_COUNT``, whose ``CA_SV_CSi_TYPE`` says what
  it is: 1 Left Aileron, 2 Right Aileron, 15 Single Channel Aileron; 5/6 elevons.
  PX4 sends integer parameters byte-wise in the float field (ArduPilot casts).

Each wing gets a ``Verdict``: ``aileron``, ``mixed`` (roll mixed with flap,
pitch or spoiler: the wing will follow those too), ``not_aileron``, or
``unknown`` (no answer after a few tries, another autopilot, an output driven
by a script or offboard). Later PARAM_VALUEs of the same parameters (a ground
station changing them) are judged again.

``SourceWatch`` warns once if a wing's source output never moves (by more
than ``MOVE_US``) through ``STILL_S`` seconds while the FC is armed and flying
(airspeed at least ``FLYING_MS``, or unknown).
"""

from __future__ import annotations

import logging
import math
import struct
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from warpbridge.bridge.mavlink_env import mavlink

log = logging.getLogger(__name__)

FC_COMPONENT = 1
TRY_S = 1.5  # wait this long for an answer before asking again
TRIES = 3

ARDUPILOT_NAMES = {
    0: "disabled", 1: "RC passthrough", 2: "flap", 3: "auto flap", 4: "aileron", 16: "left spoiler 1",
    17: "right spoiler 1", 18: "aileron with input", 19: "elevator", 21: "rudder", 24: "left flaperon",
    25: "right flaperon", 26: "ground steering", 27: "parachute", 29: "landing gear", 70: "throttle",
    73: "left throttle", 74: "right throttle", 77: "left elevon", 78: "right elevon", 79: "left V-tail",
    80: "right V-tail", 86: "left spoiler 2", 87: "right spoiler 2", 110: "airbrake", 124: "roll out",
    125: "pitch out", 126: "thrust out", 127: "yaw out",
}
ARDUPILOT_AILERON = {4, 18}
ARDUPILOT_MIXED = {16, 17, 24, 25, 77, 78, 86, 87, 124}
ARDUPILOT_SCRIPT = range(94, 110)  # scripting outputs: whatever a Lua script makes of them

PX4_SURFACES = {
    0: "not set", 1: "left aileron", 2: "right aileron", 3: "elevator", 4: "rudder", 5: "left elevon",
    6: "right elevon", 7: "left V-tail", 8: "right V-tail", 9: "left flap", 10: "right flap", 11: "airbrake",
    12: "custom", 13: "left A-tail", 14: "right A-tail", 15: "single channel aileron", 16: "steering wheel",
    17: "left spoiler", 18: "right spoiler",
}
PX4_AILERON = {1, 2, 15}
PX4_MIXED = {5, 6}
PX4_SERVO = range(201, 216)
PX4_MOTOR = range(101, 113)
PX4_OFFBOARD = range(301, 307)
PX4_FUNCTIONS = {0: "disabled", 1: "constant min", 2: "constant max", 400: "landing gear", 401: "parachute",
                 402: "RC roll passthrough", 403: "RC pitch", 404: "RC throttle", 405: "RC yaw", 406: "RC flaps",
                 420: "gimbal roll", 421: "gimbal pitch", 422: "gimbal yaw", 430: "gripper"}

_INT_TYPES = {mavlink.MAV_PARAM_TYPE_UINT8, mavlink.MAV_PARAM_TYPE_INT8, mavlink.MAV_PARAM_TYPE_UINT16,
              mavlink.MAV_PARAM_TYPE_INT16, mavlink.MAV_PARAM_TYPE_UINT32, mavlink.MAV_PARAM_TYPE_INT32}


def decode_param(value: float, param_type: int, autopilot: str | None) -> float:
    """A PARAM_VALUE's value: PX4 packs integer parameters byte-wise into the float, ArduPilot casts."""
    if autopilot == "px4" and param_type in _INT_TYPES:
        raw = struct.unpack("<i", struct.pack("<f", value))[0]
        if param_type == mavlink.MAV_PARAM_TYPE_UINT32:
            raw &= 0xFFFFFFFF
        return float(raw)
    return float(value)


def function_param(autopilot: str, channel: int) -> str:
    """The parameter naming output ``channel``'s function (1-based, as SERVO_OUTPUT_RAW counts)."""
    if autopilot == "ardupilot":
        return f"SERVO{channel}_FUNCTION"
    return f"PWM_MAIN_FUNC{channel}" if channel <= 16 else f"PWM_AUX_FUNC{channel - 16}"


@dataclass(frozen=True)
class Verdict:
    """What the FC says a wing's source output does."""

    wing: str
    channel: int
    kind: str  # "aileron" | "mixed" | "not_aileron" | "unknown"
    what: str  # e.g. "SERVO3_FUNCTION 19 (elevator)"
    name: str = ""  # what the output does, short: "elevator", "motor 1", "left elevon"; "" if unknown

    @property
    def ok(self) -> bool:
        return self.kind in ("aileron", "mixed")

    def text(self) -> str:
        """One line for the log and ``--check``."""
        head = f"{self.wing} wing: FC output {self.channel}"
        return {
            "aileron": f"{head} is an aileron ({self.what})",
            "mixed": f"{head} carries roll mixed with more ({self.what}); the warp will follow all of it",
            "not_aileron": f"{head} is NOT an aileron ({self.what}): wrong source_channel?",
            "unknown": f"{head}: the FC cannot tell what it does ({self.what})",
        }[self.kind]

    def status(self) -> str:
        """Short STATUSTEXT form (one 50-character message where it can be)."""
        tag = self.wing[0].upper()
        return {
            "aileron": f"WB {tag} out {self.channel}: aileron",
            "mixed": f"WB {tag} out {self.channel} is {self.name}: roll mixed",
            "not_aileron": f"WB {tag} out {self.channel} is {self.name}, not aileron",
            "unknown": f"WB {tag} out {self.channel}: function unknown ({self.what})",
        }[self.kind][:100]


class OutputFunctionCheck:
    """Reads the output-function parameters of each wing's source channel; see the module docstring.

    ``take(messages, now)`` each cycle: consumes the FC's PARAM_VALUEs, asks (again) as needed, and
    returns the verdicts that are new or changed (empty list otherwise)."""

    def __init__(self, link: Any, channels: dict[str, int], *, try_s: float = TRY_S, tries: int = TRIES) -> None:
        self.link = link
        self.channels = dict(channels)
        self.try_s, self.tries = float(try_s), int(tries)
        self.values: dict[str, float] = {}
        self.verdicts: dict[str, Verdict] = {}
        self._asked: dict[str, tuple[float, int]] = {}  # name -> (time last asked, times asked)
        self._autopilot: str | None = None
        self._now = 0.0
        self.done = False

    # ------------------------------------------------------------------ what to ask

    def _needed(self, autopilot: str) -> list[str]:
        names: list[str] = []
        for ch in self.channels.values():
            fn_name = function_param(autopilot, ch)
            names.append(fn_name)
            fn = self.values.get(fn_name)
            if autopilot == "px4" and fn is not None and int(fn) in PX4_SERVO:
                names += ["CA_SV_CS_COUNT", f"CA_SV_CS{int(fn) - 201}_TYPE"]
        return list(dict.fromkeys(names))

    def _judge(self, wing: str, channel: int, autopilot: str | None) -> Verdict | None:
        """The verdict when every needed value is known or given up on; None while still asking."""
        if autopilot not in ("ardupilot", "px4"):
            return Verdict(wing, channel, "unknown", f"autopilot {autopilot or 'unknown'}")
        fn_name = function_param(autopilot, channel)
        fn = self._value_or_gone(fn_name)
        if fn is _WAITING:
            return None
        if fn is None:
            return Verdict(wing, channel, "unknown", f"no answer to {fn_name}")
        f = int(fn)
        if autopilot == "ardupilot":
            name = ARDUPILOT_NAMES.get(f, f"function {f}")
            what = f"{fn_name} {f} ({name})"
            if f in ARDUPILOT_AILERON:
                return Verdict(wing, channel, "aileron", what, name)
            if f in ARDUPILOT_MIXED:
                return Verdict(wing, channel, "mixed", what, name)
            if f in ARDUPILOT_SCRIPT:
                return Verdict(wing, channel, "unknown", f"{fn_name} {f}: a script output")
            return Verdict(wing, channel, "not_aileron", what, name)
        if f in PX4_SERVO:
            k = f - 201
            count, kind = self._value_or_gone("CA_SV_CS_COUNT"), self._value_or_gone(f"CA_SV_CS{k}_TYPE")
            if count is _WAITING or kind is _WAITING:
                return None
            if count is not None and k >= int(count):
                return Verdict(wing, channel, "not_aileron", f"{fn_name} {f}: servo {k + 1} is a tilt servo",
                               "tilt servo")
            if kind is None:
                return Verdict(wing, channel, "unknown", f"{fn_name} {f}, no answer to CA_SV_CS{k}_TYPE")
            t = int(kind)
            name = PX4_SURFACES.get(t, f"surface type {t}")
            what = f"{fn_name} {f}, CA_SV_CS{k}_TYPE {t} ({name})"
            if t in PX4_AILERON:
                return Verdict(wing, channel, "aileron", what, name)
            return Verdict(wing, channel, "mixed" if t in PX4_MIXED else "not_aileron", what, name)
        if f in PX4_OFFBOARD:
            return Verdict(wing, channel, "unknown", f"{fn_name} {f}: offboard actuator set {f - 300}")
        name = f"motor {f - 100}" if f in PX4_MOTOR else PX4_FUNCTIONS.get(f, f"function {f}")
        return Verdict(wing, channel, "not_aileron", f"{fn_name} {f} ({name})", name)

    def _value_or_gone(self, name: str) -> Any:
        if name in self.values:
            return self.values[name]
        asked = self._asked.get(name)
        if asked is not None and asked[1] >= self.tries and self._now - asked[0] >= self.try_s:
            return None  # asked enough: no answer
        return _WAITING

    # ------------------------------------------------------------------ the cycle

    def take(self, messages: Iterable[Any], now: float) -> tuple[list[Any], list[Verdict]]:
        """Consume the FC's PARAM_VALUEs; returns (the other messages, verdicts new or changed)."""
        self._now = now
        link = self.link
        autopilot = getattr(link, "autopilot", None)
        rest = []
        changed = False
        for msg in messages:
            if self._is_fc_param_value(msg):
                name = str(msg.param_id).split("\x00")[0]
                v = decode_param(msg.param_value, msg.param_type, autopilot)
                if math.isfinite(v) and self.values.get(name) != v:
                    self.values[name] = v
                    changed = True
                continue
            rest.append(msg)
        if autopilot is None or getattr(link, "system_id", None) is None or not getattr(link, "fc_alive", True):
            return rest, []
        if autopilot != self._autopilot:
            self._autopilot = autopilot
            self._asked.clear()
            changed = True
        new: list[Verdict] = []
        if autopilot in ("ardupilot", "px4"):
            self._ask(autopilot, now)
        if changed or not self.done:
            complete = True
            for wing, ch in self.channels.items():
                v = self._judge(wing, ch, autopilot)
                if v is None:
                    complete = False
                    continue
                if self.verdicts.get(wing) != v:
                    self.verdicts[wing] = v
                    new.append(v)
            self.done = complete
        return rest, new

    def _ask(self, autopilot: str, now: float) -> None:
        for name in self._needed(autopilot):
            if name in self.values:
                continue
            last, n = self._asked.get(name, (-math.inf, 0))
            if n >= self.tries or now - last < self.try_s:
                continue
            self._asked[name] = (now, n + 1)
            self.link.send(mavlink.MAVLink_param_request_read_message(
                self.link.system_id, FC_COMPONENT, name.encode("ascii"), -1))
            log.debug("asked the FC for %s", name)

    def _is_fc_param_value(self, msg: Any) -> bool:
        try:
            return (msg.get_type() == "PARAM_VALUE" and msg.get_srcComponent() == FC_COMPONENT
                    and msg.get_srcSystem() == self.link.system_id)
        except Exception:  # noqa: BLE001
            return False


_WAITING = object()


class SourceWatch:
    """Warns once per wing if its source output stays still through ``still_s`` of armed flight."""

    MOVE_US = 10.0  # more than PWM jitter
    STILL_S = 30.0
    FLYING_MS = 5.0

    def __init__(self, channels: dict[str, int], *, still_s: float = STILL_S,
                 on_still: Callable[[str, int, float, float], None] | None = None) -> None:
        self.channels = dict(channels)
        self.still_s = float(still_s)
        self.on_still = on_still or (lambda *_: None)
        self._span: dict[str, tuple[float, float]] = {}
        self._flown: dict[str, float] = {}
        self.warned: set[str] = set()
        self.moved: set[str] = set()

    def update(self, pwm: dict[int, float], armed: bool, airspeed: float | None, dt: float) -> None:
        """One cycle: ``pwm`` the FC's valid outputs, ``dt`` seconds since the last call."""
        flying = armed and (airspeed is None or airspeed >= self.FLYING_MS)
        if not flying or not dt > 0:
            return
        for wing, ch in self.channels.items():
            if wing in self.moved or wing in self.warned:
                continue
            v = pwm.get(ch)
            if v is None:
                continue
            lo, hi = self._span.get(wing, (v, v))
            lo, hi = min(lo, v), max(hi, v)
            self._span[wing] = (lo, hi)
            if hi - lo > self.MOVE_US:
                self.moved.add(wing)
                continue
            self._flown[wing] = self._flown.get(wing, 0.0) + min(dt, 1.0)
            if self._flown[wing] >= self.still_s:
                self.warned.add(wing)
                self.on_still(wing, ch, 0.5 * (lo + hi), self._flown[wing])
