"""The MAVLink parameter protocol for the bridge's component: ``ParamServer(store, link)``.

Ground stations (QGroundControl, Mission Planner, MAVProxy, MAVSDK) list, read and
set the ``ParamStore`` through PARAM_REQUEST_LIST, PARAM_REQUEST_READ and
PARAM_SET; every answer is a PARAM_VALUE with param_count and param_index,
broadcast as the protocol asks. The same parameters can be downloaded as
ArduPilot's ``@PARAM/param.pck`` over MAVLink FTP (``warpbridge.bridge.mavftp``),
which MAVProxy and Mission Planner try first.

Types: integer parameters go out as MAV_PARAM_TYPE_INT32, the rest as REAL32.
How an integer sits in PARAM_VALUE's float field follows the flight controller,
since ground stations decode our component's values by the autopilot they see:
ArduPilot casts (3 -> 3.0; MAVSDK, MAVProxy and QGroundControl read it so from an
ArduPilot system), PX4 copies the bytes (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE).
PARAM_SET is read the same way: REAL32 as a plain float; UINT8 .. INT32 cast
(ArduPilot) or byte-wise (PX4); any other type, and an integer's bytes sent to
an ArduPilot-style component (a denormal float), is refused, never guessed.

Addressing follows PX4's mavlink_parameters and ArduPilot's router: a request
counts when target_system is ours (or 0 for list/read) and target_component is
191 or 0 (MAV_COMP_ID_ALL); FTP only when addressed to 191 itself (a session
has one server). A set that is refused (NaN, inf, out of range, not a whole
number, an unknown param_type, sender not in the allow-list) is answered with the
unchanged value plus a STATUSTEXT saying why. Clients re-send a set whose echo
differs (MAVProxy and MAVSDK up to three times): the same refused set from the
same sender within ``REPEAT_S`` is echoed again but not reported again. A set of
a name we do not have gets the STATUSTEXT only (as PX4 does; there is no index to
answer with), and a broadcast one nothing, as it is the other components' to
answer. Sets addressed to another system or component are not ours: no answer.
Replies go out at most ``send_rate_hz`` per second (token bucket) so a slow
telemetry radio is not flooded; FTP replies, single reads and set echoes go
before the rest of a list. Refusal STATUSTEXTs are limited too (burst 5, then one
a second): a flood of bad sets is counted (``refused``, ``texts_dropped``), not
echoed onto the radio.
"""

from __future__ import annotations

import logging
import math
import struct
import time
from collections import OrderedDict, deque
from collections.abc import Callable, Iterable
from typing import Any

from warpbridge.bridge.mavftp import FtpServer, PackedParam
from warpbridge.bridge.mavlink_env import mavlink
from warpbridge.bridge.params import ParamError, ParamStore

log = logging.getLogger(__name__)

_BURST = 10  # PARAM_VALUE messages that may go out back to back
_TEXT_BURST = 5.0  # refusal STATUSTEXTs back to back, then _TEXT_PER_S
_TEXT_PER_S = 1.0
REPEAT_S = 5.0  # the same refused set again within this long is a client's retry: echoed, not reported
_REPEATS_KEPT = 64

_F32_MIN_NORMAL = 1.1754943508222875e-38
REAL32 = mavlink.MAV_PARAM_TYPE_REAL32
INT32 = mavlink.MAV_PARAM_TYPE_INT32
# integer types a PARAM_SET may carry: struct format of the value in the float's low bytes (byte-wise)
_INT_TYPES = {
    mavlink.MAV_PARAM_TYPE_UINT8: "<B", mavlink.MAV_PARAM_TYPE_INT8: "<b",
    mavlink.MAV_PARAM_TYPE_UINT16: "<H", mavlink.MAV_PARAM_TYPE_INT16: "<h",
    mavlink.MAV_PARAM_TYPE_UINT32: "<I", mavlink.MAV_PARAM_TYPE_INT32: "<i",
}


def param_name(raw: Any) -> str:
    """Decode a 16-byte param_id that may or may not end in NUL."""
    if isinstance(raw, bytes | bytearray):
        raw = bytes(raw).decode("ascii", "replace")
    return str(raw).split("\x00", 1)[0]


def bytewise(link: Any) -> bool:
    """True if integers travel byte-wise in the float field (PX4), False if cast (ArduPilot, unknown)."""
    return getattr(link, "autopilot", None) == "px4"


