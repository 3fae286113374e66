"""In-memory servo output and warp sensor for tests and simulation; spec ``loop:``.

Pulses land in ``pulses`` (channel -> (pulse_us, time)) and in ``history``; counts
come from a dict (``counts[channel]``) or a callable ``counts(channel) -> float | None``.
Setting ``broken = True`` makes every call raise ``DeviceError`` until ``reopen()``,
to exercise the caller's back-off; ``errors`` is returned and cleared by
``poll_errors``, like a real board's error register.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from warpbridge.hw.base import check_pulse
from warpbridge.hw.errors import DeviceError

Counts = dict[int, float] | Callable[[int], float | None]


class LoopBackend:
    """ServoOutput and WarpSensor in memory."""

    name = "loop"

    def __init__(self, counts: Counts | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        self.counts: Counts = {} if counts is None else counts
        self.pulses: dict[int, tuple[float, float]] = {}
        self.history: list[tuple[float, int, float]] = []
        """(time, channel, pulse_us) of every set_pulse, oldest first."""
        self.errors = 0
        self.broken = False
        self.closed = False
        self.reopen_count = 0
        self._clock = clock

    def _check(self) -> None:
        if self.broken:
            raise DeviceError("simulated device loss", self.name)

    def set_pulse(self, channel: int, pulse_us: float) -> None:
        """Record ``pulse_us`` on ``channel``."""
        self._check()
        pulse = check_pulse(pulse_us)
        now = self._clock()
        self.pulses[channel] = (pulse, now)
        self.history.append((now, channel, pulse))

    def pulse(self, channel: int) -> float | None:
        """Last pulse commanded on ``channel`` (us), None if never."""
        entry = self.pulses.get(channel)
        return None if entry is None else entry[0]

    def read_counts(self, channel: int) -> float | None:
        """Counts of ``channel`` from the dict or callable; None if absent."""
        self._check()
        if callable(self.counts):
            value = self.counts(channel)
        else:
            value = self.counts.get(channel)
        return None if value is None else float(value)

    def poll_errors(self) -> int:
        """Return and clear ``errors``."""
        self._check()
        bits, self.errors = self.errors, 0
        return bits

    def error_names(self, bits: int) -> list[str]:
        """Loop errors are just numbered bits."""
        return [f"bit {b}" for b in range(bits.bit_length()) if bits & (1 << b)]

    def reopen(self, url: str | None = None) -> None:
        """Come back after ``broken`` (which a test clears); raises while still broken."""
        self.reopen_count += 1
        self._check()
        self.closed = False

    def close(self) -> None:
        """Mark closed."""
        self.closed = True
