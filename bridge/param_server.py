"""The MAVLink parameter protocol for the bridge's component: ``ParamServer(store, link)``.

Ground stations (QGroundControl, Mission Planner, MAVProxy, MAVSDK) list, read and
set the ``ParamStore`` through PARAM_REQUEST_LIST, PARAM_REQUEST_READ and
PARAM_SET; every answer is a PARAM_VALUE (MAV_PARAM_TYPE_REAL32 for all values,
integers included, with param_count and param_index), broadcast as the protocol
asks. Addressing follows PX4's mavlink_parameters and ArduPilot's router: a
request counts when target_system is ours (or 0 for list/read) and
target_component is 191 or 0 (MAV_COMP_ID_ALL). A set that is refused (NaN,
inf, out of range, not a whole number, a param_type other than REAL32, sender not
in the allow-list) is answered with the unchanged value plus a STATUSTEXT saying
why, so a GCS does not retry forever; a set of a name we do not have gets the
STATUSTEXT only (as PX4 does; there is no index to answer with), and a broadcast
one nothing, as it is the other components' to answer. Sets addressed to another
system or component are not ours: no answer. Replies go out at most
``send_rate_hz`` per second (token bucket) so a slow telemetry radio is not
flooded; single reads and set echoes go before the rest of a list. Refusal
STATUSTEXTs are limited too (burst 5, then one a second): a flood of bad sets is
counted (``refused``, ``texts_dropped``), not echoed onto the radio.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any

from warpbridge.bridge.mavlink_env import mavlink
from warpbridge.bridge.params import ParamError, ParamStore

log = logging.getLogger(__name__)

_BURST = 10  # PARAM_VALUE messages that may go out back to back
_TEXT_BURST = 5.0  # refusal STATUSTEXTs back to back, then _TEXT_PER_S
_TEXT_PER_S = 1.0


def param_name(raw: Any) -> str:
    """Decode a 16-byte param_id that may or may not end in NUL."""
    if isinstance(raw, bytes | bytearray):
        raw = bytes(raw).decode("ascii", "replace")
    return str(raw).split("\x00", 1)[0]


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
        self.refused = 0
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
        return bool(self._urgent or self._list)

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
        return False

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
        if name not in self.store:
            if not broadcast:
                self._refuse(f"unknown parameter {printable(name)}")
            return
        index = self.store.index(name)
        sender = msg.get_srcSystem()
        if self.allowed_gcs is not None and sender not in self.allowed_gcs:
            self._refuse(f"{name}: sysid {sender} may not set params")
            self._queue_urgent(index)
            return
        if msg.param_type != mavlink.MAV_PARAM_TYPE_REAL32:
            # the value field of another type may be byte-wise encoded (PX4 style): never guess
            self._refuse(f"{name}: param_type {msg.param_type} refused, send REAL32")
            self._queue_urgent(index)
            return
        value = msg.param_value
        try:
            stored = self.store.set(name, value)
        except ParamError as e:
            self._refuse(str(e))
        else:
            log.info("%s set to %g by %d/%d", name, stored, sender, msg.get_srcComponent())
        self._queue_urgent(index)  # echo: new value if accepted, old one if refused

    def _refuse(self, reason: str) -> None:
        self.refused += 1
        now = self.clock()
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
        while self._tokens >= 1.0 and (self._urgent or self._list):
            queue = self._urgent if self._urgent else self._list
            if not self.send_value(queue[0]):
                return  # link not ready: keep it for later
            queue.popleft()
            self._tokens -= 1.0

    def send_value(self, index: int) -> bool:
        """Send PARAM_VALUE for the parameter at ``index`` now."""
        name = self.store.names[index]
        value = self.store.get(name)
        if not math.isfinite(value):  # cannot happen through set(); keep the wire clean anyway
            value = float(self.store.specs[name].default)
        msg = mavlink.MAVLink_param_value_message(
            name.encode("ascii"), value, mavlink.MAV_PARAM_TYPE_REAL32, len(self.store), index
        )
        return self.link.send(msg)
