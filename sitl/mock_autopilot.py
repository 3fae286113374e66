"""A mock flight controller that speaks MAVLink like ArduPilot Plane or PX4, for SITL and tests.

``python -m warpbridge.sitl.mock_autopilot --fc-port N [--gcs udp:127.0.0.1:14550 ...]
--autopilot ardupilot|px4 [--scenario sine|steps|hold|module:attr | --roll-file CSV]``
(or ``MockAutopilot`` in-process, with ``start()``/``stop()``). It is system 1
component 1 and sends HEARTBEAT as a fixed wing (MAV_AUTOPILOT_ARDUPILOTMEGA or
MAV_AUTOPILOT_PX4). It sends UDP to 127.0.0.1:N, where the bridge listens
(``udpin:127.0.0.1:N``), as ArduPilot SITL's ``udpclient`` outputs do
(``--fc`` takes any pymavlink string instead).

Ground-station outputs (``--gcs``, repeatable; an int port means
``udp:127.0.0.1:PORT``) behave as a SITL's: ``udp:HOST:PORT`` / ``udpout:`` (or
plain ``HOST:PORT``) sends there from the start, heartbeats included, without
waiting for the ground station, and once a ground station sends, replies go to
the address it sends from (PX4's UDP link takes its partner's address the same
way; ArduPilot's ``sim_vehicle.py`` puts MAVProxy ``--out 127.0.0.1:14550`` there);
``udpin:HOST:PORT`` listens and answers whoever sent; ``tcp:``/``tcpin:`` as
pymavlink. QGroundControl, Mission Planner and MAVProxy listen on UDP 14550 by
default, MAVSDK with ``udpin://0.0.0.0:14550``.

It answers MAV_CMD_SET_MESSAGE_INTERVAL with COMMAND_ACK and then streams the
message at that rate: SERVO_OUTPUT_RAW (36) on both autopilots,
ACTUATOR_OUTPUT_STATUS (375) on PX4 only (``active`` = number of outputs, as PX4
fills it), VFR_HUD (74). Output pulses come from a roll source, any callable
``t -> {channel: pulse_us}`` (t in s since start; default a sine on the two
aileron outputs 1 and 2), quantised to 1 us with +-1 us jitter. It accepts
MAV_CMD_DO_SET_SERVO (ArduPilot) and MAV_CMD_DO_SET_ACTUATOR (PX4): acked,
recorded, and a DO_SET_SERVO output then shows the commanded pulse. It has a few
parameters of its own so a ground station finishes its parameter download, by
PARAM_REQUEST_LIST or, as ArduPilot, as ``@PARAM/param.pck`` over MAVLink FTP
(as PX4, FTP there is refused at once: file not found). It publishes what each
output does as the autopilot would (``OutputFunctionParams``: ArduPilot's
``SERVOn_FUNCTION``, PX4's ``PWM_MAIN_FUNCn`` and ``CA_SV_CSi_TYPE``, integers
byte-wise in the float as PX4 sends them); ``output_functions`` (CLI
``--output-function CH=ROLE``) changes them, e.g. to put the aileron elsewhere.

Routing follows ArduPilot's MAVLink_routing: routes (system, component) ->
link are learned from what arrives; a message with no target, or a broadcast
target, is forwarded to every other link that has a route, one for another
component goes only where that component was heard, and whatever is for us (or
broadcast) is handled here. On top of that, as a SITL's ground-station output
does, every ground-station output receives everything untargeted that comes
from the vehicle side (the bridge's HEARTBEAT, NAMED_VALUE_FLOAT, STATUSTEXT,
PARAM_VALUE) even before the ground station has sent anything: a GCS that only
listens sees component 191. The mock's own heartbeat and streams go to every link.

Failsafe tests: ``pause_streams(seconds, forget=False, heartbeat=True)`` (CLI
``--stall-at T --stall-for S [--stall-forget] [--stall-heartbeat]``) stops the
streams; with ``forget`` the requested rates are lost as in a reboot, so they
come back only if the bridge asks again.
"""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"  # before pymavlink is imported: MAVLink 2, ardupilotmega
os.environ["MAVLINK_DIALECT"] = "ardupilotmega"

import argparse  # noqa: E402
import csv  # noqa: E402
import errno  # noqa: E402
import importlib  # noqa: E402
import logging  # noqa: E402
import math  # noqa: E402
import select  # noqa: E402
import signal  # noqa: E402
import struct  # noqa: E402
import sys  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable, Mapping, Sequence  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
from pymavlink import mavutil  # noqa: E402

from warpbridge.bridge.mavftp import ERR_FILE_NOT_FOUND, OP_ACK, OP_NAK, FtpOp, FtpServer, PackedParam  # noqa: E402