def encode_value(value: float, integer: bool, byte_wise: bool) -> tuple[float, int]:
    """(float field, param_type) of PARAM_VALUE for a stored value."""
    if not integer:
        return float(value), REAL32
    n = int(round(value))
    if byte_wise:
        return struct.unpack("<f", struct.pack("<i", n))[0], INT32
    return float(n), INT32


def decode_value(raw: float, param_type: int, byte_wise: bool) -> float:
    """The number a PARAM_SET carries; ValueError (the reason) for a type or encoding we do not read."""
    if param_type == REAL32:
        return float(raw)
    fmt = _INT_TYPES.get(param_type)
    if fmt is None:
        raise ValueError(f"param_type {param_type} refused")
    if byte_wise:
        bits = struct.pack("<f", raw)
        return float(struct.unpack(fmt, bits[: struct.calcsize(fmt)])[0])
    if raw != 0.0 and abs(raw) < _F32_MIN_NORMAL:
        # a denormal is an integer's bytes (PX4 style) sent to an ArduPilot-style component: never guess
        raise ValueError("byte-wise int refused")
    return float(raw)  # cast, as ArduPilot sends and reads it (validation rejects fractions)


def printable(name: str) -> str:
    """``name`` fit for a log line or STATUSTEXT: printable ASCII only, at most 16 characters."""
    return "".join(c if " " <= c <= "~" else "?" for c in name[:16])


