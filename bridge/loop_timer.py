"""Fixed-rate loop timing with absolute deadlines: tick k is due at start + k * period.

Deadlines never accumulate sleep error, so the loop does not drift. When the
loop falls behind by more than one period it skips the missed ticks instead of
running them back to back, and counts them as overruns. Lateness (how long
after its deadline each tick started) is kept as jitter statistics. The clock
and sleep are injectable so the logic is tested without real sleeps.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class TimerStats:
    ticks: int  # ticks run
    overruns: int  # ticks skipped because the loop fell behind
    late_mean_s: float  # mean lateness of a tick's start behind its deadline
    late_std_s: float
    late_max_s: float


class LoopTimer:
    """``wait()`` sleeps until the next deadline and returns how many ticks were skipped."""

    def __init__(self, rate_hz: float, *, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        if not rate_hz > 0:
            raise ValueError("rate must be positive")
        self.period = 1.0 / rate_hz
        self._clock, self._sleep = clock, sleep
        self.start = clock()
        self.k = 0  # index of the tick last started
        self.ticks = 0
        self.overruns = 0
        self._n = 0
        self._mean = 0.0
        self._m2 = 0.0
        self._max = 0.0

    def deadline(self, k: int) -> float:
        return self.start + k * self.period

    def wait(self) -> int:
        """Block until the next tick's deadline; skip ticks missed by more than a period."""
        nxt = self.k + 1
        now = self._clock()
        skipped = 0
        if now - self.deadline(nxt) > self.period:
            target = math.floor((now - self.start) / self.period) + 1  # the next deadline still ahead
            skipped = target - nxt
            nxt = target
            self.overruns += skipped
        delay = self.deadline(nxt) - now
        if delay > 0:
            self._sleep(delay)
        self.k = nxt
        self.ticks += 1
        self._record(max(0.0, self._clock() - self.deadline(nxt)))
        return skipped

    def _record(self, late: float) -> None:
        self._n += 1
        d = late - self._mean
        self._mean += d / self._n
        self._m2 += d * (late - self._mean)
        self._max = max(self._max, late)

    def elapsed(self) -> float:
        """Seconds since the timer started."""
        return self._clock() - self.start

    def stats(self) -> TimerStats:
        std = math.sqrt(self._m2 / (self._n - 1)) if self._n > 1 else 0.0
        return TimerStats(self.ticks, self.overruns, self._mean, std, self._max)