if mavutil.current_dialect != "ardupilotmega" or mavutil.mavlink.WIRE_PROTOCOL_VERSION != "2.0":
    mavutil.set_dialect("ardupilotmega")
mavlink = mavutil.mavlink

log = logging.getLogger(__name__)

RollSource = Callable[[float], Mapping[int, float]]
AirspeedSource = Callable[[float], float]

SYSID = 1
COMPID = mavlink.MAV_COMP_ID_AUTOPILOT1
MSG_HEARTBEAT = mavlink.MAVLINK_MSG_ID_HEARTBEAT
MSG_SERVO_OUTPUT_RAW = mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW
MSG_ACTUATOR_OUTPUT_STATUS = mavlink.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS
MSG_VFR_HUD = mavlink.MAVLINK_MSG_ID_VFR_HUD
STREAMABLE = {
    "ardupilot": {MSG_HEARTBEAT, MSG_SERVO_OUTPUT_RAW, MSG_VFR_HUD},
    "px4": {MSG_HEARTBEAT, MSG_SERVO_OUTPUT_RAW, MSG_ACTUATOR_OUTPUT_STATUS, MSG_VFR_HUD},
}
AUTOPILOT_IDS = {"ardupilot": mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, "px4": mavlink.MAV_AUTOPILOT_PX4}
DEFAULT_RATE_HZ = 4.0  # SET_MESSAGE_INTERVAL with interval 0 ("default rate")
N_OUTPUTS = 8  # outputs the mock reports (PX4 "active" count)


# ---------------------------------------------------------------------- roll sources


@dataclass
class SineRoll:
    """Aileron outputs swinging as a sine around trim; other outputs fixed."""

    amplitude_us: float = 300.0
    freq_hz: float = 0.5
    trim_us: float = 1500.0
    channels: tuple[int, ...] = (1, 2)
    fixed: dict[int, float] = field(default_factory=lambda: {3: 1100.0, 4: 1500.0})

    def __call__(self, t: float) -> dict[int, float]:
        out = dict(self.fixed)
        v = self.trim_us + self.amplitude_us * math.sin(2 * math.pi * self.freq_hz * t)
        out.update({ch: v for ch in self.channels})
        return out


@dataclass
class StepRoll(SineRoll):
    """Square wave between trim - amplitude and trim + amplitude."""

    def __call__(self, t: float) -> dict[int, float]:
        out = dict(self.fixed)
        s = 1.0 if math.sin(2 * math.pi * self.freq_hz * t) >= 0 else -1.0
        out.update({ch: self.trim_us + s * self.amplitude_us for ch in self.channels})
        return out


@dataclass
class HoldRoll(SineRoll):
    """Everything at trim."""

    def __call__(self, t: float) -> dict[int, float]:
        out = dict(self.fixed)
        out.update({ch: self.trim_us for ch in self.channels})
        return out


class CsvRoll:
    """Outputs from a CSV with columns ``t,ch1,ch2,...`` (and optionally ``airspeed``), linearly
    interpolated, held at the ends (or repeated with ``loop=True``)."""

    def __init__(self, path: str | os.PathLike[str], *, loop: bool = False) -> None:
        with open(path, newline="", encoding="utf-8") as f:
            rows = list(csv.reader(f))
        if len(rows) < 2:
            raise ValueError(f"{path}: needs a header and at least one row")
        header = [h.strip().lower() for h in rows[0]]
        if "t" not in header:
            raise ValueError(f"{path}: no 't' column")
        data = np.array([[float(x) for x in r] for r in rows[1:] if r], dtype=float)
        if data.ndim != 2 or data.shape[1] != len(header):
            raise ValueError(f"{path}: rows do not match the header")
        self.t = data[:, header.index("t")]
        if np.any(np.diff(self.t) < 0) or not np.all(np.isfinite(self.t)):
            raise ValueError(f"{path}: column t must be finite and increasing")
        self.columns: dict[int, np.ndarray] = {}
        for i, h in enumerate(header):
            if h.startswith("ch") and h[2:].isdigit():
                self.columns[int(h[2:])] = data[:, i]
        if not self.columns:
            raise ValueError(f"{path}: no ch<N> columns")
        self.airspeed_column = data[:, header.index("airspeed")] if "airspeed" in header else None
        self.loop = loop
        self.duration = float(self.t[-1] - self.t[0])

    def _time(self, t: float) -> float:
        if self.loop and self.duration > 0:
            return self.t[0] + (t - self.t[0]) % self.duration
        return t

    def __call__(self, t: float) -> dict[int, float]:
        tt = self._time(t)
        return {ch: float(np.interp(tt, self.t, col)) for ch, col in self.columns.items()}

    def airspeed(self, t: float) -> float:
        if self.airspeed_column is None:
            raise ValueError("no airspeed column")
        return float(np.interp(self._time(t), self.t, self.airspeed_column))


