"""Where the residual lives: splits by hysteresis phase, warp level, frequency band, time and airspeed.

``cells(...)`` labels every sample by phase (loading, unloading, and the
windows just after a reversal to either), by warp level (quartiles of the
model's warp), by time (ten equal spans) and by dynamic pressure (quartiles,
when the log has airspeed). ``split(...)`` measures a residual in every cell
against the floor it should reach (noise^2 plus the model's known error^2),
and scores each dimension by the share of the excess residual variance it
explains beyond a constant offset (reported as the offset share): the spread
of the cell means about the overall mean for the sample partitions, the part
coherent with the input for the frequency bands. The dimension with the
largest share dominates. A second residual (after augmentation) gives the
share of the gap closed in every cell.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from warpbridge.model.diagnosis.records import Record
from warpbridge.model.diagnosis.stats import band_table, change_point, effective_n, xcorr_lag
from warpbridge.model.effects import dynamic_pressure_kpa
from warpbridge.model.signals import central_range

PHASES = ("loading", "unloading", "after reversal to loading", "after reversal to unloading")
REVERSAL_WINDOW = 0.1  # of the input span: travel after a reversal that counts as "just after"
REVERSAL_DEADBAND = 0.005  # of the input span: smaller wiggles are not reversals


def phase_labels(u: np.ndarray, window: float = REVERSAL_WINDOW, deadband: float = REVERSAL_DEADBAND) -> np.ndarray:
    """Phase index per sample (see ``PHASES``); direction changes need ``deadband`` of travel."""
    u = np.asarray(u, dtype=np.float64)
    lo, hi = central_range(u)
    span = max(hi - lo, 1e-12)
    eps, win = deadband * span, window * span
    n = u.size
    lab = np.zeros(n, dtype=np.int64)
    direction = 1 if n < 2 or u[min(n - 1, 1)] >= u[0] else -1
    ext = u[0]  # extremum since the last reversal
    rev_u = math.nan  # input at the last reversal (none yet)
    for k in range(n):
        x = u[k]
        if direction > 0:
            if x > ext:
                ext = x
            elif ext - x > eps:
                direction, rev_u, ext = -1, ext, x
        else:
            if x < ext:
                ext = x
            elif x - ext > eps:
                direction, rev_u, ext = 1, ext, x
        if abs(x - rev_u) < win:  # False while rev_u is NaN
            lab[k] = 2 if direction > 0 else 3
        else:
            lab[k] = 0 if direction > 0 else 1
    return lab


def quantile_labels(x: np.ndarray, k: int = 4) -> tuple[np.ndarray, list[tuple[float, float]]]:
    """Bin index by quantiles of x, and the bins' ranges."""
    edges = np.unique(np.percentile(x, np.linspace(0, 100, k + 1)))
    if edges.size < 2:
        return np.zeros(x.size, dtype=np.int64), [(float(x.min()), float(x.max()))]
    lab = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, edges.size - 2)
    return lab, [(float(a), float(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


@dataclass
class Cells:
    """Per-sample labels of each sample partition, with cell names."""

    labels: dict[str, np.ndarray]
    names: dict[str, list[str]]
    fs: float
    band_edges: list[float]


def cells(t: np.ndarray, u: np.ndarray, w_model: np.ndarray, airspeed: np.ndarray | None,
          n_time: int = 10) -> Cells:
    """Label every sample by phase, warp level, time span and (if any) dynamic pressure."""
    t = np.asarray(t, dtype=np.float64)
    labels: dict[str, np.ndarray] = {"phase": phase_labels(u)}
    names: dict[str, list[str]] = {"phase": list(PHASES)}
    lab, rng = quantile_labels(w_model)
    labels["amplitude"] = lab
    names["amplitude"] = [f"warp {a:.2f}..{b:.2f} deg" for a, b in rng]
    edges = np.linspace(t[0], t[-1], n_time + 1)
    labels["time"] = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, n_time - 1)
    names["time"] = [f"{a - t[0]:.1f}..{b - t[0]:.1f} s" for a, b in zip(edges[:-1], edges[1:], strict=True)]
    if airspeed is not None and np.ptp(airspeed) > 0.05 * max(float(np.max(np.abs(airspeed))), 1e-9):
        q = dynamic_pressure_kpa(airspeed)
        lab, rng = quantile_labels(q)
        labels["airspeed"] = lab
        names["airspeed"] = [f"q {1000 * a:.0f}..{1000 * b:.0f} Pa" for a, b in rng]
    fs = (t.size - 1) / max(t[-1] - t[0], 1e-12)
    nyq = fs / 2
    edges_hz = [0.0] + [f for f in (0.1, 1.0, 5.0, 20.0) if f < 0.8 * nyq] + [nyq]
    return Cells(labels, names, fs, edges_hz)


def _cell_rows(r: np.ndarray, lab: np.ndarray, names: list[str], mask: np.ndarray, floor2: float,
               r_after: np.ndarray | None) -> list[dict]:
    rows = []
    n_all = int(mask.sum())
    for i, name in enumerate(names):
        sel = mask & (lab == i)
        n = int(sel.sum())
        if n == 0:
            continue
        ms = float(np.mean(r[sel] ** 2))
        row = {"cell": name, "samples": n, "share_of_samples": n / max(n_all, 1), "rms_deg": math.sqrt(ms),
               "mean_deg": float(np.mean(r[sel])), "excess_ms": ms - floor2}
        if r_after is not None:
            ms2 = float(np.mean(r_after[sel] ** 2))
            row["rms_after_deg"] = math.sqrt(ms2)
            row["gap_closed"] = gap_closed(ms, ms2, floor2)
        rows.append(row)
    return rows


def gap_closed(mse_before: float, mse_after: float, floor2: float) -> float | None:
    """(MSE_before - MSE_after) / (MSE_before - floor^2); None where there is no gap to close."""
    gap = mse_before - floor2
    if not gap > 0 or not math.isfinite(gap):
        return None
    return float((mse_before - mse_after) / gap)


def _between_share(r: np.ndarray, lab: np.ndarray, mask: np.ndarray, excess: float) -> float:
    """Share of the excess residual variance carried by the cell means (between-cell sum of squares)."""
    x = r[mask]
    lab = lab[mask]
    if x.size == 0 or excess <= 0:
        return 0.0
    k = int(lab.max()) + 1
    cnt = np.bincount(lab, minlength=k).astype(np.float64)
    s = np.bincount(lab, weights=x, minlength=k)
    ok = cnt > 0
    means = s[ok] / cnt[ok]
    ss = float(np.sum(cnt[ok] * (means - x.mean()) ** 2)) / x.size  # between-cell mean square
    return float(min(1.0, ss / excess))


@dataclass(frozen=True)
class ResidualSplit(Record):
    """A residual split over the cells (``split``): its RMS against the floor, with a second residual's RMS
    and the share of the gap it closes; the mean offset and its share of the excess; each dimension's cells
    (``dimensions``: phase, amplitude, time, airspeed, band, with the time trend and the band's
    cross-correlation beside their cells); each dimension's share of the excess beyond the offset
    (``scores``), the dominant one and its worst cell. ``reading`` False leaves the scores and the dominant
    dimension out of the written form (the shrinkage's split, judged by the gap closed in each cell)."""

    rms_deg: float
    noise_deg: float
    model_error_deg: float
    floor_deg: float
    excess_ms: float
    after: tuple[float, float | None] | None  # (RMS of the second residual, the share of the gap it closes)
    mean_deg: float
    offset_share: float
    dimensions: dict[str, dict] = field(repr=False)
    scores: dict[str, float]
    dominant: str | None
    dominant_cell: str | None
    reading: bool = True

    def to_dict(self) -> dict:
        out = {"rms_deg": self.rms_deg, "noise_deg": self.noise_deg, "model_error_deg": self.model_error_deg,
               "floor_deg": self.floor_deg, "excess_ms": self.excess_ms}
        if self.after is not None:
            out["rms_after_deg"], out["gap_closed"] = self.after
        out |= {"mean_deg": self.mean_deg, "offset_share": self.offset_share} | self.dimensions
        if self.reading:
            out |= {"scores": self.scores, "dominant": self.dominant, "dominant_cell": self.dominant_cell}
        return out

    def cells_only(self) -> ResidualSplit:
        """The same split, written without the scores and the dominant dimension."""
        return replace(self, reading=False)


def split(t: np.ndarray, u: np.ndarray, r: np.ndarray, c: Cells, mask: np.ndarray, noise: float,
          model_error: float = 0.0, r_after: np.ndarray | None = None) -> ResidualSplit:
    """The residual ``r`` (deg) split over the cells of ``c`` within ``mask``; see the module docstring."""
    floor2 = noise ** 2 + model_error ** 2
    ms = float(np.mean(r[mask] ** 2))
    excess = ms - floor2
    after = None
    if r_after is not None:
        ms2 = float(np.mean(r_after[mask] ** 2))
        after = (math.sqrt(ms2), gap_closed(ms, ms2, noise ** 2))
    scores: dict[str, float] = {}
    bias = float(np.mean(r[mask]))
    offset_share = float(min(1.0, bias ** 2 / excess)) if excess > 0 else 0.0
    varex = max(excess - bias ** 2, 0.0)  # the excess beyond a constant offset, which the splits share out
    dims: dict[str, dict] = {}
    for dim, lab in c.labels.items():
        dims[dim] = {"cells": _cell_rows(r, lab, c.names[dim], mask, floor2, r_after)}
        scores[dim] = _between_share(r, lab, mask, varex)
    # time: trend and change point on top of the ten spans
    idx = np.flatnonzero(mask)
    tt, rr = t[idx], r[idx]
    if rr.size > 10:
        A = np.column_stack([np.ones_like(tt), tt - tt.mean()])
        coef, *_ = np.linalg.lstsq(A, rr, rcond=None)
        res = rr - A @ coef
        neff = effective_n(res)
        se = math.sqrt(float(np.mean(res ** 2)) / max(neff, 1.0) / max(float(np.var(tt)), 1e-300))
        j, shift, share = change_point(rr)
        dims["time"]["trend_deg_per_s"] = float(coef[1])
        dims["time"]["trend_t"] = float(coef[1] / se) if se > 0 else None
        dims["time"]["change_point_s"] = float(tt[j] - t[0])
        dims["time"]["change_point_shift_deg"] = shift
        dims["time"]["change_point_share"] = share
    # frequency bands on the longest contiguous run of the mask (the whole log when it is all scored)
    run = _longest_run(mask)
    x = np.gradient(u[run[0]:run[1]], t[run[0]:run[1]]) if run[1] - run[0] > 16 else None
    if x is not None:
        rs = r[run[0]:run[1]]
        bands = band_table(rs, x, c.fs, c.band_edges)
        total = sum(b["power"] for b in bands) or 1e-300
        noise_density = noise ** 2 / (c.fs / 2)
        for b in bands:
            b["share_of_power"] = b["power"] / total
            b["noise_power"] = noise_density * (b["hi_hz"] - b["lo_hz"])
            b["excess_power"] = b["power"] - b["noise_power"]
            b["cell"] = f"{b['lo_hz']:g}..{b['hi_hz']:g} Hz"
        if r_after is not None:
            after_bands = band_table(r_after[run[0]:run[1]], x, c.fs, c.band_edges)
            for b, a in zip(bands, after_bands, strict=False):
                b["power_after"] = a["power"]
                b["gap_closed"] = gap_closed(b["power"], a["power"], b["noise_power"])
        lag, val = xcorr_lag(x, rs, c.fs)
        coherent = sum(b["coherence"] * b["power"] for b in bands) / total
        dims["band"] = {"cells": bands, "input_rate_xcorr_lag_s": lag, "input_rate_xcorr": val,
                        "coherent_share": coherent}
        var_r = float(np.var(rs))
        scores["band"] = float(min(1.0, coherent * var_r / varex)) if varex > 0 else 0.0
    dominant = dominant_cell = None
    if excess > 0 and scores:
        dominant = max(scores, key=scores.get)
        dominant_cell = _worst_cell(dims[dominant]["cells"])
    return ResidualSplit(math.sqrt(ms), noise, model_error, math.sqrt(floor2), excess, after, bias, offset_share,
                         dims, scores, dominant, dominant_cell)


def _worst_cell(rows: list[dict]) -> str | None:
    key = "excess_power" if rows and "excess_power" in rows[0] else "excess_ms"
    if not rows:
        return None
    if key == "excess_ms":
        return max(rows, key=lambda r: r["share_of_samples"] * r["excess_ms"])["cell"]
    return max(rows, key=lambda r: r[key])["cell"]


def _longest_run(mask: np.ndarray) -> tuple[int, int]:
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return 0, 0
    breaks = np.flatnonzero(np.diff(idx) > 1)
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [idx.size - 1]])
    k = int(np.argmax(ends - starts))
    return int(idx[starts[k]]), int(idx[ends[k]]) + 1
