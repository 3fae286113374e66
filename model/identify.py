"""Identification of the generalized Bouc-Wen model from a log, as in the paper.

A global population search (differential evolution, in place of the paper's
genetic algorithm) then a Nelder-Mead polish, on the forward output error:
simulate warp from the logged tendon input and compare with the measured warp.
The last part of the log is held out and only scored; the result says whether
the model beats a straight line u -> w fitted on the same training samples
there, and if not, why (``support_check``).

What makes this fast and robust:

- Normalised units: w / Ws and (u - uc) / Us, so the search box is the same for
  any wing; the model's form is unchanged by this scaling (sgn(w) is kept).
- A physical parameterisation with the scale redundancy removed (az = 1): the
  saturation levels of z on loading and unloading, the return ratios after a
  reversal, A and n, then the quadratic. With warp on one side of zero only four
  combinations of b are identifiable; two more are fitted when the log holds
  warp of both signs.
- The initial state is not assumed: every candidate starts from the z its own
  parameters give for the log's first samples (z is algebraic in u and w), so a
  log that starts with the tendon loaded is fitted from its first sample.
- A transport delay in front of the model, when asked (``max_delay_s``): the
  servo, its link and the sensor's filter make the warp follow the tendon
  command late. The Bouc-Wen model is rate independent, so without a delay it
  widens its loop to take up that lag. That wider loop is what a feed-forward
  flies best with (it cannot undo a delay, and the wider loop leads the
  motion), but a diagnosis judged against it mistakes a field sensor lag for a
  delay. After the search at no delay, a scan of delays (a short polish each,
  from the best model so far) and a final polish at the best one find it; the
  delay is kept only when the polished model with it lowers the training cost
  by ``DELAY_GAIN`` against the polished model without it (``model.effects``
  ``delay_s`` in MODEL.json, where ``predict``, ``diagnose`` and the SITL apply
  it).
- Path compression: the model is rate independent, so its output at a kept
  sample depends only on the input's extrema before it. Keeping every reversal
  plus a decimated grid gives the same outputs at a fraction of the cost.
- A cost bounded by the data, not by luck: an evaluation costs about one
  sub-step per kept sample plus some tens per reversal, so the search scores on
  at most ``SEARCH_POINTS`` samples and ``SEARCH_REVERSALS`` reversals and the
  polish on at most ``max_fit_points`` and ``POLISH_REVERSALS`` (evenly spread
  stretches of the training part, each started from its own first samples);
  a candidate that needs more sub-steps than its budget is rejected instead of
  being integrated for as long as a thousand ordinary ones; the search stops
  when its population agrees within ``SEARCH_SPREAD``.
- A backbone that does not fold where the wing flies: u = a1 w^2 + a2 w + a3
  turns back at its vertex, and beyond it the forward map has no warp to give
  (it holds the vertex). A bench log that covers only part of the travel can be
  fitted best by a backbone whose vertex sits just past its lowest warp, and
  every field log that goes lower is then predicted flat there. When the
  search's result folds inside the working range (``working_range``: the log's
  warp widened by ``FOLD_MARGIN`` of its span each way, and a one-sided wing's
  down to rest, zero warp), the search runs again with such backbones
  penalised, and its result is kept unless it fits the training part more
  than ``FOLD_KEEP`` worse: then the data themselves show the fold (a
  backbone that really turns just beyond the log), and the first is kept.

Everything here is pure numerics; progress is reported through a callback.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import differential_evolution, minimize

from warpbridge.model import kernels as K
from warpbridge.model._jit import njit, prange
from warpbridge.model.boucwen import BoucWenParams, forward
from warpbridge.model.effects import delayed
from warpbridge.model.initial_state import algebraic_z0_rows, estimate_z0

log = logging.getLogger(__name__)

# parameter vector theta (normalised units):
#   0 n, 1 log10 A, 2 log10 zsat_load, 3 log10 zsat_unload, 4 asinh r_unload, 5 asinh r_load,
#   6-8 the quadratic alpha1 (w - c)^2 + alpha2 (w - c) + alpha3 around the data's middle c,
#   [9 asinh D, 10 asinh E  (two-sided warp only)]
THETA_NAMES = ("n", "log10_A", "log10_zsat_load", "log10_zsat_unload", "asinh_r_unload", "asinh_r_load",
               "alpha1", "alpha2", "alpha3", "asinh_D", "asinh_E")
# return ratios r = Psi(return quadrant) / Psi(saturating quadrant) < 1: after a reversal z must head for
# the other branch (r > 1 would push it away and the ODE would blow up)
BOUNDS_ONE_SIDED = [(1.0, 5.0), (-2.0, 2.5), (-2.5, 0.5), (-2.5, 0.5), (-8.0, 0.85), (-8.0, 0.85),
                    (-1.5, 1.5), (-0.5, 3.0), (-2.0, 2.0)]
BOUNDS_TWO_SIDED = BOUNDS_ONE_SIDED + [(-8.0, 8.0), (-8.0, 8.0)]
EDGE_FRAC = 0.01  # a search result this close (share of the range) to the exponent's upper limit is at it
FOLD_MARGIN = 0.5  # the working range reaches this share of the log's warp span beyond it on each side
FOLD_PENALTY = 1e3  # cost of a backbone folding inside the working range (a fit costs well under 1), plus its depth
FOLD_KEEP = 1.05  # the search without a fold is kept when its training RMS is at most this times the first's


def central_range(x: np.ndarray) -> tuple[float, float]:
    """A log's range without its outliers: the 0.5 and 99.5 percentiles (of its travel, or of its warp)."""
    lo, hi = np.percentile(x, [0.5, 99.5])
    return float(lo), float(hi)


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


