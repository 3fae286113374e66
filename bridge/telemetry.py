"""Telemetry tap of the running bridge: NAMED_VALUE_FLOAT values and STATUSTEXT messages.

``Telemetry(link, rate_hz)`` sends each named value at most ``rate_hz`` times a
second (the latest value wins; call ``poll()`` each cycle to flush values held
back), and STATUSTEXT without storms: a keyed status goes out once until
``clear(key)`` (a key counts as sent only when the link took the message, so a
condition raised before the FC is known is reported as soon as it is; a key that
flaps is re-sent at most every ``key_holdoff_s``),
an unkeyed one is rate limited (burst of 5, then one a second).

To PX4 the named values go one at a time, at least ``PX4_NAMED_GAP_S`` apart, the longest waiting
first: PX4 publishes each as ``debug_key_value``, a topic that holds one message, and its logger takes
one per cycle (3.5 ms), so of a burst only the last would reach the ``.ulg``.

Names sent (at most 10 characters; shown by MAVProxy, Mission Planner's Quick tab
and QGroundControl's MAVLink Inspector, logged by ArduPilot as NVAL):

| name | unit | meaning |
|---|---|---|
| ``L_sp`` / ``R_sp`` | deg | warp setpoint of the left / right wing (from the FC's aileron outputs) |
| ``L_warp`` / ``R_warp`` | deg | measured warp (flex sensor); not sent without a sensor |
| ``L_cmd`` / ``R_cmd`` | mm | tendon command sent to the servo (feed-forward + PI) |
| ``L_ff`` / ``R_ff`` | mm | feed-forward part of the command (inverse Bouc-Wen on the setpoint) |
| ``L_pi`` / ``R_pi`` | mm | PI trim part of the command |
| ``WB_mode`` | - | mode that runs (ff where a sensor is missing): 0 open, 1 pi, 2 ff, 3 ff+pi, -1 failsafe |
| ``WB_aspd`` | m/s | airspeed the bridge uses |
| ``WB_lat`` | ms | age of the latest servo output message at use |
| ``WB_cal`` / ``WB_cal_pct`` | - / % | self-calibration state and progress (``bridge.calibrate``) |
| ``L_ad_off`` / ``R_ad_off`` | mm | online pre-tension offset estimate |
| ``L_ad_gain`` / ``R_ad_gain`` | - | online pre-tension gain estimate |
| ``L_ad_st`` / ``R_ad_st`` | - | adaptation state |
| ``L_ad_drft`` / ``R_ad_drft`` | deg | sensor zero drift estimate (when enabled) |
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from typing import Any

from warpbridge.bridge.link import NAMED_FLOAT_MAX

log = logging.getLogger(__name__)

NAMES = {
    "L_sp": "left warp setpoint, deg",
    "R_sp": "right warp setpoint, deg",
    "L_warp": "left measured warp, deg",
    "R_warp": "right measured warp, deg",
    "L_cmd": "left tendon command, mm",
    "R_cmd": "right tendon command, mm",
    "L_ff": "left feed-forward, mm",
    "R_ff": "right feed-forward, mm",
    "L_pi": "left PI trim, mm",
    "R_pi": "right PI trim, mm",
    "WB_mode": "mode: 0 open, 1 pi, 2 ff, 3 ff+pi, -1 failsafe",
    "WB_aspd": "airspeed used, m/s",
    "WB_lat": "servo message age, ms",
    "WB_cal": "self-calibration: 0 idle, 1 exciting, 2 fitting, 3 applied, 4 kept old, 5 aborted",
    "WB_cal_pct": "self-calibration progress, %",
    "L_ad_off": "left adapted pre-tension offset, mm",
    "R_ad_off": "right adapted pre-tension offset, mm",
    "L_ad_gain": "left adapted pre-tension gain",
    "R_ad_gain": "right adapted pre-tension gain",
    "L_ad_st": "left adaptation state (0 off, 1 adapting, 2-4 frozen: excitation, sensor, residual)",
    "R_ad_st": "right adaptation state (0 off, 1 adapting, 2-4 frozen: excitation, sensor, residual)",
    "L_ad_drft": "left adapted sensor zero drift, deg",
    "R_ad_drft": "right adapted sensor zero drift, deg",
}
MODE_CODES = {"open": 0.0, "pi": 1.0, "ff": 2.0, "ff+pi": 3.0, "failsafe": -1.0}

_STATUS_BURST = 5.0
_STATUS_PER_S = 1.0
SEV_ERROR, SEV_WARNING = 3, 4  # MAV_SEVERITY_ERROR, MAV_SEVERITY_WARNING
PX4_NAMED_GAP_S = 0.004  # PX4's logger keeps one debug_key_value per cycle of 3.5 ms


def _level(severity: int) -> int:
    """MAV_SEVERITY -> logging level."""
    if severity <= SEV_ERROR:
        return logging.ERROR
    return logging.WARNING if severity == SEV_WARNING else logging.INFO


class Telemetry:
    """Rate-limited NAMED_VALUE_FLOAT and storm-free STATUSTEXT over an ``FcLink``."""

    def __init__(
        self,
        link: Any,
        rate_hz: float = 10.0,
        *,
        key_holdoff_s: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.link = link
        self.rate_hz = float(rate_hz)
        self.period = 1.0 / rate_hz if rate_hz > 0 else math.inf
        self.key_holdoff_s = key_holdoff_s
        self.clock = clock
        self._last_sent: dict[str, float] = {}
        self._pending: dict[str, float] = {}
        self._last_any = -math.inf
        self._active_keys: set[str] = set()
        self._key_sent: dict[str, float] = {}
        self._key_logged: set[str] = set()
        self._tokens = _STATUS_BURST
        self._token_time = clock()
        self.dropped_status = 0

    # ------------------------------------------------------------------ named values

    def named_float(self, name: str, value: float) -> None:
        """Queue ``value`` under ``name`` (<= 10 chars); sent now if the name is due, else later."""
        if not name or len(name) > NAMED_FLOAT_MAX or not name.isascii():
            raise ValueError(f"telemetry name {name!r} must be 1..{NAMED_FLOAT_MAX} ASCII characters")
        if self.rate_hz <= 0:
            return
        self._pending[name] = float(value)
        if not self._one_at_a_time():
            self._flush(name, self.clock())
        elif self.clock() - self._last_any >= PX4_NAMED_GAP_S:
            self.poll()  # the longest waiting name goes first

    def poll(self) -> None:
        """Send the values held back whose name is due again."""
        now = self.clock()
        names = list(self._pending)
        if self._one_at_a_time():
            names.sort(key=lambda n: self._last_sent.get(n, -math.inf))
        for name in names:
            self._flush(name, now)

    def _one_at_a_time(self) -> bool:
        return getattr(self.link, "autopilot", None) == "px4"

    def _flush(self, name: str, now: float) -> None:
        last = self._last_sent.get(name)
        if last is not None and now - last < self.period:
            return
        if self._one_at_a_time() and now - self._last_any < PX4_NAMED_GAP_S:
            return
        if self.link.send_named_float(name, self._pending[name]):
            self._last_sent[name] = now
            self._last_any = now
            del self._pending[name]

    # ------------------------------------------------------------------ status texts

    def status(self, severity: int, text: str, key: str | None = None, *, log_it: bool = True) -> bool:
        """Send STATUSTEXT; with ``key`` only once until ``clear(key)`` (a failed send is retried
        by the next call with that key). True if sent.

        Every status is also logged once (a keyed one when first raised, even before the link can carry
        it) at the level of its severity: error and worse as ERROR, warning as WARNING, the rest INFO;
        ``log_it=False`` when the caller logged it already in more words."""
        now = self.clock()
        if key is not None:
            if key in self._active_keys:
                return False
            if log_it and key not in self._key_logged:
                log.log(_level(severity), "%s", text)
            self._key_logged.add(key)
            last = self._key_sent.get(key)
            if last is not None and now - last < self.key_holdoff_s:
                self._active_keys.add(key)
                log.debug("status %r flapping; not re-sent", key)
                return False
            if not self.link.send_statustext(severity, text):
                return False  # not sent (link not ready): the next call tries again
            self._active_keys.add(key)
            self._key_sent[key] = now
            log.debug("status [%s] sent: %s", key, text)
            return True
        if log_it:
            log.log(_level(severity), "%s", text)
        self._tokens = min(_STATUS_BURST, self._tokens + (now - self._token_time) * _STATUS_PER_S)
        self._token_time = now
        if self._tokens < 1.0:
            self.dropped_status += 1
            log.debug("status dropped (rate limit): %s", text)
            return False
        self._tokens -= 1.0
        return bool(self.link.send_statustext(severity, text))

    def clear(self, key: str) -> None:
        """The condition behind ``key`` is over: the next ``status(..., key)`` is sent (and logged) again."""
        self._active_keys.discard(key)
        self._key_logged.discard(key)

    def active(self, key: str) -> bool:
        return key in self._active_keys