SCENARIOS: dict[str, Callable[[], RollSource]] = {"sine": SineRoll, "steps": StepRoll, "hold": HoldRoll}


def load_scenario(name: str) -> RollSource:
    """A built-in scenario name, or ``module:attr`` naming a roll source (callable t -> {ch: us})."""
    if name in SCENARIOS:
        return SCENARIOS[name]()
    if ":" in name:
        module, _, attr = name.partition(":")
        obj = getattr(importlib.import_module(module), attr)
        return obj
    raise ValueError(f"unknown scenario {name!r}: use {', '.join(SCENARIOS)} or module:attr")


# ---------------------------------------------------------------------- output functions (parameter protocol)

# role -> ArduPilot SERVOn_FUNCTION (SRV_Channel::Aux_servo_function_t)
ARDUPILOT_FUNCTIONS = {"disabled": 0, "aileron": 4, "elevator": 19, "rudder": 21, "throttle": 70,
                       "left_flaperon": 24, "right_flaperon": 25, "left_elevon": 77, "right_elevon": 78}
# role -> PX4 control surface type (CA_SV_CSi_TYPE); "throttle" is a motor (PWM_MAIN_FUNCn 101..)
PX4_SURFACE_TYPES = {"left_aileron": 1, "aileron": 1, "right_aileron": 2, "elevator": 3, "rudder": 4,
                     "left_elevon": 5, "right_elevon": 6, "left_flaperon": 9, "right_flaperon": 10}
DEFAULT_OUTPUT_FUNCTIONS = {1: "aileron", 2: "aileron", 3: "throttle", 4: "rudder"}  # as SineRoll drives them
N_FUNCTION_PARAMS = 16


class OutputFunctionParams:
    """What each output does, published through the parameter protocol as the real autopilots do.

    ``roles``: output (1-based) -> role (keys of ``ARDUPILOT_FUNCTIONS`` / ``PX4_SURFACE_TYPES``, or
    ``"throttle"``); other outputs are disabled. ArduPilot: ``SERVOn_FUNCTION`` (INT16, value cast into
    the float). PX4: ``PWM_MAIN_FUNCn`` = 201 + servo index for control surfaces, 101.. for motors,
    ``CA_SV_CS_COUNT`` and ``CA_SV_CSi_TYPE`` (INT32, bytes of the integer in the float: PX4's
    byte-wise parameter encoding)."""

    def __init__(self, autopilot: str, roles: Mapping[int, str] | None = None) -> None:
        self.autopilot = autopilot
        self.roles = dict(DEFAULT_OUTPUT_FUNCTIONS if roles is None else roles)
        self.values: dict[str, int] = {}
        if autopilot == "ardupilot":
            for ch in range(1, N_FUNCTION_PARAMS + 1):
                role = self.roles.get(ch, "disabled")
                if role not in ARDUPILOT_FUNCTIONS:
                    raise ValueError(f"unknown output role {role!r}")
                self.values[f"SERVO{ch}_FUNCTION"] = ARDUPILOT_FUNCTIONS[role]
        else:
            surfaces, motors = 0, 0
            for ch in range(1, N_FUNCTION_PARAMS + 1):
                role = self.roles.get(ch, "disabled")
                if role == "throttle":
                    motors += 1
                    self.values[f"PWM_MAIN_FUNC{ch}"] = 100 + motors
                elif role in PX4_SURFACE_TYPES:
                    self.values[f"CA_SV_CS{surfaces}_TYPE"] = PX4_SURFACE_TYPES[role]
                    surfaces += 1
                    self.values[f"PWM_MAIN_FUNC{ch}"] = 200 + surfaces
                elif role == "disabled":
                    self.values[f"PWM_MAIN_FUNC{ch}"] = 0
                else:
                    raise ValueError(f"unknown output role {role!r}")
            self.values["CA_SV_CS_COUNT"] = surfaces

    def encode(self, name: str) -> tuple[float, int]:
        """(param_value, param_type) of PARAM_VALUE for ``name``, as the autopilot encodes it."""
        v = self.values[name]
        if self.autopilot == "ardupilot":
            return float(v), mavlink.MAV_PARAM_TYPE_INT16
        return struct.unpack("<f", struct.pack("<i", v))[0], mavlink.MAV_PARAM_TYPE_INT32

    def decode(self, name: str, value: float) -> int:
        """A PARAM_SET's value for ``name`` back to the integer."""
        if self.autopilot == "ardupilot":
            return int(round(value))
        return struct.unpack("<i", struct.pack("<f", value))[0]