def backbone_vertex(thetas: np.ndarray, c: float) -> np.ndarray:
    """Normalised warp at which each search vector's backbone alpha1 (w - c)^2 + alpha2 (w - c) turns back
    (inf or nan for a straight one)."""
    th = np.atleast_2d(thetas)
    with np.errstate(divide="ignore", invalid="ignore"):
        return c - th[:, 7] / (2.0 * th[:, 6])


def fold_depth(thetas: np.ndarray, c: float, lo: float, hi: float) -> np.ndarray:
    """How deep inside [lo, hi] (normalised warp) each search vector's backbone folds: the distance of its
    vertex from the nearer end, as a share of the range; 0 when it does not fold inside."""
    v = backbone_vertex(thetas, c)
    with np.errstate(invalid="ignore"):
        d = np.minimum(v - lo, hi - v) / (hi - lo)
    return np.where(np.isfinite(d) & (d > 0), d, 0.0)


@dataclass(frozen=True)
class Normaliser:
    """w_hat = w / ws,  u_hat = (u - uc) / us; the quadratic is searched around c = w_mid / ws.

    ws is the warp's half-range (not its peak), so the search box fits one-sided
    warp far from zero as well as two-sided warp; sgn(w) is kept."""

    ws: float
    uc: float
    us: float
    c: float = 0.0

    @classmethod
    def from_data(cls, u: np.ndarray, w: np.ndarray) -> Normaliser:
        wlo, whi = central_range(w)
        ws = (whi - wlo) / 2.0
        lo, hi = central_range(u)
        us = (hi - lo) / 2.0
        if not ws > 0 or not us > 0:
            raise ValueError("the log's warp or tendon input does not vary")
        return cls(ws=ws, uc=float(np.median(u)), us=us, c=float(0.5 * (wlo + whi)) / ws)

    def to_physical(self, q: BoucWenParams) -> BoucWenParams:
        """Parameters of the normalised model expressed in mm and deg (az = 1 gauge)."""
        ws, uc, us = self.ws, self.uc, self.us
        n = q.n
        # u = us*u_hat + uc, w = ws*w_hat, z_mm = us*z_hat (with az_hat = 1)
        A = us * q.A / ws
        b = tuple(x * us ** (1.0 - n) / ws for x in q.b)
        return BoucWenParams(a1=us * q.a1 / ws ** 2, a2=us * q.a2 / ws, a3=us * q.a3 + uc,
                             az=q.az, A=A, n=n, b=b).canonical()

    def to_normalised(self, p: BoucWenParams) -> BoucWenParams:
        """Inverse of ``to_physical`` (returns the az = 1 representative)."""
        ws, uc, us = self.ws, self.uc, self.us
        p = p.canonical()
        n = p.n
        return BoucWenParams(a1=p.a1 * ws ** 2 / us, a2=p.a2 * ws / us, a3=(p.a3 - uc) / us, az=1.0,
                             A=p.A * ws / us, n=n, b=tuple(x * ws / us ** (1.0 - n) for x in p.b))


def thetas_to_rows(thetas: np.ndarray, c: float = 0.0) -> np.ndarray:
    """Normalised Bouc-Wen parameters (az = 1), one ``BoucWenParams.to_array()`` row per search vector;
    the quadratic in theta is alpha1 (w - c)^2 + alpha2 (w - c) + alpha3."""
    th = np.atleast_2d(np.asarray(thetas, dtype=np.float64))
    n = th[:, 0]
    A = 10.0 ** th[:, 1]
    with np.errstate(over="ignore"):
        p1 = A / (10.0 ** th[:, 2]) ** n
        p3 = A / (10.0 ** th[:, 3]) ** n
    p2 = np.sinh(th[:, 4]) * p1
    p4 = np.sinh(th[:, 5]) * p3
    d = np.sinh(th[:, 9]) * p1 if th.shape[1] > 9 else 0.0
    e = np.sinh(th[:, 10]) * p1 if th.shape[1] > 10 else 0.0
    s = (p1 - p2 - p3 + p4) / 4
    t = (p1 + p2 - p3 - p4) / 4
    al1, al2, al3 = th[:, 6], th[:, 7], th[:, 8]
    P = np.empty((th.shape[0], K.N_PARAMS))
    P[:, 0] = al1
    P[:, 1] = al2 - 2 * al1 * c
    P[:, 2] = al1 * c * c - al2 * c + al3
    P[:, 3] = 1.0
    P[:, 4] = A
    P[:, 5] = n
    P[:, 6] = (p1 - p2 + p3 - p4) / 4
    P[:, 7] = (s + d) / 2
    P[:, 8] = (t + e) / 2
    P[:, 9] = (s - d) / 2
    P[:, 10] = (t - e) / 2
    P[:, 11] = (p1 + p2 + p3 + p4) / 4
    return P


