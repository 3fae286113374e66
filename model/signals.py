"""Signal helpers shared by identification, the initial state, the diagnosis and the input checks.

Pure numerics on one log's arrays (tendon input u in mm, warp w in deg): the
noise floor of a warp signal, its central range, the input's reversals and
turning points, the first sample worth scoring, a compressed path that keeps
every reversal, and the straight-line baseline every fit is judged against.
"""

from __future__ import annotations

import math

import numpy as np

NOISE_TRIM = 4.0  # second differences past this many robust deviations are signal (a reversal's kink), not noise
NOISE_TRIM_PASSES = 2
# the share of a normal variance kept when its tails past +-NOISE_TRIM are cut off
NOISE_TRIM_KEPT = 1.0 - 2.0 * NOISE_TRIM * math.exp(-0.5 * NOISE_TRIM ** 2) / (
    math.sqrt(2.0 * math.pi) * math.erf(NOISE_TRIM / math.sqrt(2.0)))


def central_range(x: np.ndarray) -> tuple[float, float]:
    """A log's range without its outliers: the 0.5 and 99.5 percentiles (of its travel, or of its warp)."""
    lo, hi = np.percentile(x, [0.5, 99.5])
    return float(lo), float(hi)


def noise_floor(w: np.ndarray) -> float:
    """Standard deviation of white measurement noise on w (its quantisation included), from second differences.

    The mean square of the second differences within ``NOISE_TRIM`` robust deviations of their median, corrected
    for the normal tails cut off. A median absolute deviation alone is robust to the kinks a reversal leaves, but
    on a quantised sensor's readings the differences are multiples of its step, and their median moves in those
    steps: with the step near the noise it is off by up to 30 %. The mean square inside the cut is not: the
    deviation only sets where the cut lies, and the second pass cuts where the first pass's estimate says."""
    w = np.asarray(w, dtype=np.float64)
    if w.size < 8:
        return float("nan")
    d = np.diff(w, 2) / math.sqrt(6.0)
    a = np.abs(d - np.median(d))
    mad = float(np.median(a))
    s = 1.4826 * mad if mad > 0 else float(np.sqrt(np.mean(d ** 2)))
    for _ in range(NOISE_TRIM_PASSES):  # the cut from the last pass's estimate: a median off by a step moves it
        kept = a[a <= NOISE_TRIM * s]
        if not kept.size:
            break
        s = float(np.sqrt(np.mean(kept ** 2) / NOISE_TRIM_KEPT))
    return s


def reversal_indices(u: np.ndarray) -> np.ndarray:
    """Indices where the input changes direction (last sample before the new direction)."""
    du = np.diff(u)
    nz = np.flatnonzero(du != 0)
    if nz.size < 2:
        return np.zeros(0, dtype=np.int64)
    s = np.sign(du[nz])
    flips = np.flatnonzero(s[1:] != s[:-1])
    return nz[flips + 1]  # the sample at which u starts moving the other way is nz[flips+1]


def compress_path(u: np.ndarray, keep_every: int) -> np.ndarray:
    """Sorted sample indices: every ``keep_every``-th sample, every reversal and both ends."""
    n = u.size
    idx = np.arange(0, n, max(1, keep_every))
    rev = reversal_indices(u)
    return np.unique(np.concatenate([idx, rev, [0, n - 1]]))


def warmup_end(u: np.ndarray, max_frac: float = 0.1) -> int:
    """First sample scored: after the first reversal (the initial z is unknown), capped."""
    rev = reversal_indices(u)
    first = int(rev[0]) if rev.size else 0
    return min(first, int(max_frac * u.size))


def turning_indices(x: np.ndarray, threshold: float) -> np.ndarray:
    """Indices of the extrema after which x moves back by at least ``threshold`` (jitter does not count)."""
    x = np.asarray(x, dtype=np.float64)
    out: list[int] = []
    if not x.size or not threshold > 0:
        return np.zeros(0, dtype=np.int64)
    direction = 0
    i_lo = i_hi = 0
    lo = hi = float(x[0])
    for i, v in enumerate(x.tolist()):
        if direction == 0:
            if v < lo:
                lo, i_lo = v, i
            if v > hi:
                hi, i_hi = v, i
            if v - lo >= threshold:
                direction, hi, i_hi = 1, v, i
            elif hi - v >= threshold:
                direction, lo, i_lo = -1, v, i
        elif direction == 1:
            if v > hi:
                hi, i_hi = v, i
            elif hi - v >= threshold:
                out.append(i_hi)
                direction, lo, i_lo = -1, v, i
        else:
            if v < lo:
                lo, i_lo = v, i
            elif v - lo >= threshold:
                out.append(i_lo)
                direction, hi, i_hi = 1, v, i
    return np.asarray(out, dtype=np.int64)


def turning_points(u: np.ndarray, frac: float = 0.05) -> int:
    """Reversals of u after which it moves back by at least ``frac`` of its span (jitter does not count)."""
    u = np.asarray(u, dtype=np.float64)
    thr = frac * float(np.ptp(u)) if u.size else 0.0
    return int(turning_indices(u, thr).size)


def linear_fit(u: np.ndarray, w: np.ndarray, train: np.ndarray) -> tuple[float, float]:
    """(c0, c1) of the least-squares straight line w = c0 + c1 u on the training samples."""
    c1, c0 = np.polyfit(u[train], w[train], 1)
    return float(c0), float(c1)


def linear_baseline(u: np.ndarray, w: np.ndarray, train: np.ndarray, held: np.ndarray) -> float:
    """Held-out RMS of a straight-line fit w = c0 + c1 u on the training part."""
    c0, c1 = linear_fit(u, w, train)
    e = w[held] - (c0 + c1 * u[held])
    return float(np.sqrt(np.mean(e ** 2)))


def effective_samples(r: np.ndarray, max_lag: int | None = None) -> float:
    """How many independent samples a residual series is worth: n / (1 + 2 sum of its autocorrelations),
    summed up to the first lag where the autocorrelation is no longer positive (Geyer's initial positive
    sequence, simplified); between 1 and n."""
    r = np.asarray(r, dtype=np.float64)
    r = r[np.isfinite(r)]
    n = r.size
    if n < 4:
        return float(max(n, 1))
    x = r - r.mean()
    v = float(np.dot(x, x))
    if not v > 0:
        return float(n)
    m = min(n - 1, max_lag if max_lag is not None else n // 4)
    f = np.fft.rfft(x, 2 * n)
    ac = np.fft.irfft(f * np.conj(f))[:m + 1] / v
    s = 0.0
    for k in range(1, m + 1):
        if ac[k] <= 0:
            break
        s += float(ac[k])
    return float(min(n, max(1.0, n / (1.0 + 2.0 * s))))
