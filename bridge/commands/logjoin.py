"""Joining the bridge's cycle log to the flight controller's log on the FC's clock.

The cycle log's ``t`` runs from the bridge's start; its ``fc_t`` column is the FC's time stamp of the
servo-output message each row follows. The offset (FC time = ``t`` + offset) is the upper envelope of
``fc_t - t`` over the rows that took a fresh message (a message is used after it is stamped, never
before), fitted as a line over the flight so that a drifting companion clock is followed. A cycle log
without ``fc_t`` (older bridges) is placed by cross-correlation alone.

Either way the join is checked against the FC's own record of its aileron output (DataFlash ``RCOU``,
``SERVO_OUTPUT_RAW``, ``actuator_outputs``): the differential warp setpoint the bridge computed from
that output must follow it. The cross-correlation's lag, less the delay the stamps predict (the
message's transit plus the wait for the next cycle), is the alignment's residual error.
"""

from __future__ import annotations

import csv
import logging
import math
import os
from dataclasses import dataclass, field

import numpy as np

from warpbridge.bridge.commands.fclog import FcLog, Series, check_readable
from warpbridge.bridge.errors import UserError

log = logging.getLogger(__name__)

WINGS = ("left", "right")
WING_FIELDS = ("setpoint", "ff", "pi", "u", "warp", "pulse")
XCORR_DT_S = 0.01  # grid of the cross-correlation; the peak is refined below it
CHECK_WINDOW_S = 1.0  # lags searched around the stamps' alignment
ENVELOPE_WINDOW_S = 10.0  # offset estimated per window, then fitted as a line
ENVELOPE_PCT = 95.0
MIN_SIGNAL_STD = 1e-6
# a join whose check falls below this |correlation|, or whose residual exceeds this, is not of one flight: the
# real flights of the tests check at |r| 0.986-0.999 with residuals of 0.03-3.3 ms (|r| 0.94 and 13 ms at PX4's
# 10 Hz outputs); each flight's cycle log against the other flight's FC log checks at |r| 0.70-0.71
CHECK_MIN_CORR = 0.85
CHECK_MAX_RESIDUAL_S = 0.1


@dataclass
class CycleLog:
    """The bridge's cycle log as arrays: ``t`` (s, bridge clock), ``mode`` (str), ``airspeed`` (m/s),
    ``wing[name][field]`` for the fields of ``WING_FIELDS``, ``fc_t`` (s, FC clock) or None."""

    path: str
    t: np.ndarray
    mode: np.ndarray
    airspeed: np.ndarray
    wing: dict[str, dict[str, np.ndarray]]
    fc_t: np.ndarray | None

    @property
    def rate_hz(self) -> float:
        """Rows per second (the loop's rate, and more where the bridge also ran a cycle on a fresh message)."""
        span = float(self.t[-1] - self.t[0]) if self.t.size > 2 else 0.0
        return (self.t.size - 1) / span if span > 0 else 0.0

    def differential(self) -> np.ndarray:
        """Left minus right warp setpoint, deg: the roll command as the wings see it."""
        return self.wing["left"]["setpoint"] - self.wing["right"]["setpoint"]


def read_cycle_log(path: str | os.PathLike) -> CycleLog:
    """Read a bridge cycle log (``bridge.cyclelog`` columns); raises UserError when it is not one."""
    p = check_readable(path, "cycle log")
    try:
        with p.open(newline="", encoding="utf-8") as fh:
            reader = csv.reader(fh)
            header = [h.strip() for h in next(reader, [])]
            rows = [r for r in reader if r]
    except OSError as e:
        raise UserError(f"cycle log {p}: cannot be read ({e.strerror or e})") from None
    except (UnicodeDecodeError, csv.Error) as e:
        raise UserError(f"{p}: not a bridge cycle log ({e})") from None
    need = ["t", "mode", "left_setpoint", "right_setpoint"]
    missing = [c for c in need if c not in header]
    if missing:
        raise UserError(f"{p}: not a bridge cycle log (missing {', '.join(missing)})")
    if len(rows) < 10:
        raise UserError(f"{p}: cycle log too short ({len(rows)} rows)")
    idx = {h: i for i, h in enumerate(header)}
    width = len(header)
    rows = [r for r in rows if len(r) == width]

    def col(name: str) -> np.ndarray:
        if name not in idx:
            return np.full(len(rows), np.nan)
        i = idx[name]
        out = np.empty(len(rows))
        for k, r in enumerate(rows):
            try:
                out[k] = float(r[i])
            except ValueError:
                out[k] = np.nan
        return out

    t = col("t")
    ok = np.isfinite(t)
    keep = np.flatnonzero(ok)
    t = t[keep]
    if np.any(np.diff(t) < 0):
        raise UserError(f"{p}: time goes backwards: several runs in one file? split it")
    mode = np.array([rows[k][idx["mode"]] for k in keep])
    wing = {w: {f: col(f"{w}_{f}")[keep] for f in WING_FIELDS} for w in WINGS}
    fc = col("fc_t")[keep] if "fc_t" in idx else None
    if fc is not None and not np.isfinite(fc).any():
        fc = None
    return CycleLog(path=str(p), t=t, mode=mode, airspeed=col("airspeed")[keep], wing=wing, fc_t=fc)