def theta_to_normalised(theta: np.ndarray, c: float = 0.0) -> BoucWenParams:
    """Normalised Bouc-Wen parameters (az = 1) from one search vector (see ``thetas_to_rows``)."""
    return BoucWenParams.from_array(thetas_to_rows(theta, c)[0])


def normalised_to_theta(q: BoucWenParams, two_sided: bool, c: float = 0.0) -> np.ndarray | None:
    """Search vector for normalised parameters, or None if they are outside the search's form
    (e.g. z does not saturate on loading)."""
    q = q.canonical()
    p = q.to_array()
    b1, b2, b3, b4, b5, b6 = q.b
    s, t = b2 + b4, b3 + b5
    p1 = b1 + s + t + b6
    p2 = -b1 - s + t + b6
    p3 = b1 - s - t + b6
    p4 = -b1 + s - t + b6
    if p1 <= 0 or p3 <= 0 or q.A <= 0:
        return None
    al1 = q.a1
    al2 = q.a2 + 2 * al1 * c
    al3 = q.a3 - al1 * c * c + al2 * c
    theta = [q.n, math.log10(q.A), math.log10((q.A / p1) ** (1 / q.n)), math.log10((q.A / p3) ** (1 / q.n)),
             math.asinh(p2 / p1), math.asinh(p4 / p3), al1, al2, al3]
    if two_sided:
        theta += [math.asinh((b2 - b4) / p1), math.asinh((b3 - b5) / p1)]
    del p
    return np.array(theta)


# ---- data preparation ------------------------------------------------------------------------

NOISE_TRIM = 4.0  # second differences past this many robust deviations are signal (a reversal's kink), not noise
NOISE_TRIM_PASSES = 2
# the share of a normal variance kept when its tails past +-NOISE_TRIM are cut off
NOISE_TRIM_KEPT = 1.0 - 2.0 * NOISE_TRIM * math.exp(-0.5 * NOISE_TRIM ** 2) / (
    math.sqrt(2.0 * math.pi) * math.erf(NOISE_TRIM / math.sqrt(2.0)))


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


@dataclass
class IdentResult:
    """What identification found and measured (RMS in deg)."""

    params: BoucWenParams
    train_rms: float
    heldout_rms: float
    noise: float
    linear_heldout_rms: float
    n_train: int
    n_heldout: int
    two_sided: bool
    evaluations: int
    split_time: float
    w_pred: np.ndarray = field(repr=False)
    train_mask: np.ndarray = field(repr=False)
    heldout_mask: np.ndarray = field(repr=False)
    z0: float = 0.0
    trace: SearchTrace | None = field(default=None, repr=False)
    support: Support | None = None
    delay_s: float = 0.0  # transport delay in front of the model (s): the model sees u(t - delay_s)
    travel_mm: tuple[float, float] | None = None  # the log's tendon travel (0.5 and 99.5 percentiles, mm)

    def fit_dict(self) -> dict:
        d = {"train_rms_deg": self.train_rms, "heldout_rms_deg": self.heldout_rms, "noise_deg": self.noise,
             "linear_heldout_rms_deg": self.linear_heldout_rms, "n_train": self.n_train,
             "n_heldout": self.n_heldout, "split_time_s": self.split_time, "two_sided": self.two_sided,
             "evaluations": self.evaluations, "method": "differential-evolution + nelder-mead",
             "z0_start_of_log": self.z0, "delay_s": self.delay_s}
        if self.travel_mm is not None:
            d["travel_mm"] = list(self.travel_mm)
        if self.support is not None:
            d |= {"supported": self.support.supported, "support": self.support.reason}
        if self.trace is not None and self.trace.restarts:  # the kept model came from the seed after --seed
            d |= {"searched_again": True, "second_search_kept": self.trace.restart_kept}
        if self.trace is not None and self.trace.fold_deg is not None:
            d |= {"backbone_fold_deg": self.trace.fold_deg, "working_range_deg": list(self.trace.working_range_deg),
                  "fold_search_kept": self.trace.fold_outcome == "kept",
                  "fold_train_rms_deg": list(self.trace.fold_train_rms or ())}
        return d


def check_log(t: np.ndarray, u: np.ndarray, w: np.ndarray, min_samples: int = 50) -> None:
    """Refuse data that cannot identify the model, with a reason a user can act on."""
    if t.size < min_samples:
        raise ValueError(f"log too short: {t.size} samples (need at least {min_samples})")
    if reversal_indices(u).size < 2:
        raise ValueError("the tendon input never reverses: hysteresis cannot be identified "
                         "(excite with a random or sine input)")
    if np.ptp(w) <= 0:
        raise ValueError("the measured warp never changes")
    c = np.corrcoef(u, w)[0, 1]
    if not c > 0:
        raise ValueError("warp decreases as the tendon input increases: check the sign of u or warp "
                         f"(correlation {c:.2f})")


