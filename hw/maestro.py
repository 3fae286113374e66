"""Pololu Maestro servo controller over serial; spec ``maestro:<pyserial url or device>[,baud]``.

One ``Maestro`` owns the port and serves as both ServoOutput (``set_pulse`` on servo
channels) and WarpSensor (``read_counts`` on channels configured as inputs: the 10-bit
analog reading 0..1023 of a flex sensor, 0..5 V). Examples::

    maestro:/dev/ttyACM0                  Maestro command port, 115200 baud
    maestro:/dev/serial/by-id/usb-Pololu_Corporation_Pololu_Micro_Maestro_6-Servo_Controller_00123456-if00
                                          same, but a stable name across unplug/replug
    maestro:/dev/ttyAMA0,57600            TTL serial (the Maestro detects the baud rate)
    maestro:spy:///dev/ttyACM0            hex-dump all traffic to stderr (field debugging)
    maestro:spy:///dev/ttyACM0?file=wing.txt   ... to a file instead

Protocol (Pololu Maestro user's guide, "Serial Servo Commands"): the compact protocol,
or the Pololu protocol (``0xAA, device number, command & 0x7F, ...``) when a
``device_number`` is given (daisy-chained boards). Set Target ``0x84, ch, lo7, hi7``
with the target in quarter-microseconds; Get Position ``0x90, ch`` answers 2 bytes
little-endian (quarter-us on a servo channel, 0..1023 on an analog input); Get Errors
``0xA1`` answers 2 bytes of error bits and clears them. Channels are numbered from 0,
as on the board. Set up the board with Maestro Control Center: serial mode "USB Dual
Port" (or "UART, detect baud rate" on TTL), the tendon channels as Servo, the flex
sensors as Input (analog only on channels 0-11 of a Mini Maestro).

Every pulse is clamped to the channel's safe range (``limits``) before it is written.
Reads wait at most ``timeout`` (default 20 ms) and give None when the board is silent; after
that, queries give None at once (nothing is sent) until the late answer has come and been
dropped, or for at most ``late_answer_s`` (0.25 s), so that a late answer is never taken for
another query's (a wrong flex-sensor reading would kick the PI trim); writes give up after 0.1 s.
A lost port (USB unplugged) raises ``DeviceError``; the caller retries ``reopen()``
with back-off (``hw.base.Backoff``).
"""

from __future__ import annotations

import logging
import time

from warpbridge.hw.base import PORT_ERRORS, SerialDevice, check_pulse

log = logging.getLogger(__name__)

SET_TARGET = 0x84
GET_POSITION = 0x90
GET_ERRORS = 0xA1
POLOLU_START = 0xAA

DEFAULT_BAUD = 115200
DEFAULT_LIMITS_US = (1000.0, 2000.0)
MAX_TARGET_QUS = 0x3FFF  # 14 bits of quarter-microseconds

ERROR_BITS: dict[int, str] = {
    0: "serial signal error",
    1: "serial overrun error",
    2: "serial RX buffer full",
    3: "serial CRC error",
    4: "serial protocol error",
    5: "serial timeout",
    6: "script stack error",
    7: "script call stack error",
    8: "script program counter error",
}
LATE_ANSWER_S = 0.25  # an answer this late after its query timed out is taken as never coming
NO_REPLY = 1 << 16
"""Not a board bit: set by ``poll_errors`` when the board did not answer Get Errors."""


def error_names(bits: int) -> list[str]:
    """Names of the Maestro error bits set in ``bits`` (unknown bits as ``bit N``)."""
    names = []
    for bit in range(17):
        if bits & (1 << bit):
            if (1 << bit) == NO_REPLY:
                names.append("no reply")
            else:
                names.append(ERROR_BITS.get(bit, f"bit {bit}"))
    return names


def encode_set_target(channel: int, quarter_us: int) -> bytes:
    """Compact-protocol Set Target bytes for ``quarter_us`` (0..16383) on ``channel``."""
    if not 0 <= quarter_us <= MAX_TARGET_QUS:
        raise ValueError(f"target {quarter_us} quarter-us out of 0..{MAX_TARGET_QUS}")
    return bytes([SET_TARGET, channel, quarter_us & 0x7F, (quarter_us >> 7) & 0x7F])


