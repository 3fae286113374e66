"""What every backend in ``hw`` shares: the two interfaces, the serial-port base, back-off.

Backends are picked by a string (see ``hw.open_servo``/``hw.open_sensor``), like pyserial
URLs. A serial backend takes ``<pyserial url or device>[,baud]``: anything
``serial.serial_for_url`` opens works, so ``spy:///dev/ttyACM0`` hex-dumps the traffic
of a real port to stderr (``spy:///dev/ttyACM0?file=wing.txt`` to a file) when a wing
misbehaves in the field. ``SerialDevice`` opens the port, maps every port failure
(``SerialException``, ``OSError``) to ``hw.errors.DeviceError``, and re-opens on
request; a backend fills in only its protocol. A device path is opened exclusively (an
advisory ``flock``, as pyserial's ``exclusive``): a second bridge, or any program that locks its
ports the same way, cannot open a port this one has open, and is told it is in use.
"""

from __future__ import annotations

import errno as errno_codes
import logging
import math
import os
import threading
import time
from collections.abc import Callable
from typing import Protocol, runtime_checkable

import serial

from warpbridge.hw.errors import DeviceError

try:
    import fcntl
    import termios

    _TERMIOS_ERRORS: tuple[type[BaseException], ...] = (termios.error,)
except ImportError:  # not POSIX
    fcntl = None  # type: ignore[assignment]
    _TERMIOS_ERRORS = ()

log = logging.getLogger(__name__)

PORT_ERRORS: tuple[type[BaseException], ...] = (serial.SerialException, OSError, *_TERMIOS_ERRORS)
"""What pyserial raises when a port goes away (termios.error on a hung-up tty)."""


PORT_IN_USE = "in use by another process (another bridge on the same port?)"


def lock_exclusive(fd: int) -> None:
    """Take the advisory lock pyserial's ``exclusive=True`` takes on a port's ``fd`` (for ports opened by
    another library); raises ``BlockingIOError`` (EAGAIN) when another open file holds it."""
    if fcntl is not None:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)


def open_error_text(exc: BaseException) -> str:
    """Why a port did not open, said once: pyserial repeats the port and the errno in its text
    ("could not open port /dev/ttyACM0: [Errno 2] No such file or directory: '/dev/ttyACM0'"), the
    system's words for the errno do not."""
    errno = getattr(exc, "errno", None)
    if errno in (errno_codes.EAGAIN, errno_codes.EWOULDBLOCK):  # the exclusive lock (``lock_exclusive``)
        return PORT_IN_USE
    if isinstance(errno, int) and errno > 0:
        return os.strerror(errno)
    return getattr(exc, "strerror", None) or str(exc)  # a resolver's error (negative errno) says it itself


@runtime_checkable
class ServoOutput(Protocol):
    """Something that drives tendon servos with pulse widths in microseconds."""

    def set_pulse(self, channel: int, pulse_us: float) -> None:
        """Command ``pulse_us`` on ``channel``; raises ``DeviceError`` if the device is lost."""

    def poll_errors(self) -> int:
        """Device error bits (reading clears them); 0 = none."""

    def error_names(self, bits: int) -> list[str]:
        """Names of the set bits of a ``poll_errors`` value, for STATUSTEXT."""

    def close(self) -> None:
        """Release the device (idempotent)."""


@runtime_checkable
class WarpSensor(Protocol):
    """Something that reads a flex sensor in raw counts."""

    def read_counts(self, channel: int) -> float | None:
        """Latest reading of ``channel``; None = no (fresh) reading."""

    def close(self) -> None:
        """Release the device (idempotent)."""


class NullSensor:
    """No sensor (spec ``none``): never a reading."""

    name = "none"

    def read_counts(self, channel: int) -> float | None:
        """Always None."""
        return None

    def close(self) -> None:
        """Nothing to release."""


def parse_serial_spec(rest: str, default_baud: int) -> tuple[str, int]:
    """Split ``<url or device>[,baud]`` into (url, baud); ValueError if malformed."""
    rest = rest.strip()
    url, baud = rest, default_baud
    head, sep, tail = rest.rpartition(",")
    if sep:
        tail = tail.strip()
        if not tail.isdigit() or int(tail) <= 0:
            raise ValueError(f"bad baud rate {tail!r} in {rest!r} (expected <device>[,baud])")
        url, baud = head.strip(), int(tail)
    if not url:
        raise ValueError(f"no device given in {rest!r} (expected <device>[,baud])")
    return url, baud


