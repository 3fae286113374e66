"""Reading logs (CSV ``t,u,warp[,airspeed][,u_sent][,read]``, the bridge's own, or the FC's) and writing files
atomically.

``u_sent`` (s, optional) says how long after the row's ``t`` its command reached the servo; the bridge's cycle
log records it per wing (``<wing>_u_sent``). A model with a servo holds the row before's command until then.
``read`` (s, optional; ``<wing>_read``) says how long after ``t`` the row's warp was read: each row is moved
to its read (and its send time with it), unless that would put rows out of order.

A flight controller's log (ArduPilot ``.BIN``, a ground station's ``.tlog``, PX4 ``.ulg``; read by
``fclog``) is taken wherever a CSV is, with ``--wing``: the bridge's named values as the FC logged them,
``<L|R>_cmd`` as u, ``<L|R>_warp`` as warp and ``WB_aspd`` as airspeed, resampled onto the times of the
command. They come at the telemetry rate (``WB_TLM_HZ``, 10 Hz by default), which is said in a warning
when it is below what a diagnosis needs.

Real logs are messy. Repeated timestamps (a logger faster than its sensor)
keep the last row of each; uneven sampling and gaps are fine for a rate
independent model; rows with a missing or non-finite t, u or warp are dropped
and counted. What cannot be repaired is refused with one line that says where:
a missing column, a cell that is not a number, time running backwards, too
short a log.
"""

from __future__ import annotations

import csv
import logging
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from warpbridge.bridge import atomic
from warpbridge.bridge.errors import UserError

log = logging.getLogger(__name__)

MAX_DROPPED_FRACTION = 0.2
FC_LOG_MIN_HZ = 50.0  # named values slower than this locate a gap but cannot separate delay, rate limit, lag
TAG = {"left": "L", "right": "R"}
MISSING = {"", "nan", "na", "n/a", "null", "none", "-"}


@dataclass
class LogData:
    """A cleaned log: t strictly increasing (s), u (mm), warp (deg) or None, airspeed (m/s) or None."""

    t: np.ndarray
    u: np.ndarray
    warp: np.ndarray | None
    airspeed: np.ndarray | None
    path: str
    rows_read: int
    rows_dropped: int = 0
    rows_merged: int = 0
    notes: list[str] = field(default_factory=list)
    u_sent: np.ndarray | None = None  # how long after each row's t its command reached the servo (s), if logged
    read_shifted: bool = False  # each row's t moved to its warp's read (the log's ``read`` column)

    def __len__(self) -> int:
        return int(self.t.size)


def _columns_for(wing: str | None) -> tuple[str, str, str, str]:
    """(u, warp, u_sent, read) column names of a plain log or of one wing of the bridge's cycle log."""
    if wing is None:
        return "u", "warp", "u_sent", "read"
    if wing not in ("left", "right"):
        raise UserError(f"--wing must be left or right (got {wing!r})")
    return f"{wing}_u", f"{wing}_warp", f"{wing}_u_sent", f"{wing}_read"


def _number(cell: str, row: int, col: str) -> float:
    s = cell.strip()
    if s.lower() in MISSING:
        return math.nan
    try:
        return float(s)
    except ValueError:
        raise UserError(f"row {row}, column {col!r}: not a number ({s[:20]!r})") from None