def warmup_end(u: np.ndarray, max_frac: float = 0.1) -> int:
    """First sample scored: after the first reversal (the initial z is unknown), capped."""
    rev = reversal_indices(u)
    first = int(rev[0]) if rev.size else 0
    return min(first, int(max_frac * u.size))


def linear_fit(u: np.ndarray, w: np.ndarray, train: np.ndarray) -> tuple[float, float]:
    """(c0, c1) of the least-squares straight line w = c0 + c1 u on the training samples."""
    c1, c0 = np.polyfit(u[train], w[train], 1)
    return float(c0), float(c1)


def linear_baseline(u: np.ndarray, w: np.ndarray, train: np.ndarray, held: np.ndarray) -> float:
    """Held-out RMS of a straight-line fit w = c0 + c1 u on the training part."""
    c0, c1 = linear_fit(u, w, train)
    e = w[held] - (c0 + c1 * u[held])
    return float(np.sqrt(np.mean(e ** 2)))


def turning_points(u: np.ndarray, frac: float = 0.05) -> int:
    """Reversals of u after which it moves back by at least ``frac`` of its span (jitter does not count)."""
    u = np.asarray(u, dtype=np.float64)
    thr = frac * float(np.ptp(u)) if u.size else 0.0
    if not thr > 0:
        return 0
    count, direction = 0, 0
    lo = hi = float(u[0])
    for x in u.tolist():
        if direction == 0:
            lo, hi = min(lo, x), max(hi, x)
            if x - lo >= thr:
                direction, hi = 1, x
            elif hi - x >= thr:
                direction, lo = -1, x
        elif direction == 1:
            if x > hi:
                hi = x
            elif hi - x >= thr:
                count, direction, lo = count + 1, -1, x
        else:
            if x < lo:
                lo = x
            elif x - lo >= thr:
                count, direction, hi = count + 1, 1, x
    return count


@dataclass(frozen=True)
class Support:
    """Whether a log supports the identified model: it must beat a straight line on the held-out part."""

    supported: bool
    reason: str


MIN_TURNING_POINTS = 4  # reversals (5 % of the span or more) the training part needs to pin the loop down


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


# ---- the search ------------------------------------------------------------------------------

FIT_TOL_Z = 1e-6  # local error per sub-step while fitting (normalised z: a millionth of the tendon half-range)
BUDGET_PER_POINT = 40  # sub-steps an evaluation may spend per kept sample ...
BUDGET_PER_REVERSAL = 1000  # ... and per reversal (a whole transition between saturations takes 100-250)
SEARCH_POINTS, SEARCH_REVERSALS = 1200, 60  # what one candidate of the global search is scored on, at most
POLISH_REVERSALS = 120  # the polish scores on at most this many reversals (and ``max_fit_points`` samples)
STRETCHES = 4  # when a log holds more, evenly spread stretches of it
SEARCH_SPREAD = 0.01  # the search stops once its population's costs agree within this (std / mean)
START_SAMPLES = 25  # raw samples given to the algebraic initial state of a stretch
DELAY_GRID_S = (0.005, 0.01, 0.02, 0.03, 0.045, 0.065, 0.09, 0.12, 0.16)  # transport delays the scan tries (s)
DELAY_SCAN_EVALS = 200  # Nelder-Mead evaluations of the short polish at each delay of the scan
DELAY_GAIN = 0.02  # a delay is kept only when it lowers the training cost by this share of the no-delay cost


