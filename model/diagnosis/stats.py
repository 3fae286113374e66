"""Statistics for the diagnosis: noise floor, whiteness, input independence, paired held-out tests.

Plain functions on arrays. A residual ``r`` (deg) is the measured warp minus a
model's prediction. ``effective_n`` turns a correlated residual's sample count
into the number of independent samples it is worth; ``paired_gain`` compares
two models on segments neither was fitted on (a forecast-encompassing test
with an autocorrelation-robust variance), so that slow structured error does
not pass for a significant gain.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal, stats


def acf(x: np.ndarray, nlags: int) -> np.ndarray:
    """Sample autocorrelation at lags 0..nlags (FFT, biased estimator)."""
    x = np.asarray(x, dtype=np.float64) - float(np.mean(x))
    n = x.size
    nlags = int(min(nlags, n - 1))
    if n < 2 or not np.any(x):
        out = np.zeros(nlags + 1)
        out[0] = 1.0
        return out
    m = 1 << (2 * n - 1).bit_length()
    f = np.fft.rfft(x, m)
    c = np.fft.irfft(f * np.conj(f), m)[: nlags + 1]
    return c / c[0]


def effective_n(x: np.ndarray, max_lag: int | None = None) -> float:
    """Number of independent samples a correlated series is worth: n / (1 + 2 sum rho_k),
    summing the autocorrelation up to its first non-positive value (Geyer's initial sequence)."""
    x = np.asarray(x, dtype=np.float64)
    n = x.size
    if n < 4:
        return float(n)
    max_lag = max_lag or min(n // 4, 5000)
    rho = acf(x, max_lag)
    s = 0.0
    for k in range(1, rho.size):
        if rho[k] <= 0.0:
            break
        s += rho[k]
    return float(max(1.0, min(n, n / (1.0 + 2.0 * s))))


@dataclass
class TestResult:
    """A test statistic, its p-value and whether the null hypothesis stands at level ``alpha``."""

    name: str
    statistic: float
    p_value: float
    passed: bool
    detail: str = ""

    def to_dict(self) -> dict:
        return {"test": self.name, "statistic": _finite(self.statistic), "p_value": _finite(self.p_value),
                "passed": self.passed, "detail": self.detail}


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def ljung_box(r: np.ndarray, nlags: int = 20, alpha: float = 0.01) -> TestResult:
    """Whiteness: Ljung-Box portmanteau test on the autocorrelation at lags 1..nlags."""
    r = np.asarray(r, dtype=np.float64)
    n = r.size
    nlags = int(min(nlags, max(1, n // 5)))
    rho = acf(r, nlags)[1:]
    k = np.arange(1, rho.size + 1)
    q = float(n * (n + 2) * np.sum(rho ** 2 / (n - k)))
    p = float(stats.chi2.sf(q, df=rho.size))
    return TestResult("ljung-box whiteness", q, p, p >= alpha, f"{rho.size} lags, {n} samples")


def input_independence(x: np.ndarray, r: np.ndarray, max_lag: int = 10, alpha: float = 0.01) -> TestResult:
    """Input independence: cross-correlation of the (pre-whitened) input with the residual at lags
    -max_lag..max_lag; under independence and a white residual, n sum rho^2 ~ chi2(2 max_lag + 1)."""
    x = np.asarray(x, dtype=np.float64)
    r = np.asarray(r, dtype=np.float64)
    n = min(x.size, r.size)
    x, r = x[:n] - x[:n].mean(), r[:n] - r[:n].mean()
    sx, sr = float(np.std(x)), float(np.std(r))
    if n < 3 * max_lag + 3 or sx == 0 or sr == 0:
        return TestResult("input-residual independence", math.nan, 1.0, True, "not enough data")
    rho = []
    for lag in range(-max_lag, max_lag + 1):
        if lag >= 0:
            c = np.mean(x[: n - lag] * r[lag:])
        else:
            c = np.mean(x[-lag:] * r[: n + lag])
        rho.append(c / (sx * sr))
    rho = np.asarray(rho)
    s = float(n * np.sum(rho ** 2))
    p = float(stats.chi2.sf(s, df=rho.size))
    k = int(np.argmax(np.abs(rho))) - max_lag
    return TestResult("input-residual independence", s, p, p >= alpha,
                      f"largest cross-correlation {rho[k + max_lag]:+.3f} at lag {k} samples")


def prewhiten(x: np.ndarray) -> np.ndarray:
    """First difference: the tendon input of a log is a slow signal, its increments are near white."""
    return np.diff(np.asarray(x, dtype=np.float64))


@dataclass
class PairedGain:
    """Held-out comparison of two models by chunk: mean gain in MSE (deg^2) and its significance."""

    gain: float
    se: float
    t: float
    p_value: float
    chunks: int

    def to_dict(self) -> dict:
        return {"gain_mse": self.gain, "se": _finite(self.se), "t": _finite(self.t),
                "p_value": _finite(self.p_value), "chunks": self.chunks}


def _lag_products(x: np.ndarray, max_lag: int) -> np.ndarray:
    """sum_i x_i x_(i+k) for k = 0..max_lag (FFT)."""
    n = x.size
    m = 1 << (n + max_lag).bit_length()
    f = np.fft.rfft(x, m)
    return np.fft.irfft(f * np.conj(f), m)[: max_lag + 1]


def chunk_ids(mask: np.ndarray, t: np.ndarray, chunk_s: float) -> np.ndarray:
    """Chunk label per sample (-1 outside ``mask``): runs of ``mask`` cut every ``chunk_s`` seconds."""
    ids = np.full(mask.size, -1, dtype=np.int64)
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return ids
    run_start = np.concatenate([[True], np.diff(idx) > 1])
    run = np.cumsum(run_start) - 1
    label = 0
    out = np.empty(idx.size, dtype=np.int64)
    for r in range(int(run[-1]) + 1):
        sel = np.flatnonzero(run == r)
        tt = t[idx[sel]]
        span = tt[-1] - tt[0]
        k = max(1, int(span // chunk_s))
        sub = np.minimum(((tt - tt[0]) / max(span, 1e-12) * k).astype(np.int64), k - 1)
        out[sel] = label + sub
        label += k
    ids[idx] = out
    return ids


def paired_gain(e0: np.ndarray, e1: np.ndarray, ids: np.ndarray) -> PairedGain:
    """Is model 1 better than model 0 on the scored samples (``ids >= 0``)?

    A forecast-encompassing test conditioned on the change of prediction d = e0 - e1 (fixed by the
    fit on other blocks): regress e0 = beta d + eps; model 1 lowers the expected squared error iff
    beta > 1/2. The variance of beta uses the autocovariance of eps up to its first non-positive
    autocorrelation (Bartlett weights), so slow structured error does not pass for evidence, while
    a gain concentrated in a few bursts (a slew limit biting on fast moves) is judged by how well
    it matches the residual there, not by how many bursts there were. ``gain`` is the difference of
    the mean squared errors, ``t`` the z statistic."""
    sel = ids >= 0
    a, b = e0[sel], e1[sel]
    m = int(ids.max()) + 1 if sel.any() else 0
    if a.size < 4:
        return PairedGain(0.0, math.inf, 0.0, 1.0, m)
    gain = float(np.mean(a * a - b * b))
    d = a - b
    sdd = float(np.dot(d, d))
    if sdd <= 1e-18 * max(float(np.dot(a, a)), 1e-300):
        return PairedGain(gain, math.inf, 0.0, 1.0, m)
    beta = float(np.dot(a, d)) / sdd
    eps = a - beta * d
    n = a.size
    rho = acf(eps, min(n // 10 + 1, 4000))
    lag_max = 0
    for k in range(1, rho.size):
        if rho[k] <= 0.0:
            break
        lag_max = k
    c0 = float(np.mean(eps * eps))
    var = c0 * sdd
    if lag_max > 0:
        k = np.arange(1, lag_max + 1)
        wk = 1.0 - k / (lag_max + 1.0)
        var += 2.0 * c0 * float(np.sum(wk * rho[1:lag_max + 1] * _lag_products(d, lag_max)[1:]))
    se_beta = math.sqrt(max(var, 0.0)) / sdd
    z = (beta - 0.5) / se_beta if se_beta > 0 else (math.inf if beta > 0.5 else -math.inf)
    p = float(stats.norm.sf(z)) if math.isfinite(z) else (0.0 if z > 0 else 1.0)
    se_gain = 2.0 * se_beta * sdd / n  # d(gain)/d(beta) = 2 sum d^2 / n
    return PairedGain(gain, se_gain, z, p, m)


def change_point(x: np.ndarray, min_frac: float = 0.05) -> tuple[int, float, float]:
    """Single change in mean: (index, shift, explained share of variance) of the best split."""
    x = np.asarray(x, dtype=np.float64)
    n = x.size
    if n < 10:
        return 0, 0.0, 0.0
    c = np.cumsum(x)
    k = np.arange(1, n)
    m1 = c[:-1] / k
    m2 = (c[-1] - c[:-1]) / (n - k)
    ss_between = k * (n - k) / n * (m1 - m2) ** 2
    lo = max(1, int(min_frac * n))
    hi = max(lo + 1, n - lo)
    j = lo + int(np.argmax(ss_between[lo - 1:hi - 1]))
    tot = float(np.sum((x - x.mean()) ** 2))
    share = float(ss_between[j - 1] / tot) if tot > 0 else 0.0
    return j, float(m2[j - 1] - m1[j - 1]), share


def band_table(r: np.ndarray, x: np.ndarray, fs: float, edges: list[float]) -> list[dict]:
    """Residual power, input-residual coherence per frequency band (Welch, ~4 s segments)."""
    n = r.size
    nper = int(min(n, max(64, 2 ** int(math.log2(max(64, 4 * fs))))))
    f, prr = signal.welch(r, fs=fs, nperseg=nper)
    _, coh = signal.coherence(x, r, fs=fs, nperseg=nper)
    coh = np.nan_to_num(coh)
    df = f[1] - f[0] if f.size > 1 else fs / 2
    rows = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = (f >= lo) & (f < hi) if hi < edges[-1] else (f >= lo) & (f <= hi)
        if not sel.any():
            continue
        p = float(np.sum(prr[sel]) * df)
        c = float(np.sum(coh[sel] * prr[sel]) / max(np.sum(prr[sel]), 1e-300))
        rows.append({"lo_hz": lo, "hi_hz": hi, "power": p, "coherence": c})
    return rows


def xcorr_lag(x: np.ndarray, r: np.ndarray, fs: float, max_lag_s: float = 1.0) -> tuple[float, float]:
    """Lag (s, positive = residual after input) and value of the peak normalised cross-correlation."""
    x = np.asarray(x, dtype=np.float64) - np.mean(x)
    r = np.asarray(r, dtype=np.float64) - np.mean(r)
    n = min(x.size, r.size)
    if n < 8 or not np.any(x) or not np.any(r):
        return 0.0, 0.0
    m = 1 << (2 * n - 1).bit_length()
    c = np.fft.irfft(np.conj(np.fft.rfft(x[:n], m)) * np.fft.rfft(r[:n], m), m)
    L = int(min(n - 1, max_lag_s * fs))
    lags = np.concatenate([np.arange(0, L + 1), np.arange(-L, 0)])
    vals = np.concatenate([c[: L + 1], c[m - L:]]) / (np.linalg.norm(x[:n]) * np.linalg.norm(r[:n]))
    k = int(np.argmax(np.abs(vals)))
    return float(lags[k] / fs), float(vals[k])