@dataclass
class Alignment:
    """How the cycle log sits on the FC's clock: FC time = ``t`` + ``offset_s`` + ``drift`` (``t`` - ``t_ref``)."""

    method: str  # "fc_t" (the bridge's stamps) or "xcorr" (cross-correlation alone)
    offset_s: float
    drift: float = 0.0  # s per s
    t_ref: float = 0.0
    check_lag_s: float = math.nan  # cross-correlation lag of the aligned aileron records
    expected_lag_s: float = math.nan  # the lag the stamps predict (transit + wait for the cycle)
    check_corr: float = math.nan  # |correlation| at the peak
    overlap_s: float = 0.0
    telemetry_lag_s: float = math.nan  # the FC's logged L_sp behind the cycle log's (bridge -> FC, rate limit)
    check_channel: int | None = None  # the FC output the check correlated with
    unchecked: str = ""  # why the check could not be made ("" when it was)
    notes: list[str] = field(default_factory=list)

    @property
    def residual_s(self) -> float:
        """Alignment error: the measured lag less the predicted one (NaN when not checked)."""
        if self.method == "xcorr":
            return math.nan  # the match itself placed the log: nothing independent is left to check it by
        return self.check_lag_s - self.expected_lag_s

    def fc_time(self, t: np.ndarray) -> np.ndarray:
        return np.asarray(t) + self.offset_s + self.drift * (np.asarray(t) - self.t_ref)


def join_unchecked(al: Alignment) -> str | None:
    """``alignment not checked: why`` when the check found nothing to correlate, else None."""
    return f"alignment not checked: {al.unchecked}" if al.unchecked else None


def join_mismatch(al: Alignment) -> str | None:
    """Why the cycle log seems not to be of this FC log's flight (its setpoint does not follow the FC's aileron
    output: a low correlation, or a lag the stamps do not predict), or None. Unchecked joins pass."""
    corr, res = al.check_corr, al.residual_s
    low = math.isfinite(corr) and corr < CHECK_MIN_CORR
    off = math.isfinite(res) and abs(res) > CHECK_MAX_RESIDUAL_S
    if not (low or off):
        return None
    said = f"|r| {corr:.2f}" + (f", residual {res * 1e3:.0f} ms" if math.isfinite(res) else "")
    return (f"the cycle log's setpoint does not follow this FC log's aileron output ({said}; the logs of one "
            "flight check at |r| near 1, within a few ms): is the cycle log of another flight? The tracking and "
            "roll-authority figures are of the two logs as joined")


def _grid(t: np.ndarray, v: np.ndarray, t0: float, t1: float, dt: float) -> np.ndarray:
    ok = np.isfinite(v)
    if ok.sum() < 2:
        return np.zeros(0)
    g = np.arange(t0, t1, dt)
    return np.interp(g, t[ok], v[ok], left=np.nan, right=np.nan)


def _standard(x: np.ndarray) -> np.ndarray:
    x = x.copy()
    fin = np.isfinite(x)
    if fin.sum() < 3:
        return np.zeros_like(x)
    x[fin] -= x[fin].mean()
    s = x[fin].std()
    x[~fin] = 0.0
    return x / s if s > MIN_SIGNAL_STD else np.zeros_like(x)