def fit_stretches(u: np.ndarray, n_end: int, max_reversals: int, pieces: int = STRETCHES) -> list[tuple[int, int]]:
    """Raw sample ranges [a, b) of u[:n_end] to score on: all of it when it holds at most
    ``max_reversals`` reversals, else ``pieces`` evenly spaced stretches that hold that many together.

    The Bouc-Wen state is (w, z) and z follows from u and w, so each stretch starts from the state
    its own first samples imply: a fit's cost is bounded by these limits, not by the log."""
    rev = reversal_indices(u[:n_end])
    if rev.size <= max_reversals:
        return [(0, n_end)]
    per = max(1, max_reversals // pieces)
    out = []
    for j in range(pieces):
        a = int(j * n_end / pieces)
        nxt = int((j + 1) * n_end / pieces)
        k = int(np.searchsorted(rev, a, side="right"))
        b = int(rev[k + per]) if k + per < rev.size else n_end
        out.append((a, max(a + 2, min(b, nxt))))
    return out


@dataclass
class FitPath:
    """Stretches of the compressed training path (normalised units), concatenated; ``offsets`` bound them."""

    u: np.ndarray
    w: np.ndarray
    weight: np.ndarray
    offsets: np.ndarray
    starts: list[tuple[np.ndarray, np.ndarray]]
    budgets: np.ndarray

    @classmethod
    def build(cls, u_hat: np.ndarray, w_hat: np.ndarray, n_end: int, max_points: int,
              max_reversals: int) -> FitPath:
        ranges = fit_stretches(u_hat, n_end, max_reversals)
        span = sum(b - a for a, b in ranges)
        keep_every = max(1, int(math.ceil(span / max_points)))
        us, ws, wts, offs, starts, budgets = [], [], [], [0], [], []
        for a, b in ranges:
            idx = compress_path(u_hat[a:b], keep_every)
            wt = np.zeros(idx.size)
            wt[idx % keep_every == 0] = 1.0
            us.append(u_hat[a:b][idx])
            ws.append(w_hat[a:b][idx])
            wts.append(wt)
            offs.append(offs[-1] + idx.size)
            starts.append((u_hat[a:min(b, a + START_SAMPLES)], w_hat[a:min(b, a + START_SAMPLES)]))
            budgets.append(BUDGET_PER_POINT * idx.size + BUDGET_PER_REVERSAL * (reversal_indices(us[-1]).size + 1))
        return cls(np.concatenate(us), np.concatenate(ws), np.concatenate(wts), np.array(offs, dtype=np.int64),
                   starts, np.array(budgets, dtype=np.int64))

    @property
    def reversals(self) -> int:
        return int(sum(reversal_indices(self.u[a:b]).size for a, b in zip(self.offsets[:-1], self.offsets[1:],
                                                                           strict=True)))


def rest_warp_rows(P: np.ndarray, u0: float, z0: np.ndarray) -> np.ndarray:
    """Per row of P: the warp at which the model holding state z0 outputs u0 (rising root of the quadratic)."""
    a1, a2 = P[:, 0], P[:, 1]
    c = P[:, 2] + P[:, 3] * z0 - u0
    with np.errstate(divide="ignore", invalid="ignore"):
        disc = a2 * a2 - 4.0 * a1 * c
        r = np.sqrt(np.maximum(disc, 0.0))
        lin = -c / a2
        root1 = (-a2 + r) / (2.0 * a1)
        root2 = (-a2 - r) / (2.0 * a1)
        quad = np.where(2.0 * a1 * root1 + a2 > 0, root1, np.where(2.0 * a1 * root2 + a2 > 0, root2, root1))
        quad = np.where(disc < 0, -a2 / (2.0 * a1), quad)
    return np.where(np.abs(a1) < 1e-15, lin, quad)


class _Objective:
    """Mean squared forward output error on a ``FitPath`` (normalised units).

    Every candidate starts each stretch from the state that stretch's first samples imply for it
    (``algebraic_z0``), and may spend at most a budget of sub-steps: a parameter set that needs
    more is no model of a wing (a state stuck where it is unstable, or a saturation far stiffer
    than the data) and is rejected at a bounded cost instead of a thousand ordinary evaluations'."""

    def __init__(self, path: FitPath, c: float = 0.0, tol: float = FIT_TOL_Z,
                 fold: tuple[float, float] | None = None) -> None:
        self.path = path
        self.c = c
        self.fold = fold  # (lo, hi) normalised warp: backbones folding inside cost FOLD_PENALTY (None: no check)
        self.wsum = float(path.weight.sum())
        self.tol = float(tol)
        self.calls = 0

    def params_matrix(self, thetas: np.ndarray) -> np.ndarray:
        return thetas_to_rows(thetas, self.c)

    def start(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(w0, z0), one column per stretch: the state its first samples imply, consistent with its first u."""
        m = len(self.path.starts)
        W0, Z0 = np.empty((P.shape[0], m)), np.empty((P.shape[0], m))
        for j, (us, ws) in enumerate(self.path.starts):
            z0 = algebraic_z0_rows(P, us, ws)
            Z0[:, j] = np.where(np.isfinite(z0), z0, 0.0)
            W0[:, j] = rest_warp_rows(P, float(us[0]), Z0[:, j])
        return W0, Z0

    def many(self, thetas: np.ndarray) -> np.ndarray:
        """Vectorised cost for DE: thetas has shape (S, N)."""
        thetas = np.atleast_2d(thetas)
        self.calls += thetas.shape[0]
        depth = fold_depth(thetas, self.c, *self.fold) if self.fold is not None else np.zeros(thetas.shape[0])
        out = FOLD_PENALTY * (1.0 + depth)  # a folding backbone is not simulated
        run = depth <= 0
        if run.any():
            P = self.params_matrix(thetas[run])
            sse = np.empty(P.shape[0])
            W0, Z0 = self.start(P)
            pa = self.path
            rows = _sse_rows if P.shape[0] >= 4 else _sse_rows_serial
            rows(P, pa.u, pa.w, pa.weight, pa.offsets, W0, Z0, pa.budgets, self.tol, sse)
            sse = sse / self.wsum
            sse[~np.isfinite(sse)] = 1e6
            out[run] = sse
        return out

    def one(self, theta: np.ndarray) -> float:
        return float(self.many(theta[None, :])[0])


@njit(cache=True)
def _sse_row(p, u, w, weight, offsets, w0, z0, budgets, tol) -> float:
    s = 0.0
    for j in range(offsets.shape[0] - 1):
        a, b = offsets[j], offsets[j + 1]
        s += K.forward_sse_budget(p, u[a:b], w[a:b], weight[a:b], w0[j], z0[j], budgets[j], tol)
        if not s < np.inf:
            break
    return s


@njit(cache=True, parallel=True)
def _sse_rows(P, u, w, weight, offsets, W0, Z0, budgets, tol, out):
    for i in prange(P.shape[0]):
        out[i] = _sse_row(P[i], u, w, weight, offsets, W0[i], Z0[i], budgets, tol)


@njit(cache=True)
def _sse_rows_serial(P, u, w, weight, offsets, W0, Z0, budgets, tol, out):
    """One candidate at a time (the polish): a parallel region per evaluation would wait for a second
    thread to be scheduled, which on a busy machine costs more than the evaluation."""
    for i in range(P.shape[0]):
        out[i] = _sse_row(P[i], u, w, weight, offsets, W0[i], Z0[i], budgets, tol)


@dataclass
class SearchTrace:
    """How the search went: generations run, best cost per generation, polish iterations (a second search,
    when there is one, appends to the same lists and counts)."""

    generations: int = 0
    best: list[float] = field(default_factory=list)
    spread: list[float] = field(default_factory=list)
    polish_iterations: int = 0
    stopped_early: bool = False
    restarts: int = 0  # searches run again because the first settled at the exponent's upper limit
    restart_kept: bool = False  # the search run again fitted the training part better and was kept
    fold_deg: float | None = None  # where the first search's backbone folded inside the working range (deg)
    working_range_deg: tuple[float, float] | None = None
    # the search run again with the fold kept outside: "kept", "fits worse" (the data show the fold) or
    # "still folds" (it found no backbone without one); "" when the first did not fold
    fold_outcome: str = ""
    fold_train_rms: tuple[float, float] | None = None  # training RMS of the first search and of the one without


def identify(t, u, w, *, heldout_frac: float = 0.25, seed: int = 0, popsize: int = 10, maxiter: int = 150,
             polish_evals: int = 2500, max_fit_points: int = 2500,
             prior: BoucWenParams | None = None, max_delay_s: float = 0.0,
             progress: Callable[[str, int, int], None] | None = None) -> IdentResult:
    """Identify the Bouc-Wen model (warp -> tendon) from a log by forward output error.

    ``t`` s, ``u`` mm, ``w`` deg, cleaned (finite, t strictly increasing). The last
    ``heldout_frac`` of the log (by time) is held out. ``prior`` (default: the
    paper's parameters) seeds one member of the population. ``progress(stage, i, n)``
    is called once per DE generation and every 20 polish iterations."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    u = np.ascontiguousarray(u, dtype=np.float64)
    w = np.ascontiguousarray(w, dtype=np.float64)
    check_log(t, u, w)
    if not 0.05 <= heldout_frac <= 0.5:
        raise ValueError("heldout_frac must lie in [0.05, 0.5]")
    norm = Normaliser.from_data(u, w)
    u_hat = (u - norm.uc) / norm.us
    w_hat = w / norm.ws
    two_sided = bool(np.mean(w < -0.05 * np.percentile(np.abs(w), 99)) > 0.02)
    bounds = BOUNDS_TWO_SIDED if two_sided else BOUNDS_ONE_SIDED

    n = t.size
    split_time = float(t[0] + (1.0 - heldout_frac) * (t[-1] - t[0]))
    n_train_end = int(np.searchsorted(t, split_time))
    train_mask = np.zeros(n, bool)
    train_mask[:n_train_end] = True
    held_mask = np.zeros(n, bool)
    held_mask[n_train_end:] = True

    # compressed training path: the model only needs reversals and a coarse grid; every candidate
    # starts from the state the first samples imply for it, so the whole training part is scored.
    # The global search scores on a bounded part of it, the polish on a larger one.
    search_path = FitPath.build(u_hat, w_hat, n_train_end, min(SEARCH_POINTS, max_fit_points), SEARCH_REVERSALS)
    polish_path = FitPath.build(u_hat, w_hat, n_train_end, max_fit_points, POLISH_REVERSALS)
    w_lo, w_hi = working_range(w, two_sided)
    fold_hat = (w_lo / norm.ws, w_hi / norm.ws)
    calls = [0]  # evaluations over every search

    prior = prior if prior is not None else BoucWenParams.paper()
    x0 = normalised_to_theta(norm.to_normalised(prior), two_sided, norm.c)
    if x0 is not None:
        x0 = np.clip(x0, [b[0] for b in bounds], [b[1] for b in bounds])
    trace = SearchTrace()

    first_search = [0, 0]  # generations and polish iterations the first search ran, once a second one starts
    stage = ["search"]  # the progress stage of the search running: "search", "search again", "search without a fold"

    def _cb(intermediate_result=None):
        trace.generations += 1
        if intermediate_result is not None:
            trace.best.append(float(intermediate_result.fun))
        if progress:  # the generations of this search (a second one counts from 1 again)
            progress(stage[0], trace.generations - first_search[0], maxiter)
        if intermediate_result is not None:
            e = np.asarray(intermediate_result.population_energies)
            trace.spread.append(float(np.std(e) / max(abs(float(np.mean(e))), 1e-300)))
        return False

    lo = np.array([b[0] for b in bounds])
    hi = np.array([b[1] for b in bounds])

    def _nm_cb(_xk):
        trace.polish_iterations += 1
        done = trace.polish_iterations - first_search[1]
        if progress and done % 20 == 0:
            progress("polish", min(done, polish_evals), polish_evals)

    def search_and_polish(de_seed: int, fold: tuple[float, float] | None = None) -> tuple[np.ndarray, float]:
        """Global search, delay scan and polish from one random seed: (theta, transport delay s); with ``fold``,
        backbones folding inside that range (normalised warp) are penalised."""
        search = _Objective(search_path, norm.c, fold=fold)
        obj = _Objective(polish_path, norm.c, fold=fold)
        de = differential_evolution(
            lambda X: search.many(np.atleast_2d(X.T)), bounds, popsize=popsize, maxiter=maxiter, tol=SEARCH_SPREAD,
            atol=0.0, mutation=(0.5, 1.0), recombination=0.9, seed=de_seed, polish=False, init="latinhypercube",
            updating="deferred", vectorized=True, x0=x0, callback=_cb)
        # the polish starts from whichever of the search's five best is best on the polish's data
        top = np.asarray(de.population)[np.argsort(de.population_energies)[:5]]
        costs = obj.many(top)
        x_start = top[int(np.argmin(costs))]
        delay = 0.0
        if max_delay_s > 0:
            no_delay_start = x_start
            delay, x_start, scan_calls = _delay_search(t, u_hat, w_hat, n_train_end, norm.c, x_start, lo, hi,
                                                       max_delay_s, progress, fold)
            search.calls += scan_calls
        if delay > 0:
            obj_d = _Objective(FitPath.build(delayed(t, u_hat, delay), w_hat, n_train_end, max_fit_points,
                                             POLISH_REVERSALS), norm.c, fold=fold)
            best, cost = _polish(obj_d, x_start, lo, hi, polish_evals, _nm_cb)
            # the scan judged on a smaller path with short polishes: the delay is kept only if the fully polished
            # model with it still beats the one without it (the same amount of polish) on the polish's path
            no_delay, cost0 = _polish(obj, no_delay_start, lo, hi, polish_evals, _nm_cb)
            search.calls += obj_d.calls
            if cost > (1.0 - DELAY_GAIN) * cost0:
                log.info("transport delay %.1f ms not kept: polished, it fits no better than none", 1e3 * delay)
                delay, best = 0.0, no_delay
        else:
            best, _ = _polish(obj, x_start, lo, hi, polish_evals, _nm_cb)
        calls[0] += search.calls + obj.calls
        return best, delay

    def evaluate(theta: np.ndarray, delay: float):
        """(physical parameters, z0, prediction of the whole log, training RMS) of one search result."""
        params = norm.to_physical(theta_to_normalised(theta, norm.c))
        x = delayed(t, u, delay) if delay > 0 else u
        z0 = estimate_z0(params, x[:n_train_end], w[:n_train_end])
        w_pred, _, _ = forward(params, x, z0=z0)
        return params, z0, w_pred, float(np.sqrt(np.mean((w_pred - w)[train_mask] ** 2)))

    best, delay = search_and_polish(seed)
    params, z0, w_pred, train_rms = evaluate(best, delay)
    if at_exponent_edge(best, lo, hi, EDGE_FRAC):
        # the exponent n trades against the saturation levels along a long, flat ridge, and a search can
        # walk up it to the box's upper limit; a second search from another seed, the better on training kept
        log.info("the search settled at the exponent's upper limit (n = %.3g): searching again", params.n)
        trace.restarts += 1
        first_search[:] = [trace.generations, trace.polish_iterations]
        stage[0] = "search again"
        best2, delay2 = search_and_polish(seed + 1)
        again = evaluate(best2, delay2)
        if again[3] < train_rms:
            trace.restart_kept = True
            best, delay = best2, delay2
            params, z0, w_pred, train_rms = again
    if fold_depth(best, norm.c, *fold_hat)[0] > 0:
        trace.fold_deg = float(norm.ws * backbone_vertex(best, norm.c)[0])
        trace.working_range_deg = (w_lo, w_hi)
        log.info("the backbone folds at %.3g deg, inside the working range %.3g..%.3g deg: searching again with "
                 "the fold kept outside it", trace.fold_deg, w_lo, w_hi)
        first_search[:] = [trace.generations, trace.polish_iterations]
        stage[0] = "search without a fold"
        best2, delay2 = search_and_polish(seed, fold_hat)
        unfolded = evaluate(best2, delay2)
        trace.fold_train_rms = (train_rms, unfolded[3])
        if fold_depth(best2, norm.c, *fold_hat)[0] > 0:
            trace.fold_outcome = "still folds"
            log.warning("no backbone without a fold inside the working range fits: the first search's model kept")
        elif unfolded[3] > FOLD_KEEP * train_rms:
            trace.fold_outcome = "fits worse"
            log.info("without the fold the training RMS rises from %.3g to %.3g deg: the data show the fold, the "
                     "first search's model kept", train_rms, unfolded[3])
        else:
            trace.fold_outcome = "kept"
            best, delay = best2, delay2
            params, z0, w_pred, train_rms = unfolded
    err = w_pred - w
    held_rms = float(np.sqrt(np.mean(err[held_mask] ** 2))) if held_mask.any() else float("nan")
    noise = noise_floor(w)
    return IdentResult(
        params=params, train_rms=train_rms, heldout_rms=held_rms, noise=noise,
        linear_heldout_rms=linear_baseline(u, w, train_mask, held_mask), n_train=int(train_mask.sum()),
        n_heldout=int(held_mask.sum()), two_sided=two_sided, evaluations=calls[0],
        split_time=split_time, w_pred=w_pred, train_mask=train_mask, heldout_mask=held_mask, z0=z0, trace=trace,
        support=support_check(t, u, w, w_pred, train_mask, held_mask, noise), delay_s=delay,
        travel_mm=central_range(u))


def at_exponent_edge(theta: np.ndarray, lo: np.ndarray, hi: np.ndarray, frac: float) -> bool:
    """True when the exponent n (theta[0]) lies within ``frac`` of its range from the box's upper end: a
    limit of the search, not of the model (n = 1, the lower end, is the classical Bouc-Wen and Dahl form)."""
    return bool(theta[0] >= hi[0] - frac * (hi[0] - lo[0]))


def _polish(obj: _Objective, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray, evals: int,
            callback=None) -> tuple[np.ndarray, float]:
    """Nelder-Mead from ``x0`` inside the box [lo, hi] (a penalty outside it): (theta, its cost)."""

    def clipped(th):
        pen = float(np.sum(np.maximum(th - hi, 0) + np.maximum(lo - th, 0)))
        return obj.one(np.clip(th, lo, hi)) + 10.0 * pen

    f0 = obj.one(x0)
    nm = minimize(clipped, x0, method="Nelder-Mead", callback=callback,
                  options={"maxfev": evals, "xatol": 1e-7, "fatol": 1e-14, "adaptive": True})
    if not nm.fun <= f0:
        return x0, f0
    best = np.clip(nm.x, lo, hi)
    return best, obj.one(best)


def _delay_search(t, u_hat, w_hat, n_end: int, c: float, theta0: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                  max_delay_s: float, progress, fold: tuple[float, float] | None = None,
                  ) -> tuple[float, np.ndarray, int]:
    """(delay s, theta to polish from, evaluations): the transport delay in front of the model that fits the
    training part best, by a short polish at no delay and at each delay of ``DELAY_GRID_S`` on the global
    search's path, each from the best model so far. The scan stops once two delays in a row cost half as
    much again as the best; a parabola through the best and its neighbours places the delay between grid
    points. No delay unless the best lowers the cost by ``DELAY_GAIN``."""
    dur = float(t[n_end - 1] - t[0]) if n_end > 1 else 0.0
    grid = [d for d in DELAY_GRID_S if d <= max_delay_s and d <= 0.05 * dur]

    calls = 0

    def fit_at(d: float, start: np.ndarray) -> tuple[np.ndarray, float]:
        nonlocal calls
        x = delayed(t, u_hat, d) if d > 0 else u_hat
        obj = _Objective(FitPath.build(x, w_hat, n_end, SEARCH_POINTS, SEARCH_REVERSALS), c, fold=fold)
        out = _polish(obj, start, lo, hi, DELAY_SCAN_EVALS)
        calls += obj.calls
        return out

    th0, cost0 = fit_at(0.0, theta0)
    tried = {0.0: cost0}
    best_d, best_th, best_cost = 0.0, th0, cost0
    worse = 0
    for i, d in enumerate(grid):
        if progress:
            progress("delay", i, len(grid))
        th, f = fit_at(d, best_th)
        tried[d] = f
        if f < best_cost:
            best_d, best_th, best_cost, worse = d, th, f, 0
        elif f > 1.5 * best_cost:
            worse += 1
            if worse >= 2:
                break
    if progress:
        progress("delay", len(grid), len(grid))
    if best_d <= 0 or best_cost > (1.0 - DELAY_GAIN) * cost0:
        return 0.0, th0, calls
    ds = sorted(tried)
    k = ds.index(best_d)
    if k + 1 < len(ds):  # the vertex of the parabola through the best delay and its two neighbours
        (d0, d1, d2), (f0, f1, f2) = ds[k - 1:k + 2], (tried[d] for d in ds[k - 1:k + 2])
        den = (d1 - d0) * (f1 - f2) - (d1 - d2) * (f1 - f0)
        if den != 0:
            v = d1 - 0.5 * ((d1 - d0) ** 2 * (f1 - f2) - (d1 - d2) ** 2 * (f1 - f0)) / den
            best_d = float(min(max(v, 0.5 * (d0 + d1)), 0.5 * (d1 + d2)))
    log.info("transport delay %.1f ms: training cost at no delay %.3g, at the best delay of the scan %.3g",
             1e3 * best_d, cost0, best_cost)
    return best_d, best_th, calls
