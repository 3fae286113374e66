"""The MAVLink link to the flight controller (FC): ``FcLink``.

It takes a pymavlink connection string (``/dev/ttyACM0,921600``,
``udpin:0.0.0.0:14550``, ``udpout:10.0.0.1:14550``, ``tcp:127.0.0.1:5760``) and
speaks as component 191 (MAV_COMP_ID_ONBOARD_COMPUTER) on the FC's system id,
learned from the first autopilot HEARTBEAT (component 1, autopilot not
MAV_AUTOPILOT_INVALID) unless forced. It sends its own HEARTBEAT
(MAV_TYPE_ONBOARD_CONTROLLER / MAV_AUTOPILOT_INVALID) at 1 Hz, asks the FC for the
servo outputs (SERVO_OUTPUT_RAW on ArduPilot; ACTUATOR_OUTPUT_STATUS and
SERVO_OUTPUT_RAW on PX4, whichever arrives) and VFR_HUD with
MAV_CMD_SET_MESSAGE_INTERVAL, and asks again when a stream stops. ``poll()``
never blocks and never raises: it drains what is pending, updates ``servo_pwm``,
``servo_time``, ``airspeed`` and ``armed``, and returns the messages it did not
consume (PARAM_*, COMMAND_LONG, ...) for the parameter server. Absurd values are
counted and marked invalid; a lost serial port or TCP peer is reopened with
back-off. Every send is non-blocking (a full serial buffer drops the frame).

Servo channel numbering is 1-based. SERVO_OUTPUT_RAW carries 16 outputs per
message and ``port`` counts sets of 16 (ArduPilot sends outputs 17-32 as port 1,
PX4 its second output group as port 1). ACTUATOR_OUTPUT_STATUS ``active`` is a
bitmask in the message definition but PX4 fills it with the number of outputs;
``actuator_active="auto"`` reads it as a count from PX4 and as a mask otherwise.

Hostile input: bytes that do not parse are counted (``bad_data``) and never
close the link (only an I/O error does); pymavlink's per-sender bookkeeping
(which grows with every new message type, instance and sender a fuzzer invents)
is replaced by a constant-size one. On UDP each datagram is parsed on its own (a
MAVLink frame never spans datagrams), so a truncated frame cannot swallow the
valid ones that follow, and the set of UDP peers pymavlink answers is kept to
the few most recent. With ``signing`` (``bridge.signing``) every
frame sent is signed and unsigned or wrongly signed frames are dropped and
counted (``unsigned_refused``, ``bad_signature``, ``refused``), except the FC's
own stream when the policy accepts it unsigned; dropped frames never reach the
parameter server.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import serial

from warpbridge.bridge.mavlink_env import mavlink, mavutil
from warpbridge.bridge.signing import Signer, SigningPolicy
from warpbridge.hw.base import lock_exclusive, open_error_text

log = logging.getLogger(__name__)

COMPONENT_ID = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER  # 191
FC_COMPONENT_ID = mavlink.MAV_COMP_ID_AUTOPILOT1  # 1
MSG_SERVO_OUTPUT_RAW = mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW  # 36
MSG_ACTUATOR_OUTPUT_STATUS = mavlink.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS  # 375
MSG_VFR_HUD = mavlink.MAVLINK_MSG_ID_VFR_HUD  # 74

PWM_VALID_US = (500.0, 2600.0)  # anything outside is not a servo pulse
AIRSPEED_VALID_MS = (-5.0, 150.0)
NAMED_FLOAT_MAX = 10  # NAMED_VALUE_FLOAT name field
STATUSTEXT_CHUNK = 50  # STATUSTEXT text field
STATUSTEXT_MAX_CHUNKS = 4
FC_TIMEOUT_S = 3.0  # FC heartbeat older than this: FC lost
_MAX_MESSAGES_PER_POLL = 500
_BACKOFF_S = (0.5, 1.0, 2.0, 4.0, 8.0)
_MAX_TYPE_KEYS = 64  # counters.by_type / refused: further types are counted under "OTHER"
_MAX_WARN_KEYS = 64
_MAX_UDP_PEERS = 4  # udpin answers every peer it heard: keep the most recent few
_UDP_PEER_TIMEOUT_S = 10.0
REFUSAL_TEXT_S = 10.0  # at most one STATUSTEXT about refused (unsigned) frames per this many seconds
IFLAG_SIGNED = mavlink.MAVLINK_IFLAG_SIGNED
# what the FC itself sends us; with signing these may stay unsigned (policy) when from the FC
FC_STREAM_TYPES = frozenset(
    {"HEARTBEAT", "SERVO_OUTPUT_RAW", "ACTUATOR_OUTPUT_STATUS", "VFR_HUD", "COMMAND_ACK"}
)

_AUTOPILOTS = {
    mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA: "ardupilot",
    mavlink.MAV_AUTOPILOT_PX4: "px4",
}
_NOT_VEHICLES = {
    mavlink.MAV_TYPE_GCS,
    mavlink.MAV_TYPE_GIMBAL,
    mavlink.MAV_TYPE_ADSB,
    mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
}


class LinkDisconnected(ConnectionError):
    """The connection to the FC went away (serial unplugged, TCP peer closed)."""


def split_connection(connection: str, default_baud: int = 921600) -> tuple[str, int | None]:
    """Split ``device,baud`` for serial ports; network strings come back with baud None."""
    prefixes = ("udp", "tcp", "mcast:", "ws:", "wss:", "wsserver:", "uds:", "unix:")
    if connection.startswith(prefixes):
        return connection, None
    if "," in connection:
        device, _, baud = connection.rpartition(",")
        try:
            return device, int(baud)
        except ValueError as e:
            raise ValueError(f"bad baud rate in {connection!r}") from e
    return connection, default_baud


def _enum_name(enum: str, value: int) -> str:
    entry = mavlink.enums.get(enum, {}).get(value)
    return f"{entry.name} ({value})" if entry is not None else str(value)


def _finite(x: Any) -> bool:
    return isinstance(x, int | float) and math.isfinite(x)


@dataclass
class LinkCounters:
    """Message counters, for the log and for tests."""

    received: int = 0
    datagrams: int = 0  # UDP datagrams read
    bad_data: int = 0  # bytes that did not parse as MAVLink
    ignored: int = 0  # valid MAVLink from a sender we do not listen to
    invalid_values: int = 0  # absurd servo PWM, NaN airspeed, empty masks ...
    servo_messages: int = 0
    vfr_hud: int = 0
    fc_heartbeats: int = 0
    sent: int = 0
    send_errors: int = 0
    stream_requests: int = 0
    reconnects: int = 0
    parse_errors: int = 0  # the parser raised (never closes the link)
    unsigned_refused: int = 0  # signing on: unsigned frames dropped
    bad_signature: int = 0  # signing on: frames with a wrong, replayed or stale signature dropped
    by_type: dict[str, int] = field(default_factory=dict)
    refused: dict[str, int] = field(default_factory=dict)  # dropped by the signing policy, per type


def _count(table: dict[str, int], key: str) -> None:
    if key not in table and len(table) >= _MAX_TYPE_KEYS:
        key = "OTHER"
    table[key] = table.get(key, 0) + 1


def _lock_serial(conn: Any) -> None:
    """Hold a serial FC port exclusively, as the Maestro's (``hw.base.lock_exclusive``); when another
    process holds it, the connection is closed and the ``BlockingIOError`` raised."""
    port = getattr(conn, "port", None)
    if not isinstance(port, serial.Serial):
        return
    try:
        lock_exclusive(port.fileno())
    except OSError:
        conn.close()
        raise


def _post_message(msg: Any) -> None:
    """Constant-memory stand-in for ``mavfile.post_message`` (we keep our own state)."""
    msg._posted = True
    msg._timestamp = time.time()


class FcLink:
    """MAVLink link to the flight controller; see the module docstring."""

    def __init__(
        self,
        connection: str,
        *,
        servo_rate_hz: float = 50.0,
        airspeed_rate_hz: float = 10.0,
        rerequest_s: float = 1.0,
        source_system: int | None = None,
        component_id: int = COMPONENT_ID,
        heartbeat_hz: float = 1.0,
        baud: int = 921600,
        actuator_active: str = "auto",
        signing: SigningPolicy | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if actuator_active not in ("auto", "mask", "count"):
            raise ValueError("actuator_active must be 'auto', 'mask' or 'count'")
        if source_system == 0:
            source_system = None  # 0 = learn it from the FC
        if source_system is not None and not 1 <= source_system <= 255:
            raise ValueError("source_system must be 1..255 (or 0/None to learn it)")
        self.connection = connection
        self.device, self.baud = split_connection(connection, baud)
        self.open_error: str | None = None  # why the connection last failed to open (None: it opened, or not tried)
        self.servo_rate_hz = float(servo_rate_hz)
        self.airspeed_rate_hz = float(airspeed_rate_hz)
        self.rerequest_s = float(rerequest_s)
        self.forced_system = source_system
        self.component_id = int(component_id)
        self.heartbeat_period = 1.0 / heartbeat_hz if heartbeat_hz > 0 else math.inf
        self.actuator_active = actuator_active
        self.signing = signing
        self._signer = Signer(signing.key) if signing is not None else None
        self.clock = clock

        self.mav: Any = None  # the pymavlink connection (mavutil.mavfile) while open
        self.system_id: int | None = source_system  # ours == the FC's
        self.autopilot: str | None = None  # "ardupilot" | "px4" | "generic"
        self.fc_heartbeat_time: float | None = None
        self.armed = False
        self.servo_pwm: dict[int, float] = {}  # valid outputs only, channel (1-based) -> us
        self.servo_raw: dict[int, float] = {}  # last value of every output, valid or not
        self.servo_invalid: set[int] = set()
        self.servo_time: float | None = None
        self.servo_fc_time: float | None = None  # the FC's stamp of the latest servo message (s since its boot)
        self.airspeed: float | None = None
        self.airspeed_time: float | None = None
        self.acks: dict[int, int] = {}  # command -> last MAV_RESULT
        self.counters = LinkCounters()

        self._boot = clock()
        self._next_heartbeat = 0.0
        self._reconnect_at = 0.0
        self._backoff_index = 0
        self._stream_asked: dict[str, float] = {}  # stream name -> time last asked
        self._stream_seen: dict[str, float] = {}  # stream name -> time last received
        self._statustext_id = 0
        self._warned: set[str] = set()
        self._refusal_text_at = -math.inf
        self._refusals_logged: set[tuple[str, str, int, int]] = set()
        self._fc_silent_logged = False
        self._stream_silent_logged: set[str] = set()

    # ------------------------------------------------------------------ connection

    @property
    def is_open(self) -> bool:
        return self.mav is not None

    @property
    def ready(self) -> bool:
        """Open and with a system id to speak as."""
        return self.mav is not None and self.system_id is not None

    @property
    def fc_alive(self) -> bool:
        return self.fc_heartbeat_time is not None and self.clock() - self.fc_heartbeat_time < FC_TIMEOUT_S

    def open(self) -> bool:
        """Try once to open the connection; False (and back-off) if it cannot be opened now."""
        if self.mav is not None:
            return True
        try:
            conn = mavutil.mavlink_connection(
                self.device,
                baud=self.baud or 115200,
                source_system=self.system_id or 0,
                source_component=self.component_id,
                autoreconnect=False,
                retries=0,
            )
            _lock_serial(conn)
        except Exception as e:  # serial.SerialException, OSError, socket errors, the port in use
            delay = _BACKOFF_S[min(self._backoff_index, len(_BACKOFF_S) - 1)]
            self._backoff_index += 1
            self._reconnect_at = self.clock() + delay
            self.open_error = open_error_text(e)
            self._warn_once(f"open:{type(e).__name__}", f"cannot open {self.connection}: {self.open_error}; retrying")
            return False
        self._prepare(conn)
        self.mav = conn
        self.open_error = None
        self._backoff_index = 0
        self._stream_asked.clear()
        self._warned = {w for w in self._warned if not w.startswith("open:")}
        log.info("opened %s", self.connection)
        return True

    def _prepare(self, conn: Any) -> None:
        def disconnected() -> None:
            raise LinkDisconnected(f"{self.connection} closed by peer")

        # pymavlink's TCP link prints and retries on EOF/reset; we reconnect ourselves.
        conn.handle_eof = disconnected
        conn.handle_disconnect = disconnected
        conn.post_message = _post_message
        if self._signer is not None:
            self._signer.install(conn)
        port = getattr(conn, "port", None)
        if hasattr(port, "write_timeout"):
            try:
                port.write_timeout = 0  # pyserial: non-blocking writes
            except Exception:  # noqa: BLE001 - some backends refuse; writes then block briefly
                log.debug("could not make writes non-blocking on %s", self.connection)
        if self.system_id is not None:
            conn.mav.srcSystem = self.system_id
        conn.mav.srcComponent = self.component_id

    def close(self) -> None:
        if self.mav is not None:
            try:
                self.mav.close()
            except Exception:  # noqa: BLE001
                pass
            self.mav = None

    def _lost(self, reason: str) -> None:
        log.warning("link to FC lost (%s); reconnecting", reason)
        self.close()
        self.counters.reconnects += 1
        delay = _BACKOFF_S[min(self._backoff_index, len(_BACKOFF_S) - 1)]
        self._backoff_index += 1
        self._reconnect_at = self.clock() + delay

    def connect(self, timeout: float = 10.0) -> bool:
        """Open the link and wait (blocking, for start-up only) for the FC's heartbeat."""
        deadline = self.clock() + timeout
        while True:
            self.poll()
            if self.fc_heartbeat_time is not None and self.system_id is not None:
                return True
            now = self.clock()
            if now >= deadline:
                return False
            if self.mav is not None:
                try:
                    self.mav.select(min(0.1, deadline - now))
                except Exception:  # noqa: BLE001
                    time.sleep(0.05)
            else:
                time.sleep(min(0.1, deadline - now))

    # ------------------------------------------------------------------ receive

    def poll(self) -> list[Any]:
        """Drain pending messages without blocking; return the ones not consumed here."""
        now = self.clock()
        if self.mav is None:
            if now < self._reconnect_at or not self.open():
                return []
        if self._signer is not None and not self._signer.installed_on(self.mav):
            self._signer.install(self.mav)  # pymavlink replaced its protocol object
        out: list[Any] = []
        n = 0
        while n < _MAX_MESSAGES_PER_POLL:
            try:
                batch = self._receive()
            except OSError as e:  # unplugged serial (SerialException), reset socket, peer closed
                self._lost(f"{type(e).__name__}: {e}")
                return out
            except Exception as e:  # noqa: BLE001 - the parser choked on hostile bytes: drop them
                self.counters.parse_errors += 1
                self._reset_parser()
                self._warn_once(f"parse:{type(e).__name__}", f"MAVLink parser error ({e}); input dropped")
                n += 1
                continue
            if not batch:
                break
            n += len(batch)
            for msg in batch:
                try:
                    if self._handle(msg, self.clock()):
                        out.append(msg)
                except Exception:  # noqa: BLE001 - a message we failed to understand
                    self.counters.invalid_values += 1
                    log.exception("could not handle %s", msg.get_type())
        if self.mav is not None and getattr(self.mav, "portdead", False):
            self._lost("write failed")
            return out
        self._periodic(self.clock())
        return out

    def _receive(self) -> list[Any]:
        """What is pending now: one datagram's messages on UDP, else at most one message."""
        conn = self.mav
        if isinstance(conn, mavutil.mavudp):
            data = conn.recv()
            if not data:
                return []
            self.counters.datagrams += 1
            if conn.udp_server:
                self._prune_udp_peers(conn)
            try:
                msgs = conn.mav.parse_buffer(data) or []
            finally:
                self._reset_parser()  # an incomplete frame at the end of a datagram is garbage
            for m in msgs:
                _post_message(m)
            return msgs
        msg = conn.recv_msg()
        return [] if msg is None else [msg]

    @staticmethod
    def _prune_udp_peers(conn: Any) -> None:
        conn.timeout = _UDP_PEER_TIMEOUT_S
        clients = getattr(conn, "clients", None)
        alive = getattr(conn, "clients_last_alive", None)
        if clients is None or alive is None or len(clients) <= _MAX_UDP_PEERS:
            return
        keep = sorted(clients, key=lambda a: alive.get(a, 0.0))[-_MAX_UDP_PEERS:]
        for addr in list(clients):
            if addr not in keep:
                clients.discard(addr)
                alive.pop(addr, None)

    def _reset_parser(self) -> None:
        mav = getattr(self.mav, "mav", None)
        if mav is not None:
            mav.buf = bytearray()
            mav.buf_index = 0
            mav.expected_length = mavlink.HEADER_LEN_V1 + 2

    def _handle(self, msg: Any, now: float) -> bool:
        mtype = msg.get_type()
        c = self.counters
        if mtype == "BAD_DATA":
            c.bad_data += 1
            return False
        c.received += 1
        src_sys, src_comp = msg.get_srcSystem(), msg.get_srcComponent()
        if msg.get_msgId() < 0 or mtype.startswith("UNKNOWN"):
            mtype = "UNKNOWN"
        _count(c.by_type, mtype)
        if self._signer is not None and not getattr(msg, "_signed", False):
            if not self._unsigned_ok(mtype, src_sys, src_comp):
                self._refuse_unsigned(msg, mtype, src_sys, src_comp, now)
                return False
        if mtype == "HEARTBEAT":
            if not self._is_fc_heartbeat(msg):
                return False
            if self.system_id is None:
                self._adopt_system(src_sys)
            if src_sys != self.system_id:
                c.ignored += 1
                return False
            self._fc_heartbeat(msg, now)
            return False
        from_fc = src_sys == self.system_id and src_comp == FC_COMPONENT_ID
        if mtype == "SERVO_OUTPUT_RAW":
            if from_fc:
                self._servo_output_raw(msg, now)
            else:
                c.ignored += 1
            return False
        if mtype == "ACTUATOR_OUTPUT_STATUS":
            if from_fc:
                self._actuator_output_status(msg, now)
            else:
                c.ignored += 1
            return False
        if mtype == "VFR_HUD":
            if from_fc:
                self._vfr_hud(msg, now)
            else:
                c.ignored += 1
            return False
        if mtype == "COMMAND_ACK" and self._is_for_us(msg):
            self._command_ack(msg)
            return False
        return True

    def _unsigned_ok(self, mtype: str, src_sys: int, src_comp: int) -> bool:
        """Signing on: an unsigned frame passes only if it is the FC's stream and the policy allows it."""
        if self.signing is None or not self.signing.accept_unsigned_from_fc:
            return False
        if mtype not in FC_STREAM_TYPES or src_comp != FC_COMPONENT_ID:
            return False
        return src_sys == (self.system_id if self.system_id is not None else src_sys)

    def _refuse_unsigned(self, msg: Any, mtype: str, src_sys: int, src_comp: int, now: float) -> None:
        c = self.counters
        header = getattr(msg, "_header", None)
        signed = header is not None and header.incompat_flags & IFLAG_SIGNED
        what = "badly signed" if signed else "unsigned"
        if signed:
            c.bad_signature += 1
        else:
            c.unsigned_refused += 1
        _count(c.refused, mtype)
        key = (what, mtype, src_sys, src_comp)
        if key not in self._refusals_logged and len(self._refusals_logged) < _MAX_WARN_KEYS:
            self._refusals_logged.add(key)
            log.warning("refused %s %s from %d/%d", what, mtype, src_sys, src_comp)
        if now - self._refusal_text_at >= REFUSAL_TEXT_S and mtype not in FC_STREAM_TYPES:
            self._refusal_text_at = now
            self.send_statustext(mavlink.MAV_SEVERITY_WARNING, f"WB refused {what} {mtype} from {src_sys}")

    def _is_fc_heartbeat(self, msg: Any) -> bool:
        if msg.get_srcComponent() != FC_COMPONENT_ID:
            return False
        if msg.autopilot == mavlink.MAV_AUTOPILOT_INVALID or msg.type in _NOT_VEHICLES:
            return False
        return self.forced_system is None or msg.get_srcSystem() == self.forced_system

    def _is_for_us(self, msg: Any) -> bool:
        ts = getattr(msg, "target_system", 0)
        tc = getattr(msg, "target_component", 0)
        return ts in (0, self.system_id) and tc in (0, self.component_id)

    def _adopt_system(self, sysid: int) -> None:
        self.system_id = sysid
        if self.mav is not None:
            self.mav.mav.srcSystem = sysid
        log.info("FC is system %d; speaking as %d/%d", sysid, sysid, self.component_id)

    def _fc_heartbeat(self, msg: Any, now: float) -> None:
        self.counters.fc_heartbeats += 1
        was_alive = self.fc_alive
        if self._fc_silent_logged:
            log.info("FC heartbeat back after %.1f s", now - (self.fc_heartbeat_time or now))
            self._fc_silent_logged = False
        self.fc_heartbeat_time = now
        armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
        if armed != self.armed or self.counters.fc_heartbeats == 1:
            log.info("FC %s", "armed" if armed else "disarmed")
        self.armed = armed
        autopilot = _AUTOPILOTS.get(msg.autopilot, "generic")
        if autopilot != self.autopilot:
            log.info("FC autopilot: %s (MAV_AUTOPILOT %d, vehicle type %d)", autopilot, msg.autopilot, msg.type)
            self.autopilot = autopilot
            self._stream_asked.clear()
        if not was_alive:
            self._stream_asked.clear()  # FC (re)appeared: ask for streams at once

    def _set_servo(self, channel: int, value: float) -> bool:
        self.servo_raw[channel] = value
        if _finite(value) and PWM_VALID_US[0] <= value <= PWM_VALID_US[1]:
            self.servo_pwm[channel] = float(value)
            self.servo_invalid.discard(channel)
            return True
        self.servo_pwm.pop(channel, None)
        self.servo_invalid.add(channel)
        return False

    def _servo_output_raw(self, msg: Any, now: float) -> None:
        port = int(msg.port)
        # MAVLink 1 senders and 8-output boards leave the extension fields 9..16 at 0
        n = 16 if any(getattr(msg, f"servo{i}_raw", 0) for i in range(9, 17)) else 8
        bad = 0
        for i in range(1, n + 1):
            value = getattr(msg, f"servo{i}_raw", 0)
            # 0 is how ArduPilot reports a disabled output: invalid, but not an error
            if not self._set_servo(port * 16 + i, value) and value != 0:
                bad += 1
        self._servo_seen(now, bad, msg.time_usec)

    def _actuator_output_status(self, msg: Any, now: float) -> None:
        active = int(msg.active)
        values = list(msg.actuator)
        mode = self.actuator_active
        if mode == "auto":
            mode = "count" if self.autopilot == "px4" else "mask"
        if mode == "count":
            channels = range(1, min(active, len(values)) + 1) if 0 <= active else range(0)
        else:
            channels = [i + 1 for i in range(len(values)) if active & (1 << i)]
        if not channels:
            self.counters.invalid_values += 1
            self._warn_once("actuator-empty", "ACTUATOR_OUTPUT_STATUS with no active outputs")
            self._stream_seen["servo"] = now  # the stream is alive, only empty
            return
        bad = sum(1 for ch in channels if not self._set_servo(ch, values[ch - 1]) and values[ch - 1] != 0)
        self._servo_seen(now, bad, msg.time_usec)

    def _servo_seen(self, now: float, bad: int, fc_usec: Any = None) -> None:
        self.counters.servo_messages += 1
        self.counters.invalid_values += bad
        if bad:
            self._warn_once("servo-bad", f"FC sent {bad} absurd servo value(s); marked invalid")
        self.servo_time = now
        if isinstance(fc_usec, int) and fc_usec > 0:  # SERVO_OUTPUT_RAW's is 32 bits: wraps after 71.6 min
            self.servo_fc_time = fc_usec * 1e-6
        self._stream_seen["servo"] = now

    def _vfr_hud(self, msg: Any, now: float) -> None:
        self.counters.vfr_hud += 1
        self._stream_seen["airspeed"] = now
        v = msg.airspeed
        if _finite(v) and AIRSPEED_VALID_MS[0] <= v <= AIRSPEED_VALID_MS[1]:
            self.airspeed = float(v)
            self.airspeed_time = now
        else:
            self.counters.invalid_values += 1
            self._warn_once("airspeed-bad", f"FC sent absurd airspeed {v!r}; ignored")

    def _command_ack(self, msg: Any) -> None:
        self.acks[msg.command] = msg.result
        if msg.result not in (mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_IN_PROGRESS):
            key = f"ack:{msg.command}:{msg.result}"
            if key not in self._warned:  # a refusal repeated every re-request is logged once
                self._warned.add(key)
                log.warning("FC refused command %s (result %s)", _enum_name("MAV_CMD", msg.command),
                            _enum_name("MAV_RESULT", msg.result))

    # ------------------------------------------------------------------ periodic

    def _periodic(self, now: float) -> None:
        if self.system_id is None or self.mav is None:
            return
        if now >= self._next_heartbeat:
            self._next_heartbeat = now + self.heartbeat_period
            self._send(
                "heartbeat_send",
                mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
                mavlink.MAV_AUTOPILOT_INVALID,
                0,
                0,
                mavlink.MAV_STATE_ACTIVE,
            )
        if self.fc_heartbeat_time is None:
            return
        if not self._fc_silent_logged and now - self.fc_heartbeat_time >= FC_TIMEOUT_S:
            self._fc_silent_logged = True
            log.warning("no heartbeat from the FC for %.0f s", now - self.fc_heartbeat_time)
        if self.servo_rate_hz > 0:
            ids = [MSG_SERVO_OUTPUT_RAW]
            if self.autopilot == "px4":
                ids = [MSG_ACTUATOR_OUTPUT_STATUS, MSG_SERVO_OUTPUT_RAW]
            self._keep_stream("servo", ids, self.servo_rate_hz, now)
        if self.airspeed_rate_hz > 0:
            self._keep_stream("airspeed", [MSG_VFR_HUD], self.airspeed_rate_hz, now)

    def _keep_stream(self, name: str, ids: list[int], rate_hz: float, now: float) -> None:
        seen = self._stream_seen.get(name)
        asked = self._stream_asked.get(name)
        if asked is not None and now - asked < self.rerequest_s:
            return  # asked recently: give the FC time to answer
        if seen is not None and now - seen < self.rerequest_s and asked is not None:
            if name in self._stream_silent_logged:
                self._stream_silent_logged.discard(name)
                log.info("%s stream flowing again", name)
            return  # flowing
        names = " and ".join(mavlink.mavlink_map[i].msgname if i in mavlink.mavlink_map else str(i) for i in ids)
        if asked is not None:
            if name not in self._stream_silent_logged:  # once per silence, not every re-request
                self._stream_silent_logged.add(name)
                log.warning("%s stream (%s) silent for %.1f s; asking the FC again every %.1f s",
                            name, names, now - (seen if seen is not None else asked), self.rerequest_s)
        else:
            log.info("asked the FC for %s at %g Hz", names, rate_hz)
        self._stream_asked[name] = now
        for msg_id in ids:
            self.request_message_interval(msg_id, rate_hz)

    def set_servo_rate(self, rate_hz: float) -> None:
        """Change the servo output rate and ask the FC for it now (both messages on PX4)."""
        self.servo_rate_hz = float(rate_hz)
        self._stream_asked.pop("servo", None)
        self._periodic(self.clock())

    def request_message_interval(self, msg_id: int, rate_hz: float) -> None:
        """Send MAV_CMD_SET_MESSAGE_INTERVAL for ``msg_id`` at ``rate_hz`` (<= 0: stop it)."""
        interval_us = 1e6 / rate_hz if rate_hz > 0 else -1
        self.counters.stream_requests += 1
        self.command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, interval_us, 0, 0, 0, 0, 0)

    # ------------------------------------------------------------------ send

    def _send(self, method: str, *args: Any) -> bool:
        if self.mav is None or self.system_id is None:
            return False
        try:
            getattr(self.mav.mav, method)(*args)
        except Exception as e:  # noqa: BLE001 - a send must never stop the control loop
            self.counters.send_errors += 1
            self._warn_once(f"send:{method}", f"{method} failed: {e}")
            return False
        self.counters.sent += 1
        return True

    def send(self, msg: Any) -> bool:
        """Send a ready-made pymavlink message object; False if not sent."""
        if self.mav is None or self.system_id is None:
            return False
        try:
            self.mav.mav.send(msg)
        except Exception as e:  # noqa: BLE001
            self.counters.send_errors += 1
            self._warn_once(f"send:{msg.get_type()}", f"sending {msg.get_type()} failed: {e}")
            return False
        self.counters.sent += 1
        return True

    def command_long(self, command: int, *params: float, target_component: int = FC_COMPONENT_ID) -> bool:
        """Send COMMAND_LONG to the FC (up to 7 params, missing ones 0); the ACK lands in ``acks``."""
        return self.command_long_send(self.system_id or 0, target_component, command, 0, *params)

    def command_long_send(
        self, target_system: int, target_component: int, command: int, confirmation: int, *params: float
    ) -> bool:
        """pymavlink's ``command_long_send`` signature, so the link can be handed to ``hw`` as a sender."""
        p = [float(x) for x in params][:7]
        p += [0.0] * (7 - len(p))
        return self._send("command_long_send", target_system, target_component, command, confirmation, *p)

    def time_boot_ms(self) -> int:
        return int((self.clock() - self._boot) * 1000) & 0xFFFFFFFF

    def send_named_float(self, name: str, value: float) -> bool:
        """NAMED_VALUE_FLOAT; ``name`` must be ASCII of at most 10 characters."""
        raw = name.encode("ascii")
        if not raw or len(raw) > NAMED_FLOAT_MAX:
            raise ValueError(f"NAMED_VALUE_FLOAT name {name!r} must be 1..{NAMED_FLOAT_MAX} characters")
        return self._send("named_value_float_send", self.time_boot_ms(), raw, float(value))

    def send_statustext(self, severity: int, text: str) -> bool:
        """STATUSTEXT; texts over 50 characters go as MAVLink 2 chunks sharing one id."""
        raw = text.encode("ascii", "replace")[: STATUSTEXT_CHUNK * STATUSTEXT_MAX_CHUNKS]
        if len(raw) <= STATUSTEXT_CHUNK:
            return self._send("statustext_send", severity, raw, 0, 0)
        self._statustext_id = self._statustext_id % 0xFFFF + 1
        chunks = [raw[i : i + STATUSTEXT_CHUNK] for i in range(0, len(raw), STATUSTEXT_CHUNK)]
        if len(chunks[-1]) == STATUSTEXT_CHUNK:
            chunks.append(b"")  # a chunk holding a NUL marks the end
        ok = True
        for seq, chunk in enumerate(chunks):
            ok &= self._send("statustext_send", severity, chunk, self._statustext_id, seq)
        return ok

    def _warn_once(self, key: str, text: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            log.warning("%s", text)