def parse_output_functions(items: list[str]) -> dict[int, str]:
    """``["1=elevator", "5=aileron"]`` -> ``{1: "elevator", 5: "aileron"}`` over the default roles."""
    roles = dict(DEFAULT_OUTPUT_FUNCTIONS)
    for item in items:
        ch, sep, role = item.partition("=")
        if not sep or not ch.strip().isdigit():
            raise ValueError(f"--output-function {item!r}: expected CH=ROLE, e.g. 5=aileron")
        roles[int(ch)] = role.strip()
    return roles


# ---------------------------------------------------------------------- the mock


def _connection_string(spec: int | str | None) -> str | None:
    if spec is None or isinstance(spec, str):
        return spec
    return f"udpout:127.0.0.1:{int(spec)}"


# ---------------------------------------------------------------------- ground-station outputs

GCS_KINDS = ("udp", "udpout", "udpin", "tcp", "tcpin")


def gcs_output_string(spec: int | str) -> str:
    """A ground-station output in its full form: an int port or ``HOST:PORT`` -> ``udp:HOST:PORT``.

    Raises ValueError naming the forms accepted."""
    if isinstance(spec, int) and not isinstance(spec, bool):
        kind, host, port = "udp", "127.0.0.1", str(spec)
    else:
        text = str(spec).strip()
        kind, _, rest = text.partition(":")
        if kind not in GCS_KINDS:
            kind, rest = "udp", text
        host, sep, port = rest.rpartition(":")
        if not sep or not host or ":" in host:
            raise ValueError(f"{spec!r}: expected udp:HOST:PORT (send to), udpin:HOST:PORT (listen), "
                             "udpout:, tcp: or tcpin:HOST:PORT")
    if not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"{spec!r}: port must be 1..65535")
    return f"{kind}:{host}:{int(port)}"


class UdpOutput(mavutil.mavudp):
    """``udp:HOST:PORT`` as a SITL's ground-station output: sends to HOST:PORT from the start; once
    something arrives, replies go to the address it came from (the latest sender)."""

    def __init__(self, address: str, **kw: Any) -> None:
        super().__init__(address, input=False, **kw)
        self.peer: tuple[str, int] | None = None

    def recv(self, n: int | None = None) -> bytes:
        try:
            data, addr = self.port.recvfrom(65535)
        except OSError as e:
            if e.errno in (errno.EAGAIN, errno.EWOULDBLOCK, errno.ECONNREFUSED):
                return b""
            raise
        if addr != self.peer:
            log.info("ground station at %s:%d", addr[0], addr[1])
            self.peer = addr
            self.destination_addr = addr
            self.resolved_destination_addr = addr[0]
        return data


def open_gcs_output(spec: int | str) -> Any:
    """The connection for one ground-station output (see ``gcs_output_string``)."""
    full = gcs_output_string(spec)
    kind, _, address = full.partition(":")
    if kind in ("udp", "udpout"):
        return UdpOutput(address, source_system=SYSID, source_component=COMPID)
    return mavutil.mavlink_connection(full, source_system=SYSID, source_component=COMPID)


@dataclass
class Command:
    """A COMMAND_LONG the mock received."""

    command: int
    params: tuple[float, ...]
    source: tuple[int, int]
    result: int


