"""Warp sensor read from a microcontroller that prints lines of counts; spec ``line:<device>[,baud]``.

The board prints, at its own rate, one line per sample with one value per channel,
separated by commas and/or whitespace: ``512,498\\n`` or ``512 498\\r\\n`` (channel 0 is
the first value). A background thread reads the lines and keeps the latest value of
each channel with the time it arrived; ``read_counts`` returns it while it is fresher
than ``stale_s``, else None. Lines that do not parse (noise, boot banners, a line cut
by opening the port mid-sample, a wrong number of values when ``channels`` is given)
are counted in ``garbage_lines`` and skipped. The device is any pyserial URL, so
``line:spy:///dev/ttyUSB0`` hex-dumps the traffic. If the port is lost, ``read_counts``
raises ``DeviceError`` until ``reopen()`` succeeds.
"""

from __future__ import annotations

import logging
import math
import re
import threading
import time
from collections.abc import Callable

from warpbridge.hw.base import SerialDevice
from warpbridge.hw.errors import DeviceError

log = logging.getLogger(__name__)

DEFAULT_BAUD = 115200
MAX_LINE = 256
_SPLIT = re.compile(r"[,\s]+")


def parse_line(raw: bytes, channels: int | None = None) -> list[float] | None:
    """Counts in one line, or None if it is not a line of finite numbers (of ``channels`` values)."""
    try:
        text = raw.decode("ascii").strip()
    except UnicodeDecodeError:
        return None
    if not text:
        return None
    try:
        values = [float(field) for field in _SPLIT.split(text.strip(", "))]
    except ValueError:
        return None
    if not all(math.isfinite(v) for v in values):
        return None
    if channels is not None and len(values) != channels:
        return None
    return values


class LineSensor(SerialDevice):
    """Latest counts per channel from a line-printing board on ``url``."""

    name = "line"

    def __init__(
        self,
        url: str,
        baudrate: int = DEFAULT_BAUD,
        *,
        stale_s: float = 0.1,
        channels: int | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if stale_s <= 0:
            raise ValueError(f"stale_s must be > 0, got {stale_s}")
        self.stale_s = stale_s
        self.channels = channels
        self._clock = clock
        self._values: list[float] = []
        self._stamps: list[float] = []
        self.lines = 0
        """Good lines read since construction."""
        self.garbage_lines = 0
        """Lines skipped because they did not parse."""
        self._error: DeviceError | None = None
        self._cond = threading.Condition()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        super().__init__(url, baudrate, timeout=0.05)

    def _on_open(self) -> None:
        self._error = None
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"line-sensor {self.url}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        first = True  # a line that may have been cut (just opened, overlong): drop it
        pending = b""
        while not self._stop.is_set():
            try:
                chunk = self._readline(MAX_LINE)
            except DeviceError as exc:
                with self._cond:
                    self._error = exc
                    self._cond.notify_all()
                return
            if not chunk:
                continue
            pending += chunk
            if not pending.endswith(b"\n"):
                if len(pending) < MAX_LINE:
                    continue  # timeout mid-line: keep collecting
                self._count_garbage(pending)  # no newline in MAX_LINE bytes
                pending, first = b"", True  # and drop the rest of that line
                continue
            line, pending = pending, b""
            if first:
                first = False
                continue
            values = parse_line(line, self.channels)
            if values is None:
                if line.strip():
                    self._count_garbage(line)
                continue
            now = self._clock()
            with self._cond:
                for ch, value in enumerate(values):
                    if ch >= len(self._values):
                        self._values.append(value)
                        self._stamps.append(now)
                    else:
                        self._values[ch] = value
                        self._stamps[ch] = now
                self.lines += 1
                self._cond.notify_all()

    def _count_garbage(self, line: bytes) -> None:
        with self._cond:
            self.garbage_lines += 1
        log.debug("line sensor: skipped %r", line[:40])

    def read_counts(self, channel: int) -> float | None:
        """Latest value of ``channel`` if fresher than ``stale_s``, else None."""
        with self._cond:
            if self._error is not None:
                raise DeviceError(str(self._error))
            if not 0 <= channel < len(self._values):
                return None
            if self._clock() - self._stamps[channel] > self.stale_s:
                return None
            return self._values[channel]

    def wait_for_lines(self, count: int, timeout: float) -> bool:
        """Block until ``count`` good lines have been read in total (or ``timeout`` s)."""
        with self._cond:
            return self._cond.wait_for(lambda: self.lines >= count or self._error is not None, timeout)

    def _stop_thread(self) -> None:
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=1.0)

    def reopen(self, url: str | None = None) -> None:
        """Stop the reader, close, open again (optionally another ``url``) and restart it."""
        self._stop_thread()
        super().reopen(url)

    def close(self) -> None:
        """Stop the reader thread and close the port (idempotent)."""
        self._stop_thread()
        super().close()
