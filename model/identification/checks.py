"""Steps 7-8 of identification. ``fold check``: a backbone u = a1 w^2 + a2 w + a3 that turns back inside
the working range (``working_range``) is refined again from starts that do not fold (``fold_check``).
``simpler models``: a fit worse than the best straight line on the training part is a failed search,
refined again from the line and the quadratic backbone (``simpler_models``); a fit that cannot beat a line
on the held-out part says so (``support_check``)."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from warpbridge.model.identification.data import LogData
from warpbridge.model.identification.design import Starts
from warpbridge.model.identification.excitation import MIN_TURNING_POINTS
from warpbridge.model.identification.refine import Candidate, SearchTrace, evaluate
from warpbridge.model.identification.space import backbone_vertex, fold_depth
from warpbridge.model.signals import central_range, linear_fit, turning_points

log = logging.getLogger(__name__)

FOLD_MARGIN = 0.5  # the working range reaches this share of the log's warp span beyond it on each side
FOLD_KEEP = 1.05  # the refinement without a fold is kept when its training RMS is at most this times the first's


def working_range(w: np.ndarray, two_sided: bool) -> tuple[float, float]:
    """Warp range (deg) on which the backbone must not fold: the log's warp (0.5 and 99.5 percentiles) widened
    by ``FOLD_MARGIN`` of its span each way; a one-sided wing's from rest (zero warp) instead of below it."""
    lo, hi = central_range(w)
    m = FOLD_MARGIN * (hi - lo)
    lo, hi = lo - m, hi + m
    if not two_sided:
        if lo + hi > 0:
            lo = 0.0
        else:
            hi = 0.0
    return lo, hi


def fold_range(data: LogData) -> tuple[float, float]:
    """The working range (``working_range``) in the search's normalised warp."""
    w_lo, w_hi = working_range(data.w, data.two_sided)
    return w_lo / data.norm.ws, w_hi / data.norm.ws


def folds(data: LogData, theta: np.ndarray) -> bool:
    """Does the backbone of the search vector ``theta`` fold inside the working range?"""
    return bool(fold_depth(theta, data.norm.c, *fold_range(data))[0] > 0)


def fold_check(data: LogData, best: Candidate, starts: Starts, trace: SearchTrace, search,
               more: np.ndarray | None = None) -> Candidate:
    """Step 7: a backbone that folds inside the working range is refined again from starts that do not fold
    (the design's, and apart from them ``more``: a global search's members without a fold, the better kept),
    folding backbones rejected; the result is kept unless it fits the training part ``FOLD_KEEP`` worse."""
    w_lo, w_hi = working_range(data.w, data.two_sided)
    fold_hat = fold_range(data)
    if folds(data, best.theta):
        trace.fold_deg = float(data.norm.ws * backbone_vertex(best.theta, data.norm.c)[0])
        trace.working_range_deg = (w_lo, w_hi)
        log.info("the backbone folds at %.3g deg, inside the working range %.3g..%.3g deg: refining again with "
                 "the fold kept outside it", trace.fold_deg, w_lo, w_hi)
        flat = starts.thetas
        ok = fold_depth(flat, data.norm.c, *fold_hat) <= 0
        th2, d2 = search(flat[ok] if ok.any() else flat, [n for n, k in zip(starts.labels, ok, strict=True) if k]
                         if ok.any() else starts.labels, fold_hat, "refine without a fold")
        unfolded = evaluate(data, th2, d2)
        if more is not None and len(more):
            # refined apart from the design's (ranked together, the global members can push the design's best
            # start out of the few refined), the better on training kept
            th3, d3 = search(more, ["global"] * len(more), fold_hat, "refine without a fold")
            searched = evaluate(data, th3, d3)
            if searched.train_rms < unfolded.train_rms and fold_depth(th3, data.norm.c, *fold_hat)[0] <= 0:
                unfolded, th2 = searched, th3
        trace.fold_train_rms = (best.train_rms, unfolded.train_rms)
        if fold_depth(th2, data.norm.c, *fold_hat)[0] > 0:
            trace.fold_outcome = "still folds"
            log.warning("no backbone without a fold inside the working range fits: the first model kept")
        elif unfolded.train_rms > FOLD_KEEP * best.train_rms:
            trace.fold_outcome = "fits worse"
            log.info("without the fold the training RMS rises from %.3g to %.3g deg: the data show the fold, the "
                     "first model kept", best.train_rms, unfolded.train_rms)
        else:
            trace.fold_outcome = "kept"
            best = unfolded
    return best


