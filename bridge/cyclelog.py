"""Cycle log: one CSV row per control cycle, readable by ``identify``/``diagnose`` (``--wing``).

Columns: ``t`` (s since the bridge's start, when the cycle read the wings' sensors: a model of the
servo between rows needs the sensor's time, not the cycle's start), ``mode, airspeed`` then, per wing
(left, right), ``<wing>_setpoint`` (deg), ``_ff`` (mm), ``_pi`` (mm), ``_u`` (mm, the tendon command), ``_warp``
(deg, measured) and ``_pulse`` (us), then ``fc_t``: the FC's own time stamp (s since its boot;
SERVO_OUTPUT_RAW ``time_usec``, 32 bits, wraps after 71.6 min) of the servo-output message the
row's setpoints come from, by which ``warpbridge review`` joins this log to the FC's; then per wing
``<wing>_u_sent``: how long after ``t`` the wing's command was handed to the servo board (s; its sensor read,
the control step and the write: a model of the servo holds the row before's command until then); then per
wing ``<wing>_read``: how long after ``t`` its sensor was read (s; the middle of the request and the answer:
the second wing's read waits for the first wing's whole step, and a loaded link's for a millisecond or more,
which on a fast warp is worth more than the sensor's noise).
Missing values are written as ``nan``.
Rows are buffered in memory and written every ``flush_s`` seconds and on
``close()``, so a clean stop never loses a row. A ``{time}`` in the path is
replaced by the local start time (``YYYYmmdd-HHMMSS``): a new file per run.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping
from pathlib import Path

log = logging.getLogger(__name__)

WING_FIELDS = ("setpoint", "ff", "pi", "u", "warp", "pulse")
WINGS = ("left", "right")
SENT_FIELD = "u_sent"  # after fc_t (the columns before it keep their places)
READ_FIELD = "read"  # after the send times (likewise)
COLUMNS = ("t", "mode", "airspeed") + tuple(f"{w}_{f}" for w in WINGS for f in WING_FIELDS) + ("fc_t",) + tuple(
    f"{w}_{f}" for f in (SENT_FIELD, READ_FIELD) for w in WINGS)


def expand_path(path: str | Path, when: float | None = None) -> Path:
    """Replace ``{time}`` in ``path`` by the local time ``when`` (default: now)."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(when))
    return Path(str(path).replace("{time}", stamp))


def _fmt(v: float | None) -> str:
    if v is None or not math.isfinite(v):
        return "nan"
    return f"{v:.6g}"


class CycleLog:
    """Buffered CSV writer; ``write(t, mode, airspeed, wings)`` where ``wings`` maps
    ``"left"``/``"right"`` to a mapping with the keys of ``WING_FIELDS`` (absent = nan)."""

    def __init__(self, path: str | Path, *, flush_s: float = 0.5,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.path = expand_path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "w", encoding="utf-8", newline="")  # noqa: SIM115 - closed in close()
        self._file.write(",".join(COLUMNS) + "\n")
        self._file.flush()
        self._rows: list[str] = []
        self._clock = clock
        self._flush_s = flush_s
        self._last_flush = clock()
        self.rows_written = 0
        log.info("cycle log: %s", self.path)

    def write(self, t: float, mode: str, airspeed: float | None,
              wings: Mapping[str, Mapping[str, float | None]], fc_t: float | None = None) -> None:
        if self._file is None:
            return
        cells = [f"{t:.6f}", mode.replace(",", ";"), _fmt(airspeed)]  # us: a replay runs the cycles then
        for w in WINGS:
            vals = wings.get(w, {})
            cells.extend(_fmt(vals.get(f)) for f in WING_FIELDS)
        cells.append("nan" if fc_t is None or not math.isfinite(fc_t) else f"{fc_t:.6f}")
        cells.extend(_fmt(wings.get(w, {}).get(f)) for f in (SENT_FIELD, READ_FIELD) for w in WINGS)
        self._rows.append(",".join(cells))
        now = self._clock()
        if now - self._last_flush >= self._flush_s:
            self.flush()
            self._last_flush = now

    def flush(self) -> None:
        """Write the buffered rows to disk."""
        if self._file is None or not self._rows:
            return
        self._file.write("\n".join(self._rows) + "\n")
        self._file.flush()
        self.rows_written += len(self._rows)
        self._rows.clear()

    @property
    def pending(self) -> int:
        """Rows buffered but not yet written."""
        return len(self._rows)

    def close(self) -> None:
        """Flush and close (idempotent)."""
        if self._file is None:
            return
        try:
            self.flush()
        finally:
            self._file.close()
            self._file = None

    def __enter__(self) -> CycleLog:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