class SerialDevice:
    """A pyserial port that reports failures as ``DeviceError`` and can be re-opened.

    ``timeout`` bounds every read (s); ``write_timeout`` bounds every write. After a
    failure the port is closed and stays closed until ``reopen()`` succeeds.
    """

    name = "serial"

    def __init__(self, url: str, baudrate: int, *, timeout: float, write_timeout: float = 0.1) -> None:
        self.url = url
        self.baudrate = baudrate
        self.timeout = timeout
        self.write_timeout = write_timeout
        self._port: serial.SerialBase | None = None
        self._lock = threading.RLock()
        self._open()

    @property
    def is_open(self) -> bool:
        """True while the port is open and has not failed."""
        return self._port is not None

    def _open(self) -> None:
        try:
            port = serial.serial_for_url(
                self.url, baudrate=self.baudrate, timeout=self.timeout, write_timeout=self.write_timeout,
                exclusive=True,
            )
        except (*PORT_ERRORS, ValueError) as exc:
            raise DeviceError(f"cannot open {self.url}: {open_error_text(exc)}", self.name) from exc
        self._port = port
        log.info("%s: opened %s at %d baud", self.name, self.url, self.baudrate)
        self._on_open()

    def _on_open(self) -> None:
        """Hook for backends: called after every successful open."""

    def reopen(self, url: str | None = None) -> None:
        """Close and open again (optionally another ``url``); raises ``DeviceError`` on failure."""
        with self._lock:
            self._close_port()
            if url is not None:
                self.url = url
            self._open()

    def close(self) -> None:
        """Close the port (idempotent)."""
        with self._lock:
            self._close_port()

    def _close_port(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except PORT_ERRORS:
                pass

    def _lost(self, exc: BaseException) -> DeviceError:
        log.warning("%s: port %s lost: %s", self.name, self.url, exc)
        self._close_port()
        return DeviceError(f"port {self.url} lost: {exc}", self.name)

    def _require_port(self) -> serial.SerialBase:
        if self._port is None:
            raise DeviceError(f"port {self.url} is closed (call reopen())", self.name)
        return self._port

    def _write(self, data: bytes) -> None:
        port = self._require_port()
        try:
            port.write(data)
        except PORT_ERRORS as exc:
            raise self._lost(exc) from exc

    def _read(self, size: int) -> bytes:
        """Read up to ``size`` bytes, waiting at most ``timeout``."""
        port = self._require_port()
        try:
            return port.read(size)
        except PORT_ERRORS as exc:
            raise self._lost(exc) from exc

    def _readline(self, limit: int) -> bytes:
        port = self._require_port()
        try:
            return port.readline(limit)
        except PORT_ERRORS as exc:
            raise self._lost(exc) from exc

    def _discard_input(self) -> None:
        port = self._require_port()
        try:
            port.reset_input_buffer()
        except PORT_ERRORS as exc:
            raise self._lost(exc) from exc

    def __enter__(self) -> SerialDevice:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def check_pulse(pulse_us: float) -> float:
    """``pulse_us`` as float; ValueError if it is not finite (never write NaN to a servo)."""
    pulse = float(pulse_us)
    if not math.isfinite(pulse):
        raise ValueError(f"pulse must be finite, got {pulse_us!r}")
    return pulse


class Backoff:
    """Retry schedule for a lost device, checked from a loop that must not block.

    ``due()`` says whether to try now; report the attempt with ``failed()`` (the wait
    doubles up to ``max_s``) or ``succeeded()`` (back to ``initial_s``).
    """

    def __init__(
        self,
        initial_s: float = 0.1,
        max_s: float = 5.0,
        factor: float = 2.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not 0 < initial_s <= max_s or factor < 1:
            raise ValueError("need 0 < initial_s <= max_s and factor >= 1")
        self.initial_s, self.max_s, self.factor = initial_s, max_s, factor
        self._clock = clock
        self.delay_s = initial_s
        self.failures = 0
        self._next = -math.inf

    def due(self) -> bool:
        """True when the next attempt may be made."""
        return self._clock() >= self._next

    def failed(self) -> float:
        """Record a failed attempt; returns the wait before the next one (s)."""
        wait = self.delay_s
        self._next = self._clock() + wait
        self.failures += 1
        self.delay_s = min(self.delay_s * self.factor, self.max_s)
        return wait

    def succeeded(self) -> None:
        """Record success: the next failure waits ``initial_s`` again."""
        self.delay_s = self.initial_s
        self.failures = 0
        self._next = -math.inf