def xcorr_lag(ta: np.ndarray, a: np.ndarray, tb: np.ndarray, b: np.ndarray, lag_min: float, lag_max: float,
              dt: float = XCORR_DT_S, min_overlap: float = 0.5) -> tuple[float, float]:
    """The lag L in [lag_min, lag_max] that best matches b(t + L) to a(t), and |correlation| there.

    Both signals are put on a ``dt`` grid, standardised, cross-correlated by FFT (the sign is free: a
    reversed wing correlates negatively) and the peak refined by a parabola through its neighbours.
    Lags whose overlap is under ``min_overlap`` of the shorter record are not considered."""
    if ta.size < 3 or tb.size < 3:
        return math.nan, math.nan
    ga = _standard(_grid(ta, a, ta[0], ta[-1], dt))
    gb = _standard(_grid(tb, b, tb[0], tb[-1], dt))
    if not ga.any() or not gb.any():
        return math.nan, math.nan
    n = ga.size + gb.size
    nfft = 1 << (n - 1).bit_length()
    c = np.fft.irfft(np.conj(np.fft.rfft(ga, nfft)) * np.fft.rfft(gb, nfft), nfft)
    # c[k] = sum_i ga[i] gb[i + k]; negative k wrap to the end
    ks = np.arange(-(ga.size - 1), gb.size)
    cc = np.concatenate([c[nfft - (ga.size - 1):], c[: gb.size]]) if ga.size > 1 else c[: gb.size]
    overlap = np.minimum(ga.size, gb.size - ks) - np.maximum(0, -ks)
    lags = tb[0] - ta[0] + ks * dt
    ok = (lags >= lag_min) & (lags <= lag_max) & (overlap >= min_overlap * min(ga.size, gb.size))
    if not ok.any():
        return math.nan, math.nan
    # the biased estimate (divided by the full length, not the overlap): at equal likeness the lag that
    # overlaps more wins, so a repetitive manoeuvre cannot pull the match to a sliver at the edge
    norm = np.where(overlap > 0, np.abs(cc) / min(ga.size, gb.size), 0.0)
    norm[~ok] = -1.0
    k = int(np.argmax(norm))
    # the correlation coefficient at the peak, over the overlap
    i0, i1 = max(0, -ks[k]), min(ga.size, gb.size - ks[k])
    r = abs(float(np.corrcoef(ga[i0:i1], gb[i0 + ks[k]:i1 + ks[k]])[0, 1])) if i1 - i0 > 2 else math.nan
    frac = 0.0
    if 0 < k < norm.size - 1 and ok[k - 1] and ok[k + 1]:
        y0, y1, y2 = norm[k - 1], norm[k], norm[k + 1]
        den = y0 - 2 * y1 + y2
        frac = 0.5 * (y0 - y2) / den if den < 0 else 0.0
    return float(lags[k] + frac * dt), r


def _stamp_offset(cl: CycleLog) -> tuple[float, float, float, float, int] | None:
    """(offset, drift, t_ref, predicted lag, fresh rows) from the ``fc_t`` stamps; None without them."""
    if cl.fc_t is None:
        return None
    fc = cl.fc_t
    fresh = np.flatnonzero(np.isfinite(fc) & np.r_[False, np.diff(fc) > 0])
    if fresh.size < 10:
        return None
    t, d = cl.t[fresh], fc[fresh] - cl.t[fresh]
    # a 32-bit microsecond stamp wraps after 71.6 min: unwrap
    jumps = np.flatnonzero(np.diff(d) < -2000.0) + 1
    for j in jumps:
        d[j:] += 2**32 * 1e-6
    t_ref = float(np.median(t))
    # a drifting clock tilts each window (PX4's SIH runs its clock 0.5 % slow on a busy machine: 48 ms
    # over 10 s), and a window's upper percentile would then be its early end's: the first estimate of
    # the drift is taken out before the envelope is found
    drift0 = float(np.polyfit(t - t_ref, d, 1)[0]) if np.ptp(t) > 0 else 0.0
    d = d - drift0 * (t - t_ref)
    edges = np.arange(t[0], t[-1] + ENVELOPE_WINDOW_S, ENVELOPE_WINDOW_S)
    mids, envs = [], []
    for a, b in zip(edges[:-1], edges[1:], strict=False):
        sel = (t >= a) & (t < b)
        if sel.sum() >= 5:
            mids.append(float(np.median(t[sel])))
            envs.append(float(np.percentile(d[sel], ENVELOPE_PCT)))
    if len(mids) >= 3:
        drift, offset = np.polyfit(np.array(mids) - t_ref, np.array(envs), 1)
    else:
        drift, offset = 0.0, float(np.percentile(d, ENVELOPE_PCT))
    drift += drift0
    # the lag the cross-correlation should find: the mean age of the message each row follows (a row holds
    # its message until the next arrives, so the held rows count too)
    rows = np.flatnonzero(np.isfinite(fc))
    age = cl.t[rows] + offset + drift * (cl.t[rows] - t_ref) - fc[rows]
    age = age[np.abs(age - np.median(age)) < 1000.0]  # rows across a 32-bit wrap left out
    predicted = float(np.mean(age))
    return float(offset), float(drift), t_ref, predicted, int(fresh.size)