class ParamServer:
    """Serve ``store`` over ``link`` (an ``FcLink``); feed it ``poll(link.poll())`` every cycle."""

    def __init__(
        self,
        store: ParamStore,
        link: Any,
        *,
        send_rate_hz: float = 50.0,
        allowed_gcs: Iterable[int] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.store = store
        self.link = link
        self.send_rate_hz = float(send_rate_hz)
        self.allowed_gcs = set(allowed_gcs) if allowed_gcs else None  # None or empty: anyone
        self.clock = clock
        self._urgent: deque[int] = deque()  # replies to reads and sets
        self._list: deque[int] = deque()  # pending PARAM_REQUEST_LIST answer
        self._tokens = float(_BURST)
        self._last = clock()
        self._text_tokens = _TEXT_BURST
        self._text_last = self._last
        self._recent: OrderedDict[tuple, float] = OrderedDict()  # refused set -> when last seen
        self._ftp_out: deque[tuple[tuple[int, int], bytes]] = deque()  # (to, payload)
        self.ftp = FtpServer(self.packed_params, clock=clock)
        self.refused = 0
        self.repeats = 0
        self.texts_dropped = 0

    # ------------------------------------------------------------------ entry points

    def poll(self, messages: Iterable[Any] = ()) -> None:
        """Handle the link's unconsumed messages, then send what the pacing allows."""
        for msg in messages:
            try:
                self.handle(msg)
            except Exception:  # noqa: BLE001 - one odd message must not stop the loop
                log.exception("parameter request %s not handled", msg.get_type())
        self._send_pending()

    @property
    def busy(self) -> bool:
        return bool(self._urgent or self._list or self._ftp_out)

    def handle(self, msg: Any) -> bool:
        """Handle one message; True if it was a parameter message for us."""
        mtype = msg.get_type()
        if mtype == "PARAM_REQUEST_LIST":
            if not self._addressed(msg, allow_broadcast_system=True):
                return False
            self._list = deque(range(len(self.store)))
            log.info("parameter list requested by %d/%d", msg.get_srcSystem(), msg.get_srcComponent())
            return True
        if mtype == "PARAM_REQUEST_READ":
            if not self._addressed(msg, allow_broadcast_system=True):
                return False
            index = self._lookup(msg.param_index, param_name(msg.param_id))
            if index is None:
                log.debug("read of unknown parameter %r / index %d", param_name(msg.param_id), msg.param_index)
                return False
            self._queue_urgent(index)
            return True
        if mtype == "PARAM_SET":
            if not self._addressed(msg, allow_broadcast_system=False):
                return False
            self._handle_set(msg)
            return True
        if mtype == "FILE_TRANSFER_PROTOCOL":
            if self.link.system_id is None or (msg.target_system, msg.target_component) != (
                    self.link.system_id, self.link.component_id):
                return False
            sender = (msg.get_srcSystem(), msg.get_srcComponent())
            self._ftp_out.extend((sender, p) for p in self.ftp.handle(sender, msg.payload))
            return True
        return False

    def packed_params(self) -> list[PackedParam]:
        """Every parameter as the FTP parameter file carries it."""
        values = self.store.values()
        return [PackedParam(n, values[n], s.integer, float(s.default)) for n, s in self.store.specs.items()]

    # ------------------------------------------------------------------ requests

    def _addressed(self, msg: Any, *, allow_broadcast_system: bool) -> bool:
        own_sys = self.link.system_id
        if own_sys is None:
            return False
        systems = (own_sys, 0) if allow_broadcast_system else (own_sys,)
        return msg.target_system in systems and msg.target_component in (self.link.component_id, 0)

    def _lookup(self, index: int, name: str) -> int | None:
        if index == -1 or index is None:
            return self.store.index(name) if name in self.store else None
        return index if 0 <= index < len(self.store) else None

    def _handle_set(self, msg: Any) -> None:
        name = param_name(msg.param_id)
        if name == "_HASH_CHECK":
            return  # QGroundControl's cache probe: we do not publish a hash
        broadcast = msg.target_component == 0
        key = (msg.get_srcSystem(), msg.get_srcComponent(), name, struct.pack("<f", msg.param_value), msg.param_type)
        if name not in self.store:
            if not broadcast:
                self._refuse(f"unknown parameter {printable(name)}", key)
            return
        index = self.store.index(name)
        sender = msg.get_srcSystem()
        if self.allowed_gcs is not None and sender not in self.allowed_gcs:
            self._refuse(f"{name}: sysid {sender} may not set params", key)
            self._queue_urgent(index)
            return
        try:
            value = decode_value(msg.param_value, msg.param_type, bytewise(self.link))
        except ValueError as e:
            self._refuse(f"{name}: {e}", key)
            self._queue_urgent(index)
            return
        try:
            stored = self.store.set(name, value)
        except ParamError as e:
            self._refuse(str(e), key)
        else:
            log.info("%s set to %g by %d/%d", name, stored, sender, msg.get_srcComponent())
        self._queue_urgent(index)  # echo: new value if accepted, old one if refused

    def _is_repeat(self, key: tuple, now: float) -> bool:
        """True if ``key`` (sender, name, value, type) was refused within REPEAT_S; remembers it."""
        last = self._recent.pop(key, None)
        self._recent[key] = now
        while len(self._recent) > _REPEATS_KEPT:
            self._recent.popitem(last=False)
        return last is not None and now - last <= REPEAT_S

    def _refuse(self, reason: str, key: tuple | None = None) -> None:
        self.refused += 1
        now = self.clock()
        if key is not None and self._is_repeat(key, now):
            self.repeats += 1
            log.debug("parameter set refused again (a client's retry, not reported): %s", reason)
            return
        self._text_tokens = min(_TEXT_BURST, self._text_tokens + (now - self._text_last) * _TEXT_PER_S)
        self._text_last = now
        if self._text_tokens < 1.0:
            self.texts_dropped += 1
            log.debug("parameter set refused (not reported, rate limit): %s", reason)
            return
        self._text_tokens -= 1.0
        log.warning("parameter set refused: %s", reason)
        self.link.send_statustext(mavlink.MAV_SEVERITY_WARNING, f"param {reason}")

    # ------------------------------------------------------------------ replies

    def _queue_urgent(self, index: int) -> None:
        if index not in self._urgent:
            self._urgent.append(index)

    def _send_pending(self) -> None:
        now = self.clock()
        self._tokens = min(float(_BURST), self._tokens + (now - self._last) * self.send_rate_hz)
        self._last = now
        while self._tokens >= 1.0 and self._ftp_out:
            (to_sys, to_comp), payload = self._ftp_out[0]
            if not self.link.send(mavlink.MAVLink_file_transfer_protocol_message(0, to_sys, to_comp, payload)):
                return
            self._ftp_out.popleft()
            self._tokens -= 1.0
        while self._tokens >= 1.0 and (self._urgent or self._list):
            queue = self._urgent if self._urgent else self._list
            if not self.send_value(queue[0]):
                return  # link not ready: keep it for later
            queue.popleft()
            self._tokens -= 1.0

    def send_value(self, index: int) -> bool:
        """Send PARAM_VALUE for the parameter at ``index`` now."""
        name = self.store.names[index]
        spec = self.store.specs[name]
        value = self.store.get(name)
        if not math.isfinite(value):  # cannot happen through set(); keep the wire clean anyway
            value = float(spec.default)
        raw, ptype = encode_value(value, spec.integer, bytewise(self.link))
        msg = mavlink.MAVLink_param_value_message(name.encode("ascii"), raw, ptype, len(self.store), index)
        return self.link.send(msg)