def read_log(path: str | os.PathLike, wing: str | None = None, require_warp: bool = True,
             min_rows: int = 50) -> LogData:
    """Read and clean a log; raises UserError with a one-line reason when it cannot be used."""
    p = Path(path)
    ucol, wcol, scol, rcol = _columns_for(wing)
    if p.suffix.lower() in (".bin", ".tlog", ".ulg"):
        return read_fc_named_values(p, wing, require_warp, min_rows)
    try:
        fh = p.open(newline="", encoding="utf-8-sig")
    except FileNotFoundError:
        raise UserError(f"{p}: no such file") from None
    except (IsADirectoryError, PermissionError, OSError) as e:
        raise UserError(f"{p}: cannot read ({e.strerror or e})") from None
    with fh:
        try:
            reader = csv.reader(fh)
            header = next(reader, None)
            if header is None:
                raise UserError(f"{p}: empty file (expected a CSV header with t,{ucol},{wcol})")
            names = [h.strip().lower() for h in header]
            wanted = ["t", ucol] + ([wcol] if require_warp else [])
            missing = [c for c in wanted if c not in names]
            if missing:
                hint = " (a bridge log? pass --wing left|right)" if wing is None and "left_u" in names else ""
                raise UserError(f"{p}: missing column(s) {', '.join(missing)}; found {', '.join(names[:12])}{hint}")
            it, iu = names.index("t"), names.index(ucol)
            iw = names.index(wcol) if wcol in names else None
            ia = names.index("airspeed") if "airspeed" in names else None
            isent = names.index(scol) if scol in names else None
            iread = names.index(rcol) if rcol in names else None
            t, u, w, a, sent, read = [], [], [], [], [], []
            rows = 0
            for lineno, row in enumerate(reader, start=2):
                if not row or all(not c.strip() for c in row):
                    continue
                rows += 1
                need = max(i for i in (it, iu, iw, ia, isent, iread) if i is not None)
                if len(row) <= need:
                    raise UserError(f"row {lineno}: {len(row)} cells, expected {len(names)}")
                t.append(_number(row[it], lineno, "t"))
                u.append(_number(row[iu], lineno, ucol))
                w.append(_number(row[iw], lineno, wcol) if iw is not None else math.nan)
                a.append(_number(row[ia], lineno, "airspeed") if ia is not None else math.nan)
                sent.append(_number(row[isent], lineno, scol) if isent is not None else math.nan)
                read.append(_number(row[iread], lineno, rcol) if iread is not None else math.nan)
        except UnicodeDecodeError:
            raise UserError(f"{p}: not a text CSV file") from None
        except csv.Error as e:
            raise UserError(f"{p}: malformed CSV ({e})") from None
    return clean(np.array(t), np.array(u), np.array(w) if iw is not None else None,
                 np.array(a) if ia is not None else None, str(p), rows, require_warp, min_rows,
                 np.array(sent) if isent is not None else None, np.array(read) if iread is not None else None)


def read_fc_named_values(p: Path, wing: str | None, require_warp: bool = True, min_rows: int = 50) -> LogData:
    """One wing's tendon command, measured warp and airspeed from the bridge's named values in an FC log."""
    from warpbridge.bridge.commands.fclog import read_fc_log

    if wing is None:
        raise UserError(f"{p}: a flight controller log holds both wings' named values: pass --wing left|right")
    fc = read_fc_log(p)
    tag = TAG[wing]
    u = fc.named.get(f"{tag}_cmd")
    if u is None or len(u) < 2:
        why = f" ({fc.notes[0]})" if fc.notes else ""
        raise UserError(f"{p}: no {tag}_cmd named values from the bridge in this log{why}")
    w = fc.named.get(f"{tag}_warp")
    if require_warp and (w is None or len(w) < 2):
        raise UserError(f"{p}: no {tag}_warp named values in this log: the bridge sends the measured warp only "
                        "with a warp sensor")
    rate = u.rate_hz
    gap = 3.0 / rate if rate > 0 else math.inf  # a value missing for three periods is a gap, not a ramp
    warp = w.at(u.t, gap) if w is not None and len(w) >= 2 else None
    aspd = fc.named.get("WB_aspd") or fc.airspeed
    airspeed = aspd.at(u.t, 2.0) if aspd is not None and len(aspd) >= 2 else None
    data = clean(u.t.copy(), u.v.copy(), warp, airspeed, str(p), len(u), require_warp, min_rows)
    data.notes.insert(0, f"{fc.fmt} log: {wing} wing's named values {tag}_cmd/{tag}_warp at {rate:.1f} Hz, "
                         f"resampled onto {tag}_cmd's times")
    if rate < FC_LOG_MIN_HZ:
        msg = (f"{p}: the named values come at {rate:.1f} Hz, the telemetry rate: too low to tell a delay, a rate "
               "limit or a sensor lag apart (a diagnosis needs the cycle log's rate, the loop's); enough to "
               "locate where in time, airspeed and phase the gap lies. Use the bridge's cycle log, or raise "
               "WB_TLM_HZ for logging (docs/review.md)")
        data.notes.append(msg)
        log.warning("%s", msg)
    return data