def line_train_rms(data: LogData) -> float:
    """Training RMS (deg) of the best straight line w = c0 + c1 u on the training samples."""
    c0, c1 = linear_fit(data.u, data.w, data.train_mask)
    e = (c0 + c1 * data.u - data.w)[data.train_mask]
    return float(np.sqrt(np.mean(e ** 2)))


def simpler_models(data: LogData, best: Candidate, starts: Starts, trace: SearchTrace, search,
                   progress) -> Candidate:
    """Step 8: a result that fits the training part worse than the best straight line is a failed search:
    refined again from the line and the quadratic backbone; the line-like result is kept when the model still
    does not beat the line (never a model worse than a model inside its class)."""
    line = line_train_rms(data)
    trace.line_train_rms = line
    if best.train_rms <= line:
        return best
    log.warning("the fit's training RMS %.4g deg is above the straight line's %.4g: refining again from the line "
                "and the quadratic backbone", best.train_rms, line)
    trace.line_restart = True
    if progress:
        progress("line", 0, 1)
    simple = starts.thetas[-2:]
    th, d = search(simple, starts.labels[-2:], None, "line", n_refine=2)
    again = evaluate(data, th, d)
    if again.train_rms < best.train_rms:
        best = again
    if best.train_rms > line:  # the line itself, inside the class: its start, unrefined
        th = simple[-1]
        best = min((best, evaluate(data, th, 0.0)), key=lambda c: c.train_rms)
    return best


@dataclass(frozen=True)
class Support:
    """Whether a log supports the identified model: it must beat a straight line on the held-out part."""

    supported: bool
    reason: str


def support_check(t: np.ndarray, u: np.ndarray, w: np.ndarray, w_pred: np.ndarray, train: np.ndarray,
                  held: np.ndarray, noise: float) -> Support:
    """Does the model beat the best straight line u -> w (fitted on the same training samples) on the
    held-out samples? If not, the likeliest reason in one line: too little excitation, a held-out
    input beyond the training range, a warp that drifts, or hysteresis the data do not show."""
    if not held.any():
        return Support(False, "no held-out samples to judge the model on")
    c0, c1 = linear_fit(u, w, train)
    rms = float(np.sqrt(np.mean((w_pred[held] - w[held]) ** 2)))
    line = float(np.sqrt(np.mean((c0 + c1 * u[held] - w[held]) ** 2)))
    score = f"held-out RMS {rms:.3g} deg against {line:.3g} deg for a straight line"
    if rms < line:
        return Support(True, f"the model beats a straight line on the held-out part ({score})")
    reasons = []
    k = turning_points(u[train])
    if k < MIN_TURNING_POINTS:
        reasons.append(f"too little excitation: the tendon input turns back only {k} times in the training part "
                       f"(at least {MIN_TURNING_POINTS} needed)")
    lo, hi = float(np.min(u[train])), float(np.max(u[train]))
    margin = 0.02 * (hi - lo)
    out = float(np.mean((u[held] < lo - margin) | (u[held] > hi + margin)))
    if out > 0.05:
        reasons.append(f"the held-out part drives the tendon beyond the training range ({out:.0%} of its samples): "
                       "the model would extrapolate")
    r = w - w_pred
    shift = float(np.mean(r[held]) - np.mean(r[train]))
    floor = 3.0 * noise if math.isfinite(noise) else 0.0
    if abs(shift) > max(floor, 0.5 * rms):
        reasons.append(f"the warp drifts: the held-out residual is offset by {shift:+.3g} deg from the training "
                       "part's (sensor zero drift, or the rig changed during the log)")
    if not reasons:
        fit = float(np.sqrt(np.mean((w_pred[train] - w[train]) ** 2)))
        line_fit = float(np.sqrt(np.mean((c0 + c1 * u[train] - w[train]) ** 2)))
        if fit >= 0.9 * line_fit:
            reasons.append("the data show no hysteresis the model can use: it fits the training part no better "
                           f"than a line ({fit:.3g} against {line_fit:.3g} deg)")
        else:
            reasons.append(f"the held-out part behaves differently from the training part ({rms:.3g} deg RMS "
                           f"there against {fit:.3g} deg on the training part): the rig changed during the log, "
                           "or the training part does not show what the held-out part does")
    return Support(False, "the data do not support the model: " + "; ".join(reasons) + f" ({score})")