class Maestro(SerialDevice):
    """A Pololu Maestro on ``url``: servo output and analog-input sensor on one port.

    ``limits`` maps channel -> (min_us, max_us), the safe pulse range of that tendon
    servo; other channels use ``default_limits``. ``device_number`` selects the Pololu
    protocol (None = compact protocol).
    """

    name = "maestro"

    def __init__(
        self,
        url: str,
        baudrate: int = DEFAULT_BAUD,
        *,
        timeout: float = 0.02,
        limits: dict[int, tuple[float, float]] | None = None,
        default_limits: tuple[float, float] = DEFAULT_LIMITS_US,
        device_number: int | None = None,
        late_answer_s: float = LATE_ANSWER_S,
    ) -> None:
        if device_number is not None and not 0 <= device_number <= 127:
            raise ValueError(f"Maestro device number must be 0..127, got {device_number}")
        self.device_number = device_number
        self._check_limits(-1, default_limits)
        self.default_limits = (float(default_limits[0]), float(default_limits[1]))
        self.limits: dict[int, tuple[float, float]] = {}
        self.late_answer_s = float(late_answer_s)
        self._owed = 0  # bytes of an answer that timed out and may still arrive ...
        self._owed_until = 0.0  # ... until then
        for ch, lim in (limits or {}).items():
            self.set_limits(ch, *lim)
        super().__init__(url, baudrate, timeout=timeout)

    @staticmethod
    def _check_limits(channel: int, lim: tuple[float, float]) -> None:
        lo, hi = float(lim[0]), float(lim[1])
        if not (0 < lo < hi <= MAX_TARGET_QUS / 4):
            where = "default" if channel < 0 else f"channel {channel}"
            raise ValueError(f"Maestro {where} limits must satisfy 0 < min < max <= 4095.75 us, got {lim}")

    def set_limits(self, channel: int, min_us: float, max_us: float) -> None:
        """Set the safe pulse range of ``channel`` (us)."""
        self._check_channel(channel)
        self._check_limits(channel, (min_us, max_us))
        self.limits[channel] = (float(min_us), float(max_us))

    def clamp(self, channel: int, pulse_us: float) -> float:
        """``pulse_us`` clamped to the safe range of ``channel``."""
        lo, hi = self.limits.get(channel, self.default_limits)
        return min(max(pulse_us, lo), hi)

    @staticmethod
    def _check_channel(channel: int) -> None:
        if not 0 <= channel <= 23:
            raise ValueError(f"Maestro channel must be 0..23, got {channel}")

    def _frame(self, command: int, data: bytes = b"") -> bytes:
        if self.device_number is None:
            return bytes([command]) + data
        return bytes([POLOLU_START, self.device_number, command & 0x7F]) + data

    def set_pulse(self, channel: int, pulse_us: float) -> None:
        """Command ``pulse_us`` (clamped to the channel's limits, in 0.25 us steps)."""
        self._check_channel(channel)
        pulse = self.clamp(channel, check_pulse(pulse_us))
        quarter_us = round(pulse * 4)
        frame = self._frame(SET_TARGET, encode_set_target(channel, quarter_us)[1:])
        with self._lock:
            self._write(frame)

    def release(self, channel: int) -> None:
        """Stop sending pulses on ``channel`` (target 0: the servo goes limp)."""
        self._check_channel(channel)
        with self._lock:
            self._write(self._frame(SET_TARGET, bytes([channel, 0, 0])))

    def _on_open(self) -> None:
        self._owed = 0

    def _query(self, command: int, data: bytes = b"", wait_late: bool = False) -> int | None:
        """Send a query and read its 2-byte little-endian answer; None on timeout.

        The protocol does not tag answers, so one that comes after its query timed out would be
        taken for the next query's. So after a timeout no query is sent (None at once; with
        ``wait_late`` after waiting up to ``timeout`` for it) until the late answer has arrived and
        been dropped, or ``late_answer_s`` has passed without it (a query the board never
        received); then whatever else is waiting is discarded."""
        with self._lock:
            if self._owed and not self._late_answer_gone(wait_late):
                return None
            self._discard_input()
            self._write(self._frame(command, data))
            reply = self._read(2)
            if len(reply) != 2:
                self._owed, self._owed_until = 2 - len(reply), time.monotonic() + self.late_answer_s
                log.debug("maestro: no answer to 0x%02X within %.3f s", command, self.timeout)
                return None
        return reply[0] | (reply[1] << 8)

    def _late_answer_gone(self, wait: bool) -> bool:
        """Drop what has arrived of a late answer (waiting up to ``timeout`` for it with ``wait``);
        whether no more of it is expected."""
        port = self._require_port()
        try:
            waiting = self._owed if wait else port.in_waiting
        except PORT_ERRORS as exc:
            raise self._lost(exc) from exc
        if waiting:
            self._owed -= len(self._read(min(waiting, self._owed)))
        if self._owed and time.monotonic() < self._owed_until:
            return False
        self._owed = 0
        return True

    def get_position(self, channel: int) -> int | None:
        """Raw Get Position value: quarter-us on a servo channel, 0..1023 on an input."""
        self._check_channel(channel)
        return self._query(GET_POSITION, bytes([channel]))

    def read_counts(self, channel: int) -> float | None:
        """Analog reading 0..1023 of input ``channel``; None if the board did not answer."""
        value = self.get_position(channel)
        return None if value is None else float(value)

    def read_pulse(self, channel: int) -> float | None:
        """Pulse (us) the board is sending on servo ``channel`` now; None on no answer."""
        value = self.get_position(channel)
        return None if value is None else value / 4.0

    def poll_errors(self) -> int:
        """Board error bits (Get Errors clears them); ``NO_REPLY`` if the board is silent."""
        value = self._query(GET_ERRORS, wait_late=True)  # once a second: worth a wait for a late answer
        bits = NO_REPLY if value is None else value
        if bits:
            log.warning("maestro: errors 0x%04X: %s", bits, ", ".join(error_names(bits)))
        return bits

    def error_names(self, bits: int) -> list[str]:
        """Names of the set bits of a ``poll_errors`` value."""
        return error_names(bits)