def clean(t, u, w, a, path: str, rows: int, require_warp: bool = True, min_rows: int = 50,
          sent=None, read=None) -> LogData:
    """Drop non-finite rows, merge repeated timestamps (keep the last), refuse time running backwards. A
    ``sent`` column that is missing (nan) in some rows counts as sent at the row's time there; a ``read``
    column moves each row to its read (``at_reads``)."""
    notes: list[str] = []
    ok = np.isfinite(t) & np.isfinite(u)
    if w is not None and require_warp:
        ok &= np.isfinite(w)
    dropped = int((~ok).sum())
    if rows and dropped > MAX_DROPPED_FRACTION * rows:
        raise UserError(f"{path}: {dropped} of {rows} rows have a missing or non-finite t/u/warp "
                        f"(more than {MAX_DROPPED_FRACTION:.0%}); fix the log")
    if dropped:
        notes.append(f"dropped {dropped} rows with missing or non-finite values")
    t, u = t[ok], u[ok]
    w = w[ok] if w is not None else None
    a = a[ok] if a is not None else None
    sent = sent[ok] if sent is not None else None
    shifted = False
    if read is not None:
        t, sent, shifted = at_reads(t, sent, read[ok], notes)
    if t.size:
        back = np.flatnonzero(np.diff(t) < 0)
        if back.size:
            k = int(back[0]) + 1
            raise UserError(f"{path}: time goes backwards at data row {k + 1} (t={t[k]:g} after {t[k - 1]:g}); "
                            "the log may hold several runs: split it")
    # repeated timestamps: keep the last row of each
    last = np.ones(t.size, bool)
    if t.size > 1:
        last[:-1] = np.diff(t) > 0
    merged = int((~last).sum())
    if merged:
        notes.append(f"merged {merged} rows with repeated timestamps (kept the last of each)")
    t, u = t[last], u[last]
    w = w[last] if w is not None else None
    a = a[last] if a is not None else None
    sent = sent[last] if sent is not None else None
    if t.size < min_rows:
        raise UserError(f"{path}: log too short ({t.size} usable rows, need at least {min_rows})")
    if a is not None:
        fin = np.isfinite(a)
        if not fin.any():
            a = None
        elif not fin.all():
            idx = np.flatnonzero(fin)
            a = np.interp(np.arange(a.size), idx, a[idx])
            notes.append(f"filled {int((~fin).sum())} missing airspeed values")
    if t.size > 2:
        dt = np.diff(t)
        med = float(np.median(dt))
        gaps = int((dt > 10 * med).sum())
        if gaps:
            notes.append(f"{gaps} gaps longer than 10 sample periods")
    if sent is not None:
        fin = np.isfinite(sent) & (sent >= 0)
        if not fin.any():
            sent = None
        else:
            if not fin.all():
                notes.append(f"{int((~fin).sum())} rows without a valid command send time (taken as sent at once)")
            sent = np.where(fin, sent, 0.0)
    for n in notes:
        log.info("%s: %s", path, n)
    return LogData(t=t, u=u, warp=w, airspeed=a, path=path, rows_read=rows, rows_dropped=dropped,
                   rows_merged=merged, notes=notes, u_sent=sent, read_shifted=shifted)


def at_reads(t: np.ndarray, sent: np.ndarray | None, read: np.ndarray, notes: list[str],
             ) -> tuple[np.ndarray, np.ndarray | None, bool]:
    """(t, sent, moved): each row moved to its warp's read, ``read`` s after its ``t`` (missing: at ``t``), and its
    send time counted from there, unless that puts rows out of order (then as logged, with a note)."""
    r = np.where(np.isfinite(read) & (read >= 0), read, 0.0)
    moved = t + r
    if not np.all((np.diff(t) <= 0) | (np.diff(moved) > 0)):
        notes.append("the sensor read times would put rows out of order: rows kept at their logged times")
        return t, sent, False
    if sent is not None:
        sent = np.where(np.isfinite(sent), np.maximum(sent - r, 0.0), sent)
    return moved, sent, bool(np.any(r > 0))


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write a file so that it is either the old one or the complete new one, never half-written."""
    p = Path(path)
    d = p.parent if str(p.parent) else Path(".")
    if not d.is_dir():
        raise UserError(f"{p}: directory {d} does not exist")
    if p.is_dir():
        raise UserError(f"{p}: is a directory")
    try:
        atomic.write_text_atomic(p, text)
    except OSError as e:
        raise UserError(f"{p}: cannot write ({e.strerror or e})") from None


def write_csv_atomic(path: str | os.PathLike, columns: dict[str, np.ndarray], fmt: str = "%.9g") -> None:
    """Write columns (equal lengths) as a CSV with a header, atomically."""
    names = list(columns)
    arrs = [np.asarray(columns[k], dtype=np.float64) for k in names]
    n = {a.size for a in arrs}
    if len(n) != 1:
        raise ValueError("columns must have equal lengths")
    lines = [",".join(names)]
    data = np.column_stack(arrs) if arrs else np.zeros((0, 0))
    lines.extend(",".join(fmt % v for v in row) for row in data)
    write_text_atomic(path, "\n".join(lines) + "\n")