class MockAutopilot:
    """The mock FC; see the module docstring. ``fc``/``gcs``: a UDP port on 127.0.0.1 or a
    pymavlink connection string."""

    def __init__(
        self,
        fc: int | str,
        gcs: int | str | Sequence[int | str] | None = None,
        *,
        autopilot: str = "ardupilot",
        roll_source: RollSource | None = None,
        airspeed_source: AirspeedSource | None = None,
        armed: bool = False,
        seed: int = 0,
        jitter_us: int = 1,
        heartbeat_hz: float = 1.0,
        output_functions: Mapping[int, str] | None = None,
    ) -> None:
        if autopilot not in AUTOPILOT_IDS:
            raise ValueError(f"autopilot must be one of {', '.join(AUTOPILOT_IDS)}")
        self.autopilot = autopilot
        self.roll_source: RollSource = roll_source or SineRoll()
        self.airspeed_source: AirspeedSource = airspeed_source or (lambda t: 12.0)
        self.armed = armed
        self.jitter_us = int(jitter_us)
        self.heartbeat_period = 1.0 / heartbeat_hz
        self._rng = np.random.default_rng(seed)
        self.links: dict[str, Any] = {}
        self.links["fc"] = mavutil.mavlink_connection(_connection_string(fc), source_system=SYSID,
                                                      source_component=COMPID)
        self.gcs_links: list[str] = []  # ground-station outputs: "gcs", "gcs2", ...
        outputs = [] if gcs is None else [gcs] if isinstance(gcs, int | str) else list(gcs)
        try:
            for i, spec in enumerate(outputs):
                name = "gcs" if i == 0 else f"gcs{i + 1}"
                self.links[name] = open_gcs_output(spec)
                self.gcs_links.append(name)
        except BaseException:
            for conn in self.links.values():
                conn.close()
            raise
        self.intervals: dict[int, float] = {}  # msg id -> seconds (HEARTBEAT is always on)
        self.commands: list[Command] = []
        self.servo_commands: dict[int, float] = {}  # DO_SET_SERVO: output -> us
        self.actuator_commands: dict[int, float] = {}  # DO_SET_ACTUATOR: set number 1..6 -> -1..1
        self.routes: dict[tuple[int, int], str] = {}
        self.forwarded: dict[str, int] = {}  # message type -> count forwarded
        self.sent: dict[str, int] = {}  # message type -> count of own messages sent
        self.params: dict[str, float] = (
            {"SYSID_THISMAV": 1.0, "ARSPD_TYPE": 1.0}
            if autopilot == "ardupilot"
            else {"MAV_SYS_ID": 1.0, "FW_AIRSPD_TRIM": 15.0}
        )
        self.output_functions = OutputFunctionParams(autopilot, output_functions)
        self.params.update({name: float(v) for name, v in self.output_functions.values.items()})
        self._ftp_server = FtpServer(self._ftp_params)
        self._next_due: dict[int, float] = {}
        self._pause_until = 0.0
        self._pause_heartbeat = True
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._t0 = time.monotonic()

    # ------------------------------------------------------------------ control

    def start(self) -> MockAutopilot:
        """Run in a background thread."""
        self._stop.clear()
        self._thread = threading.Thread(target=self.run, name="mock-autopilot", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None
        for conn in self.links.values():
            conn.close()
        self.links = {}

    def __enter__(self) -> MockAutopilot:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def pause_streams(self, seconds: float, *, forget: bool = False, heartbeat: bool = True) -> None:
        """Stop streaming for ``seconds``; ``forget`` drops the requested rates (as a reboot would);
        ``heartbeat=False`` silences the heartbeat too."""
        with self._lock:
            self._pause_until = time.monotonic() + seconds
            self._pause_heartbeat = not heartbeat
            if forget:
                self.intervals.clear()
                self._next_due.clear()
        log.info("streams paused for %.1f s%s", seconds, " (rates forgotten)" if forget else "")

    def set_armed(self, armed: bool) -> None:
        self.armed = bool(armed)

    def time(self) -> float:
        """Seconds since the mock started: the roll source's clock."""
        return time.monotonic() - self._t0

    def outputs(self, t: float | None = None) -> dict[int, int]:
        """Output pulses (us, integers, with jitter) as they would be streamed now."""
        t = self.time() if t is None else t
        try:
            src = dict(self.roll_source(t))
        except Exception:  # noqa: BLE001 - a broken scenario must not kill the FC
            log.exception("roll source failed at t=%.3f", t)
            src = {}
        src.update(self.servo_commands)
        out: dict[int, int] = {}
        for ch in range(1, max([N_OUTPUTS, *src.keys()]) + 1):
            v = src.get(ch, 0.0)
            if not math.isfinite(v) or v <= 0:
                out[ch] = 0  # disabled output, as ArduPilot reports it
                continue
            jitter = int(self._rng.integers(-self.jitter_us, self.jitter_us + 1)) if self.jitter_us else 0
            out[ch] = int(min(max(round(v) + jitter, 0), 65535))
        return out

    # ------------------------------------------------------------------ loop

    def run(self, duration: float | None = None) -> None:
        """Serve until ``stop()`` (or for ``duration`` s)."""
        end = None if duration is None else time.monotonic() + duration
        next_hb = time.monotonic()
        while not self._stop.is_set() and (end is None or time.monotonic() < end):
            now = time.monotonic()
            paused = now < self._pause_until
            if now >= next_hb:
                next_hb = now + self.heartbeat_period
                if not (paused and self._pause_heartbeat):
                    self._send_own("heartbeat")
            if not paused:
                self._streams(now)
            self._receive()
            wait = min([next_hb, *self._next_due.values()], default=next_hb) - time.monotonic()
            self._wait(min(max(wait, 0.0), 0.02))

    def _wait(self, timeout: float) -> None:
        fds = [c.port.fileno() for c in self.links.values()]
        if timeout <= 0 or not fds:
            return
        try:
            select.select(fds, [], [], timeout)
        except (OSError, ValueError):
            time.sleep(timeout)

    def _streams(self, now: float) -> None:
        with self._lock:
            due = [m for m, t in self._next_due.items() if now >= t]
            for msg_id in due:
                interval = self.intervals[msg_id]
                nxt = self._next_due[msg_id] + interval
                self._next_due[msg_id] = nxt if nxt > now else now + interval
        for msg_id in due:
            if msg_id == MSG_SERVO_OUTPUT_RAW:
                self._send_own("servo_output_raw")
            elif msg_id == MSG_ACTUATOR_OUTPUT_STATUS:
                self._send_own("actuator_output_status")
            elif msg_id == MSG_VFR_HUD:
                self._send_own("vfr_hud")

    def _message(self, kind: str) -> Any:
        t = self.time()
        usec = int(t * 1e6)
        if kind == "heartbeat":
            base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            if self.armed:
                base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
            return mavlink.MAVLink_heartbeat_message(
                mavlink.MAV_TYPE_FIXED_WING, AUTOPILOT_IDS[self.autopilot], base, 0, mavlink.MAV_STATE_ACTIVE, 3
            )
        if kind == "servo_output_raw":
            pwm = self.outputs(t)
            vals = [pwm.get(i, 0) for i in range(1, 17)]
            return mavlink.MAVLink_servo_output_raw_message(usec & 0xFFFFFFFF, 0, *vals)
        if kind == "actuator_output_status":
            pwm = self.outputs(t)
            n = min(max(pwm), 32)
            values = [float(pwm.get(i, 0)) for i in range(1, 33)]
            return mavlink.MAVLink_actuator_output_status_message(usec, n, values)
        if kind == "vfr_hud":
            try:
                aspd = float(self.airspeed_source(t))
            except Exception:  # noqa: BLE001
                log.exception("airspeed source failed")
                aspd = float("nan")
            return mavlink.MAVLink_vfr_hud_message(aspd, aspd, 0, 40, 100.0, 0.0)
        raise ValueError(kind)

    def _send_own(self, kind: str) -> None:
        msg = self._message(kind)
        for conn in list(self.links.values()):
            try:
                conn.mav.send(msg)
            except Exception:  # noqa: BLE001
                log.debug("send of %s failed", kind, exc_info=True)
        self.sent[msg.get_type()] = self.sent.get(msg.get_type(), 0) + 1

    def _receive(self) -> None:
        for name, conn in list(self.links.items()):
            for _ in range(200):
                try:
                    msg = conn.recv_msg()
                except Exception:  # noqa: BLE001 - e.g. ICMP port unreachable before the peer is up
                    break
                if msg is None:
                    break
                if msg.get_type() == "BAD_DATA":
                    continue
                try:
                    self._route(name, msg)
                except Exception:  # noqa: BLE001
                    log.exception("could not handle %s", msg.get_type())

    # ------------------------------------------------------------------ routing (as ArduPilot)

    def _route(self, link_name: str, msg: Any) -> None:
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if src == (SYSID, COMPID):
            return  # our own message looped back
        self.routes[src] = link_name
        target_system = getattr(msg, "target_system", -1) if "target_system" in msg.fieldnames else -1
        target_comp = getattr(msg, "target_component", -1) if "target_component" in msg.fieldnames else -1
        broadcast_system = target_system in (0, -1)
        broadcast_comp = target_comp in (0, -1)
        match_system = broadcast_system or target_system == SYSID
        process_locally = match_system and (broadcast_comp or target_comp == COMPID)
        sent_to: set[str] = set()
        if not (process_locally and not broadcast_system and not broadcast_comp):
            for (sysid, compid), out_name in list(self.routes.items()):
                if out_name == link_name or out_name in sent_to:
                    continue
                if broadcast_system or (
                    target_system == sysid and (broadcast_comp or target_comp == compid or not match_system)
                ):
                    conn = self.links.get(out_name)
                    if conn is not None:
                        conn.write(msg.get_msgbuf())
                        sent_to.add(out_name)
                        self.forwarded[msg.get_type()] = self.forwarded.get(msg.get_type(), 0) + 1
            if not sent_to and match_system:
                process_locally = True
        if broadcast_system:
            self._forward_to_gcs_outputs(link_name, msg, sent_to)
        if process_locally:
            self._handle(link_name, msg)

    def _forward_to_gcs_outputs(self, link_name: str, msg: Any, sent_to: set[str]) -> None:
        """Untargeted messages from the vehicle side reach every ground-station output, heard from or not."""
        if link_name in self.gcs_links:
            return
        for name in self.gcs_links:
            if name not in sent_to:
                self.links[name].write(msg.get_msgbuf())
                sent_to.add(name)
                self.forwarded[msg.get_type()] = self.forwarded.get(msg.get_type(), 0) + 1

    # ------------------------------------------------------------------ local handling

    def _handle(self, link_name: str, msg: Any) -> None:
        conn = self.links[link_name]
        mtype = msg.get_type()
        if mtype == "COMMAND_LONG":
            result = self._command(msg)
            self.commands.append(
                Command(
                    msg.command,
                    (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7),
                    (msg.get_srcSystem(), msg.get_srcComponent()),
                    result,
                )
            )
            conn.mav.command_ack_send(msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())
        elif mtype == "PARAM_REQUEST_LIST":
            for i, name in enumerate(self.params):
                self._param_value(conn, name, i)
        elif mtype == "PARAM_REQUEST_READ":
            names = list(self.params)
            pid = str(msg.param_id).split("\x00")[0]
            if msg.param_index == -1 and pid in self.params:
                self._param_value(conn, pid, names.index(pid))
            elif 0 <= msg.param_index < len(names):
                self._param_value(conn, names[msg.param_index], msg.param_index)
        elif mtype == "FILE_TRANSFER_PROTOCOL":
            self._ftp(conn, msg)
        elif mtype == "PARAM_SET":
            pid = str(msg.param_id).split("\x00")[0]
            if pid in self.output_functions.values:
                value = self.output_functions.decode(pid, msg.param_value)
                self.output_functions.values[pid] = value
                self.params[pid] = float(value)
                self._param_value(conn, pid, list(self.params).index(pid))
            elif pid in self.params and math.isfinite(msg.param_value):
                self.params[pid] = float(msg.param_value)
                self._param_value(conn, pid, list(self.params).index(pid))

    def _ftp_params(self) -> list[PackedParam]:
        return [PackedParam(name, value) for name, value in self.params.items()]

    def _ftp(self, conn: Any, msg: Any) -> None:
        """MAVLink FTP: ArduPilot serves its parameters as @PARAM/param.pck; PX4 has no such file."""
        sender = (msg.get_srcSystem(), msg.get_srcComponent())
        if self.autopilot == "ardupilot":
            replies = self._ftp_server.handle(sender, msg.payload)
        else:
            req = FtpOp.parse(msg.payload)
            if req.opcode in (OP_ACK, OP_NAK):  # a reply: nothing to answer
                return
            replies = [FtpOp(req.seq + 1, req.session, OP_NAK, 1, req.opcode, 0, req.offset,
                             bytes([ERR_FILE_NOT_FOUND])).pack()]
        for payload in replies:
            conn.mav.file_transfer_protocol_send(0, sender[0], sender[1], payload)

    def _param_value(self, conn: Any, name: str, index: int) -> None:
        value, ptype = (self.output_functions.encode(name) if name in self.output_functions.values
                        else (self.params[name], mavlink.MAV_PARAM_TYPE_REAL32))
        conn.mav.param_value_send(name.encode(), value, ptype, len(self.params), index)

    def _command(self, msg: Any) -> int:
        cmd = msg.command
        if cmd == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            msg_id = int(msg.param1)
            if msg_id not in STREAMABLE[self.autopilot]:
                return mavlink.MAV_RESULT_FAILED
            interval_us = msg.param2
            with self._lock:
                if msg_id == MSG_HEARTBEAT:
                    return mavlink.MAV_RESULT_ACCEPTED
                if interval_us < 0:
                    self.intervals.pop(msg_id, None)
                    self._next_due.pop(msg_id, None)
                else:
                    seconds = 1.0 / DEFAULT_RATE_HZ if interval_us == 0 else max(interval_us, 1000.0) * 1e-6
                    self.intervals[msg_id] = seconds
                    self._next_due[msg_id] = time.monotonic()
            log.info("message %d interval set to %.0f us", msg_id, interval_us)
            return mavlink.MAV_RESULT_ACCEPTED
        if cmd == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:  # from a ground station: no pre-arm checks to fail
            if msg.param1 not in (0.0, 1.0):
                return mavlink.MAV_RESULT_DENIED
            self.set_armed(msg.param1 == 1.0)
            log.info("%s by COMMAND_LONG from %d/%d", "armed" if self.armed else "disarmed", msg.get_srcSystem(),
                     msg.get_srcComponent())
            return mavlink.MAV_RESULT_ACCEPTED
        if cmd == mavlink.MAV_CMD_DO_SET_SERVO:
            if self.autopilot != "ardupilot":
                return mavlink.MAV_RESULT_UNSUPPORTED
            ch, pwm = int(msg.param1), msg.param2
            if not 1 <= ch <= 16 or not math.isfinite(pwm):
                return mavlink.MAV_RESULT_DENIED
            self.servo_commands[ch] = float(pwm)
            return mavlink.MAV_RESULT_ACCEPTED
        if cmd == mavlink.MAV_CMD_DO_SET_ACTUATOR:
            if self.autopilot != "px4":
                return mavlink.MAV_RESULT_UNSUPPORTED
            if int(msg.param7) != 0:
                return mavlink.MAV_RESULT_DENIED  # PX4 handles only the first set of six
            values = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6)
            for i, v in enumerate(values, start=1):
                if math.isfinite(v):
                    self.actuator_commands[i] = max(-1.0, min(1.0, float(v)))
            return mavlink.MAV_RESULT_ACCEPTED
        return mavlink.MAV_RESULT_UNSUPPORTED