def aileron_series(fc: FcLog, channel: int | None = None) -> tuple[int, Series] | None:
    """The FC's aileron output (channel, series): ``channel`` or the first output the parameters call
    an aileron, else the logged output that moves most (``review`` says when it is guessed)."""
    chans = [channel] if channel is not None else list(fc.aileron_channels)
    for ch in chans:
        s = fc.output(ch)
        if s is not None and len(s) > 2:
            return ch, s
    if channel is not None or fc.outputs_t.size < 3:
        return None
    ch = _most_moving_output(fc)
    s = None if ch is None else fc.output(ch)
    return (ch, s) if s is not None else None


def _most_moving_output(fc: FcLog) -> int | None:
    spread = np.full(fc.outputs.shape[1], -1.0)
    for i in range(fc.outputs.shape[1]):
        v = fc.outputs[:, i]
        v = v[np.isfinite(v)]
        if v.size > 2:
            spread[i] = float(np.std(v))
    return int(np.argmax(spread)) + 1 if spread.max() > 0 else None


def align(cl: CycleLog, fc: FcLog, channel: int | None = None) -> Alignment:
    """Place the cycle log on the FC's clock and check it against the FC's aileron output."""
    diff = cl.differential()
    ail = aileron_series(fc, channel)
    stamps = _stamp_offset(cl)
    notes: list[str] = []
    if stamps is not None:
        offset, drift, t_ref, predicted, fresh = stamps
        al = Alignment("fc_t", offset, drift, t_ref, expected_lag_s=predicted)
        notes.append(f"placed by the FC's stamps on {fresh} fresh servo messages; drift {drift * 1e6:.0f} ppm")
    elif ail is not None:
        f0, f1 = fc.span
        lag, corr = xcorr_lag(cl.t, diff, ail[1].t, ail[1].v, f0 - cl.t[-1], f1 - cl.t[0], dt=0.02, min_overlap=0.3)
        if not math.isfinite(lag):
            raise UserError("cannot align the logs: no fc_t column in the cycle log and the aileron records do "
                            "not overlap or do not move")
        al = Alignment("xcorr", lag, expected_lag_s=0.0)
        notes.append(f"no fc_t column: placed by cross-correlation alone (|r| = {corr:.2f}); the link's latency "
                     "is folded into the offset and the alignment cannot be checked independently")
    else:
        raise UserError("cannot align the logs: no fc_t column in the cycle log and no aileron output in the FC log")
    tf = al.fc_time(cl.t)
    if ail is not None:
        ch, s = ail
        al.check_channel = ch
        lag, corr = xcorr_lag(s.t, s.v, tf, diff, -CHECK_WINDOW_S, CHECK_WINDOW_S)
        al.check_lag_s, al.check_corr = lag, corr
        lo, hi = max(tf[0], s.t[0]), min(tf[-1], s.t[-1])
        al.overlap_s = max(0.0, hi - lo)
        if al.method == "xcorr" and math.isfinite(lag):
            al.offset_s -= lag  # refine on the fine grid; what is left is the check
            al.check_lag_s, al.check_corr = xcorr_lag(s.t, s.v, al.fc_time(cl.t), diff, -CHECK_WINDOW_S,
                                                      CHECK_WINDOW_S)
        if math.isfinite(al.check_lag_s):
            notes.append(f"checked on output {ch}: lag {al.check_lag_s * 1e3:.1f} ms, |r| = {al.check_corr:.3f}")
        elif al.overlap_s < CHECK_WINDOW_S:
            al.unchecked = (f"the FC's output {ch} and the cycle log, as the stamps place it, overlap by "
                            f"{al.overlap_s:.1f} s: logs of different flights?")
        else:
            al.unchecked = f"the FC's output {ch} or the cycle log's setpoint does not move where they overlap"
    else:
        al.unchecked = (f"no output {channel} in the FC log" if channel is not None
                        else "no aileron output in the FC log")
    if al.unchecked:
        notes.append(f"alignment not checked: {al.unchecked}")
    nval = fc.named.get("L_sp")
    if nval is not None and len(nval) > 5:
        lag, _ = xcorr_lag(tf, cl.wing["left"]["setpoint"], nval.t, nval.v, -CHECK_WINDOW_S, CHECK_WINDOW_S)
        al.telemetry_lag_s = lag
    al.notes = notes
    for n in notes:
        log.info("join: %s", n)
    return al