# ---------------------------------------------------------------------- command line


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m warpbridge.sitl.mock_autopilot",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--fc-port", type=int, help="UDP port on 127.0.0.1 where the bridge listens")
    p.add_argument("--fc", help="pymavlink connection string to the bridge instead of --fc-port")
    p.add_argument("--gcs", action="append", default=[], metavar="OUTPUT",
                   help="ground-station output, repeatable: udp:HOST:PORT (send there, reply to the sender), "
                        "udpin:HOST:PORT (listen), tcp:/tcpin:HOST:PORT; a plain port means udp:127.0.0.1:PORT")
    p.add_argument("--gcs-port", type=int, action="append", default=[],
                   help="UDP port on 127.0.0.1 where a ground station listens (same as --gcs udp:127.0.0.1:PORT)")
    p.add_argument("--autopilot", choices=sorted(AUTOPILOT_IDS), default="ardupilot")
    p.add_argument("--scenario", default="sine", help="sine | steps | hold | module:attr (callable t -> {ch: us})")
    p.add_argument("--roll-file", help="CSV with columns t,ch1,ch2,... [,airspeed] instead of --scenario")
    p.add_argument("--loop", action="store_true", help="repeat the roll file")
    p.add_argument("--amplitude", type=float, default=300.0, help="sine/steps amplitude, us")
    p.add_argument("--freq", type=float, default=0.5, help="sine/steps frequency, Hz")
    p.add_argument("--airspeed", type=float, default=12.0, help="VFR_HUD airspeed, m/s")
    p.add_argument("--armed", action="store_true",
                   help="start armed (a ground station arms and disarms it with MAV_CMD_COMPONENT_ARM_DISARM too)")
    p.add_argument("--output-function", action="append", default=[], metavar="CH=ROLE",
                   help="what output CH does (aileron, elevator, rudder, throttle, disabled, left_elevon, ...); "
                        "default 1,2 aileron, 3 throttle, 4 rudder")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=float, help="stop after this many seconds")
    p.add_argument("--stall-at", type=float, help="stop streaming at this time (s)")
    p.add_argument("--stall-for", type=float, default=2.0, help="for this long (s)")
    p.add_argument("--stall-forget", action="store_true", help="forget requested rates (like a reboot)")
    p.add_argument("--stall-heartbeat", action="store_true", help="stop the heartbeat too")
    p.add_argument("-v", "--verbose", action="store_true")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="mock: %(message)s")
    fc = args.fc or args.fc_port
    if fc is None:
        print("mock_autopilot: give --fc-port or --fc", file=sys.stderr)
        return 2
    airspeed_source: AirspeedSource = lambda t: args.airspeed  # noqa: E731
    if args.roll_file:
        roll: RollSource = CsvRoll(args.roll_file, loop=args.loop)
        if roll.airspeed_column is not None:
            airspeed_source = roll.airspeed
    else:
        roll = load_scenario(args.scenario)
        if isinstance(roll, SineRoll):
            roll.amplitude_us, roll.freq_hz = args.amplitude, args.freq
    try:
        roles = parse_output_functions(args.output_function)
        OutputFunctionParams(args.autopilot, roles)  # checks the roles
    except ValueError as e:
        print(f"mock_autopilot: {e}", file=sys.stderr)
        return 2
    try:
        outputs = [gcs_output_string(int(g) if g.isdigit() else g) for g in args.gcs] + list(args.gcs_port)
    except ValueError as e:
        print(f"mock_autopilot: --gcs {e}", file=sys.stderr)
        return 2
    mock = MockAutopilot(
        fc,
        outputs,
        autopilot=args.autopilot,
        roll_source=roll,
        airspeed_source=airspeed_source,
        armed=args.armed,
        seed=args.seed,
        output_functions=roles,
    )
    signal.signal(signal.SIGTERM, lambda *_: mock._stop.set())
    if args.stall_at is not None:
        timer = threading.Timer(
            args.stall_at,
            mock.pause_streams,
            args=(args.stall_for,),
            kwargs={"forget": args.stall_forget, "heartbeat": not args.stall_heartbeat},
        )
        timer.daemon = True
        timer.start()
    try:
        mock.run(args.duration)
    except KeyboardInterrupt:
        pass
    finally:
        mock.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
