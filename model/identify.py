"""Identification of the generalized Bouc-Wen model from a log, in named steps.

The method. In the paper's form the tendon travel is linear in the backbone and
state coefficients (a1, a2, a3, az) once the hysteretic state's trajectory is
fixed by the warp and the shape parameters (A, n, b). So:

1. ``read``: the log's arrays checked (``check_log``), normalised (w / Ws,
   (u - uc) / Us: the search box is the same for any wing) and split; the last
   ``heldout_frac`` of the log (by time) is held out and only scored.
2. ``excite check``: how many reversals the training part holds, at which levels
   of the warp range, over how wide a band (``excitation_check``); what a log
   does not excite is said, and the parameters it leaves open are flagged by
   the uncertainty step.
3. ``start design``: a deterministic, well-spread set of trial shapes (a
   scrambled Sobol' sequence with a fixed seed; ``seed`` selects another
   scramble, 0 the default), the paper's shape and the prior's
   (``model.ident_design``).
4. ``linear solve``: for each trial shape the state is integrated once over the
   measured warp and (a1, a2, a3, az) are solved exactly by least squares on the
   input-side error (separable least squares, variable projection); the straight
   line and the quadratic without hysteresis are inside every solve (az = 0). The
   warp's jitter is removed first (every noise reversal would be a real reversal
   of the model): the log is cut into runs at the input's real turns (a turn of
   the input inside the model's dead zone moves the warp by less than its noise)
   and, for half of the starts, at the warp's own (a closed loop's command
   reacts to the sensor's noise, so its turns are not the warp's), and in each
   run the warp is replaced by its least-squares monotone fit.
   ``servo``: the servo's position loop smooths what the command does faster than it (a closed
   loop's feed-forward jumps at each setpoint step) and crosses a large jump at its rated speed; the
   model fed the raw command reverses where the tendon never went. The design's best shapes are solved
   again with the input through first-order lags, then under speed caps (``lag_scan``; each row's
   command held until the next, ``effects.servo_follow``); the best servo, when it lowers their
   input-side cost by ``LAG_GAIN_SURE`` (or by ``LAG_GAIN`` and a short refinement of the final model
   without it fits better through it), is put in front of the model once the model without it is final
   (steps 5-8): the design is solved again through it and refined, with the model found without it as
   one more start, checked for a fold and against the simpler models, and the servo is kept only when
   the result fits the training part better by ``DELAY_GAIN`` and by what the information criterion asks
   of its parameters on the log's effective samples (``lag_pays``; ``servo_tau_s``, ``servo_rate_mm_s``;
   not with a delay scan, whose delay stands for it).
5. ``local refine``: the distinct best shapes, with the straight line and the
   quadratic backbone, are scored on the forward output error (warp simulated
   from the logged tendon input, every stretch started from the state its own
   first samples imply) and the best few refined by Levenberg-Marquardt on the
   per-sample forward residuals (``model.ident_path``), the best of them again on
   a larger part of the training data; the best start without hysteresis is
   always among those refined. A log with more reversals than a fit needs is
   scored on evenly spread stretches; a noisy input's reversals are counted
   above its noise for that (a closed-loop log's jitter would otherwise cut the
   stretches to a few samples each), while every reversal inside a stretch,
   jitter's included, is simulated as the model sees it. A result at the exponent's upper limit
   (n trades against the saturation levels along a flat ridge) is refined again
   from the next start, the better on training kept. When no two refined starts
   agree, or the result fits far above the noise floor (a wide two-sided loop
   whose basin the design can miss), the search escalates: a differential
   evolution with a fixed seed derived from the design's, seeded with the refined
   results and the design's best starts (``model.ident_global``), its best
   members refined the same way; the result that runs free over the training part
   best is kept (never chosen by held-out data).
6. ``delay``: with ``max_delay_s``, a scan of transport delays in front of the
   model (a short refinement each, from the best model so far) and a final
   refinement at the best; kept only when it lowers the training cost by
   ``DELAY_GAIN`` against the model without it (``delay_s``).
7. ``fold check``: a backbone u = a1 w^2 + a2 w + a3 that turns back inside the
   working range (``working_range``) is refined again from starts that do not
   fold, with folding backbones rejected; kept unless it fits the training part
   more than ``FOLD_KEEP`` worse (then the data show the fold).
8. ``simpler models``: a fit whose training RMS is above the best straight
   line's (fitted on the same samples) is a failed search: the refinement
   starts again from the line and from the quadratic backbone, and a result
   worse than the line is never returned. A fit that cannot beat a line on the
   held-out part says so (``support_check``).
9. ``model-error model``: what the model still gets wrong on the log, learned for
   the diagnosis (``model.model_error``; the CLI step).
10. ``uncertainty``: a 95 % interval for every parameter from the Gauss-Newton
    curvature at the optimum with the residual variance scaled by the residuals'
    effective sample count (``model.ident_uncertainty``); the parameters the data
    do not determine are named.

The answer does not depend on luck: the design is fixed and the refinements are
deterministic. Everything here is pure numerics; progress is reported through a
callback (stages "design", "refine", "refine again", "global", "refine without a fold",
"delay", "line").
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from warpbridge.model import ident_design as design
from warpbridge.model.boucwen import BoucWenParams, forward
from warpbridge.model.effects import delayed, servo_follow
from warpbridge.model.ident_global import global_search
from warpbridge.model.ident_path import (
    BUDGET_PER_POINT,
    BUDGET_PER_REVERSAL,
    FIT_TOL_Z,
    FOLD_PENALTY,
    POLISH_REVERSALS,
    SEARCH_POINTS,
    SEARCH_REVERSALS,
    START_SAMPLES,
    STRETCHES,
    FitPath,
    Objective,
    fit_stretches,
    jacobian,
    refine,
    rest_warp_rows,
)
from warpbridge.model.ident_space import (
    BOUNDS_ONE_SIDED,
    BOUNDS_TWO_SIDED,
    THETA_NAMES,
    Normaliser,
    backbone_vertex,
    fold_depth,
    normalised_to_theta,
    theta_to_normalised,
    thetas_to_rows,
)
from warpbridge.model.ident_uncertainty import Uncertainty, intervals
from warpbridge.model.initial_state import estimate_z0
from warpbridge.model.signals import (
    central_range,
    compress_path,
    effective_samples,
    linear_baseline,
    linear_fit,
    noise_floor,
    reversal_indices,
    turning_indices,
    turning_points,
    warmup_end,
)

__all__ = [
    "BOUNDS_ONE_SIDED", "BOUNDS_TWO_SIDED", "BUDGET_PER_POINT", "BUDGET_PER_REVERSAL", "DELAY_GAIN", "DELAY_GRID_S",
    "EDGE_FRAC", "FIT_TOL_Z", "FOLD_KEEP", "FOLD_MARGIN", "FOLD_PENALTY", "MIN_TURNING_POINTS", "POLISH_REVERSALS",
    "SEARCH_POINTS", "SEARCH_REVERSALS", "START_SAMPLES", "STRETCHES", "THETA_NAMES", "Excitation", "FitPath",
    "IdentResult", "Normaliser", "SearchTrace", "Support", "at_exponent_edge", "backbone_vertex", "central_range",
    "check_log", "compress_path", "excitation_check", "fit_stretches", "fold_depth", "identify", "linear_baseline",
    "linear_fit", "noise_floor", "normalised_to_theta", "rest_warp_rows", "reversal_indices", "support_check",
    "theta_to_normalised", "thetas_to_rows", "turning_points", "warmup_end", "working_range",
]

log = logging.getLogger(__name__)

EDGE_FRAC = 0.01  # a result this close (share of the range) to the exponent's upper limit is at it
EDGE_AGREE = 0.01  # refined starts whose costs agree within this (std / mean) put n at the limit themselves
FOLD_MARGIN = 0.5  # the working range reaches this share of the log's warp span beyond it on each side
FOLD_KEEP = 1.05  # the refinement without a fold is kept when its training RMS is at most this times the first's
DELAY_GRID_S = (0.005, 0.01, 0.02, 0.03, 0.045, 0.065, 0.09, 0.12, 0.16)  # transport delays the scan tries (s)
DELAY_SCAN_ITER = 6  # refinement steps at each delay of the scan
DELAY_GAIN = 0.02  # a delay is kept only when it lowers the training cost by this share of the no-delay cost
MAX_REFINED = 6  # ... or more, up to this many, until two of them agree within AGREE
AGREE = 0.01
RANKED_PER_POPSIZE = 6  # distinct design starts ranked on the forward error, per unit of ``popsize``
REFINED_STARTS = 2  # starts refined on the search's path (the best by forward cost) ...
SEARCH_ITER = 40  # ... for at most this many steps each; the best again on the polish's path
MIN_TURNING_POINTS = 4  # reversals (5 % of the span or more) the training part needs to pin the loop down
NARROW_NOISES = 20.0  # a training warp band narrower than this many noise deviations is narrow
SIMPLE_STARTS = ("line", "quadratic")  # the starts without hysteresis, inside the class
LOOP_FLOOR = 1e-3  # az (normalised) of a start without hysteresis: a loop too narrow to matter
ESCALATE_NOISES = 5.0  # ... or when the first result's training RMS is above this many noise deviations
GLOBAL_SEEDED = 10  # the design's best starts placed in its first population, beside the refined results
POPSIZE_GLOBAL = 110  # its population (ten per parameter of a two-sided wing)
MAXITER_GLOBAL = 150  # generations of the escalation's global search at most (``model.ident_global``)
LAG_GRID_S = (0.005, 0.01, 0.02, 0.03, 0.05, 0.08)  # servo lags the scan tries (s)
LAG_GAIN = 0.1  # a lag is proposed when it lowers the design's best input-side cost by this share of the no-lag's
# ... and searched at once when by this share: a closed loop's jumps through the servo leave 0.17-0.39 of the
# cost on the SITL's logs; a smaller gain (0.6-0.8 left on bench logs, a sine's with no lag at all 0.69) is
# first checked by a short refinement of the model without it, with and without the lag (``lag_checks``)
LAG_GAIN_SURE = 0.5
LAG_SHAPES = 32  # the design's best distinct shapes (at no lag) the scan solves at each lag
# speed caps the scan tries, per the fastest the lagged command asks for: a servo crosses a large jump of the
# command at its rated speed (a hobby servo's 0.1 s per 60 deg on a 10 mm horn is about 100 mm/s of tendon)
RATE_FRACTIONS = (0.7, 0.5, 0.35, 0.25, 0.18, 0.12)
# the search trace's record of the fold and simpler-model steps: the lag's pass writes its own, kept with it
LAG_PASS_FIELDS = ("fold_deg", "working_range_deg", "fold_outcome", "fold_train_rms", "line_restart", "kept_start")
LINE_ZSAT = -3.5  # log10 of the state's saturation (normalised) of the straight-line and quadratic starts


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


def at_exponent_edge(theta: np.ndarray, lo: np.ndarray, hi: np.ndarray, frac: float) -> bool:
    """True when the exponent n (theta[0]) lies within ``frac`` of its range from the box's upper end: a
    limit of the search, not of the model (n = 1, the lower end, is the classical Bouc-Wen and Dahl form)."""
    return bool(theta[0] >= hi[0] - frac * (hi[0] - lo[0]))


# ---- step 1: read ------------------------------------------------------------------------------

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


@dataclass(frozen=True)
class Servo:
    """The servo's position loop in front of the model (``effects.servo_follow``): a first-order lag of
    ``tau_s`` capped at ``rate_mm_s`` (inf: no cap); the default passes the command through as logged."""

    tau_s: float = 0.0
    rate_mm_s: float = math.inf

    @property
    def active(self) -> bool:
        return self.tau_s > 0 or math.isfinite(self.rate_mm_s)

    @property
    def parameters(self) -> int:
        """How many parameters it adds to the model (for the information criterion)."""
        return int(self.tau_s > 0) + int(math.isfinite(self.rate_mm_s))

    def apply(self, t: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The tendon travel the servo gives for commands u (u itself when inactive)."""
        return servo_follow(t, u, self.tau_s, self.rate_mm_s, float(u[0])) if self.active else u

    def __str__(self) -> str:
        lag = f"{1e3 * self.tau_s:.1f} ms"
        return lag + (f" capped at {self.rate_mm_s:.3g} mm/s" if math.isfinite(self.rate_mm_s) else "")


@dataclass
class LogData:
    """One log ready to fit: raw and normalised arrays, the split and the noise floor."""

    t: np.ndarray
    u: np.ndarray
    w: np.ndarray
    norm: Normaliser
    u_hat: np.ndarray
    w_hat: np.ndarray
    two_sided: bool
    n_train_end: int
    split_time: float
    train_mask: np.ndarray
    held_mask: np.ndarray
    noise: float
    servo: Servo = Servo()  # the servo the model's input passes through (``lag_scan``)
    x: np.ndarray | None = field(default=None, repr=False)  # the input the model sees: u through the servo (mm)
    x_hat: np.ndarray | None = field(default=None, repr=False)  # ... normalised

    def __post_init__(self) -> None:
        if self.x is None:
            self.x, self.x_hat = self.u, self.u_hat

    def with_servo(self, servo: Servo) -> LogData:
        """The same log with the model's input passed through ``servo``."""
        x = servo.apply(self.t, self.u)
        return replace(self, servo=servo, x=x, x_hat=(x - self.norm.uc) / self.norm.us)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        b = BOUNDS_TWO_SIDED if self.two_sided else BOUNDS_ONE_SIDED
        return np.array([x[0] for x in b]), np.array([x[1] for x in b])


def read(t, u, w, heldout_frac: float) -> LogData:
    """Step 1: the log's arrays checked, normalised and split (the last ``heldout_frac`` by time held out)."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    u = np.ascontiguousarray(u, dtype=np.float64)
    w = np.ascontiguousarray(w, dtype=np.float64)
    check_log(t, u, w)
    if not 0.05 <= heldout_frac <= 0.5:
        raise ValueError("heldout_frac must lie in [0.05, 0.5]")
    norm = Normaliser.from_data(u, w)
    two_sided = bool(np.mean(w < -0.05 * np.percentile(np.abs(w), 99)) > 0.02)
    n = t.size
    split_time = float(t[0] + (1.0 - heldout_frac) * (t[-1] - t[0]))
    n_end = int(np.searchsorted(t, split_time))
    train = np.zeros(n, bool)
    train[:n_end] = True
    return LogData(t, u, w, norm, (u - norm.uc) / norm.us, w / norm.ws, two_sided, n_end, split_time, train, ~train,
                   noise_floor(w))


# ---- step 2: excitation check ------------------------------------------------------------------

@dataclass
class Excitation:
    """What the training part excites: turning points of the input (5 % of its span or more), where in the
    warp range the warp turns back (maxima and minima per third of the training warp band), the band's width
    (deg and noise deviations), and one line per shortcoming (``notes``); ``poor`` when there is one."""

    turning_points: int
    maxima_per_third: tuple[int, int, int]
    minima_per_third: tuple[int, int, int]
    band_deg: float
    band_noises: float
    notes: list[str] = field(default_factory=list)

    @property
    def poor(self) -> bool:
        return bool(self.notes)

    def to_dict(self) -> dict:
        return {"turning_points": self.turning_points, "maxima_per_third": list(self.maxima_per_third),
                "minima_per_third": list(self.minima_per_third), "band_deg": self.band_deg,
                "band_noises": self.band_noises if math.isfinite(self.band_noises) else None,
                "poor": self.poor, "notes": list(self.notes)}


def excitation_check(u: np.ndarray, w: np.ndarray, noise: float) -> Excitation:
    """Step 2: how well the training part (``u``, ``w``) excites the model, and what it leaves open."""
    k = turning_points(u)
    lo, hi = central_range(w)
    band = hi - lo
    thr = max(0.05 * band, 10.0 * noise if math.isfinite(noise) else 0.0)
    turns = turning_indices(w, thr) if thr > 0 else np.zeros(0, dtype=np.int64)
    maxima, minima = [0, 0, 0], [0, 0, 0]
    for i in turns:
        prev = w[max(i - 1, 0)]
        third = int(min(2, max(0, (w[i] - lo) / band * 3))) if band > 0 else 1
        (maxima if w[i] >= prev else minima)[third] += 1
    band_noises = band / noise if noise > 0 and math.isfinite(noise) else math.inf
    notes = []
    if k < MIN_TURNING_POINTS:
        notes.append(f"too little excitation: the tendon input turns back only {k} times in the training part "
                     f"(at least {MIN_TURNING_POINTS} needed): the loop's shape is not pinned down")
    if band_noises < NARROW_NOISES:
        notes.append(f"a narrow band: the training warp spans {band:.3g} deg, {band_noises:.0f} noise deviations "
                     f"(under {NARROW_NOISES:.0f}): the backbone's curvature and the saturation are not pinned down")
    if k >= MIN_TURNING_POINTS:
        where = ("lower", "middle", "upper")
        no_max = [where[i] for i in range(3) if maxima[i] == 0]
        no_min = [where[i] for i in range(3) if minima[i] == 0]
        if sum(1 for x in maxima if x) + sum(1 for x in minima if x) <= 2:
            notes.append("reversals at one level only (the warp turns back at the same heights every time): the "
                         "return from a reversal inside the loop (minor loops) is not excited, so the return "
                         "ratios rest on the model's form")
        elif no_max == ["lower", "middle"] and no_min == ["middle", "upper"]:
            notes.append("the warp turns back only at the band's ends: minor loops are not excited")
    return Excitation(k, tuple(maxima), tuple(minima), float(band), float(band_noises), notes)


# ---- steps 3-4: start design and linear solve --------------------------------------------------

@dataclass
class Starts:
    """Search vectors to refine, best first by input-side cost, with the straight line and the quadratic
    backbone (no hysteresis) appended; ``evaluations`` of the linear solve."""

    thetas: np.ndarray
    input_rms: np.ndarray
    labels: list[str]
    evaluations: int


def start_design(data: LogData, seed: int, prior: BoucWenParams | None) -> tuple[np.ndarray, list[str]]:
    """Step 3: the trial shapes (A = 1 scale): the Sobol' design (scramble ``DESIGN_SEED + seed``), the
    paper's shape and the prior's."""
    S = design.sobol_design(data.two_sided, seed=design.DESIGN_SEED + seed)
    labels = ["design"] * S.shape[0]
    lo, hi = design.shape_bounds(data.two_sided)
    for name, p in (("paper", BoucWenParams.paper()), ("prior", prior)):
        if p is None:
            continue
        th = normalised_to_theta(data.norm.to_normalised(p), data.two_sided, data.norm.c)
        if th is not None:
            S = np.vstack([S, np.clip(design.theta_to_shape(th), lo, hi)])
            labels.append(name)
    return S, labels


def linear_solve(data: LogData, S: np.ndarray, labels: list[str], keep: int) -> Starts:
    """Step 4: (a1, a2, a3, az) solved exactly for every trial shape on the input-side error; the ``keep``
    distinct best as search vectors, then the straight line and the quadratic backbone."""
    lo, hi = design.shape_bounds(data.two_sided)
    thetas, rms, names, evaluations = [], [], [], 0
    for turns_from in ("input", "warp"):  # runs cut at the input's turns, and at the warp's: half the starts each
        wp = design.WarpPath.build(data.x_hat, data.w_hat, data.n_train_end, data.noise / data.norm.ws, turns_from)
        problem = design.InputSide(wp, data.norm.c)
        sol = problem.solve(S)
        evaluations += problem.evaluations
        best = design.distinct_best(S, sol.cost, max(1, (keep + 1) // 2), lo, hi)
        sub = design.LinearSolve(sol.cost[best], sol.alpha[best], sol.az[best], sol.ok[best])
        thetas.append(design.shapes_to_thetas(S[best], sub, LOOP_FLOOR))
        rms.append(np.sqrt(sol.cost[best]))
        names += [labels[i] for i in best]
        if turns_from == "input":
            quad = np.linalg.lstsq(problem.R, problem.Q.T @ problem.ub, rcond=None)[0]
    extra = [simple_theta(data, quad), simple_theta(data, line_alpha(data))]
    blo, bhi = data.bounds
    all_thetas = np.clip(np.vstack([*thetas, *extra]), blo, bhi)
    return Starts(all_thetas, np.concatenate([*rms, [np.nan, np.nan]]), names + ["quadratic", "line"], evaluations)


def line_alpha(data: LogData) -> np.ndarray:
    """Backbone (alpha1, alpha2, alpha3 around c, normalised) of the best straight line w = c0 + c1 u fitted
    on the training samples, written as u of w."""
    c0, c1 = linear_fit(data.x_hat, data.w_hat, data.train_mask)
    a2 = 1.0 / c1 if c1 != 0 else 1.0
    return np.array([0.0, a2, (data.norm.c - c0) * a2])


def simple_theta(data: LogData, alpha: np.ndarray) -> np.ndarray:
    """A search vector with backbone ``alpha`` and a state saturating at 10^LINE_ZSAT (no hysteresis)."""
    th = np.zeros(11 if data.two_sided else 9)
    th[0] = 2.0
    th[1] = 0.0
    th[2] = th[3] = LINE_ZSAT
    th[6:9] = alpha
    return th


def lag_pays(rms_without: float, rms_with: float, residuals: np.ndarray, parameters: int = 1) -> bool:
    """Does the servo earn its ``parameters``? The training cost must fall by ``DELAY_GAIN`` and by more than
    the Bayesian information criterion asks of them on the residuals' effective sample count
    (n_eff ln(c0 / c1) > k ln n_eff): a short log with few independent samples needs a clear gain."""
    c0, c1 = rms_without ** 2, rms_with ** 2
    if not (c1 > 0 and c1 <= (1.0 - DELAY_GAIN) * c0):
        return c1 == 0.0 < c0
    n_eff = max(effective_samples(residuals), 2.0)
    return bool(n_eff * math.log(c0 / c1) > max(parameters, 1) * math.log(n_eff))


def lag_checks(data: LogData, theta: np.ndarray, servo: Servo) -> bool:
    """Does a short refinement (``DELAY_SCAN_ITER`` steps on the search's path) from the model without the servo
    fit the training part better by ``DELAY_GAIN`` through it than without it?"""
    lo, hi = data.bounds
    costs = []
    for x in (data.x_hat, data.with_servo(servo).x_hat):
        obj = Objective(FitPath.build(x, data.w_hat, data.n_train_end, SEARCH_POINTS, SEARCH_REVERSALS), data.norm.c)
        costs.append(refine(obj, theta, lo, hi, DELAY_SCAN_ITER, tol=FIT_TOL_Z).cost)
    log.info("servo %s, a short refinement: cost %.4g without it, %.4g with it", servo, *costs)
    return bool(costs[1] <= (1.0 - DELAY_GAIN) * costs[0])


def parabola_vertex(tried: dict[float, float], best: float) -> float:
    """Where the parabola through the grid point ``best`` and its two neighbours in ``tried`` ({point: cost})
    has its minimum, kept within half a step of ``best``; ``best`` itself at the grid's ends."""
    ds = sorted(tried)
    k = ds.index(best)
    if not 0 < k < len(ds) - 1:
        return best
    (d0, d1, d2), (f0, f1, f2) = ds[k - 1:k + 2], (tried[d] for d in ds[k - 1:k + 2])
    den = (d1 - d0) * (f1 - f2) - (d1 - d2) * (f1 - f0)
    if den == 0 or not all(map(math.isfinite, (f0, f1, f2))):
        return best
    v = d1 - 0.5 * ((d1 - d0) ** 2 * (f1 - f2) - (d1 - d2) ** 2 * (f1 - f0)) / den
    return float(min(max(v, 0.5 * (d0 + d1)), 0.5 * (d1 + d2)))


def lag_scan(data: LogData, S: np.ndarray, max_lag_s: float) -> tuple[Servo, float]:
    """Step 4's servo: the position loop in front of the model (a first-order lag, capped at a rated speed)
    under which the design's best shapes explain the input best. The servo smooths what the command does
    faster than it (a closed loop's feed-forward jumps at every step of the setpoint) and a large jump it
    crosses at its rated speed: the model fed the raw command reverses where the tendon never went, and every
    loop after it is wrong. The input-side cost of the ``LAG_SHAPES`` best distinct shapes at no lag is solved
    again at each lag of ``LAG_GRID_S`` (up to ``max_lag_s`` and a twentieth of the training part), then at the
    best lag under speed caps of ``RATE_FRACTIONS`` of the fastest the lagged command asks for; a cap that
    lowers the cost by ``LAG_GAIN`` is kept and the lags are scanned again under it. A parabola through the
    best lag and its neighbours places it between grid points (the cap likewise, in its logarithm). Returns
    (servo, cost with it / cost without); no servo unless it lowers the cost by ``LAG_GAIN``; the forward
    error decides later."""
    t, n_end = data.t, data.n_train_end
    dur = float(t[n_end - 1] - t[0]) if n_end > 1 else 0.0
    grid = [d for d in LAG_GRID_S if d <= max_lag_s and d <= 0.05 * dur]
    if not grid:
        return Servo(), 1.0
    lo, hi = design.shape_bounds(data.two_sided)

    def cost_at(servo: Servo, shapes: np.ndarray) -> np.ndarray:
        d = data.with_servo(servo)
        wp = design.WarpPath.build(d.x_hat, d.w_hat, n_end, d.noise / d.norm.ws, "input")
        return design.InputSide(wp, d.norm.c).solve(shapes).cost

    c0 = cost_at(Servo(), S)
    keep = design.distinct_best(S, c0, LAG_SHAPES, lo, hi)
    if keep.size == 0:
        return Servo(), 1.0
    shapes = S[keep]
    none = float(np.min(c0[keep]))

    def lags_at(rate: float) -> dict[float, float]:
        tried = {0.0: none} if math.isinf(rate) else {}
        for lag in grid if math.isinf(rate) else [0.0, *grid]:
            c = cost_at(Servo(lag, rate), shapes)
            tried[lag] = float(np.min(c)) if np.isfinite(c).any() else math.inf
        return tried

    rate, tried = math.inf, lags_at(math.inf)
    lag = min(tried, key=lambda k: tried[k])
    fastest = float(np.max(np.abs(np.diff(Servo(lag).apply(t[:n_end], data.u[:n_end]))) / np.diff(t[:n_end])))
    if fastest > 0:
        by_rate = {math.log(f * fastest): float(np.min(cost_at(Servo(lag, f * fastest), shapes)))
                   for f in RATE_FRACTIONS}
        best_log = min(by_rate, key=lambda k: by_rate[k])
        if by_rate[best_log] <= (1.0 - LAG_GAIN) * tried[lag]:
            by_rate[math.log(fastest)] = tried[lag]  # the cap the command never reaches: none
            rate = math.exp(parabola_vertex(by_rate, best_log))
            tried = lags_at(rate)
            lag = min(tried, key=lambda k: tried[k])
    servo = Servo(parabola_vertex(tried, lag), rate)
    ratio = tried[lag] / none if none > 0 else 1.0
    if not servo.active or not ratio <= 1.0 - LAG_GAIN:
        return Servo(), 1.0
    log.info("servo %s: the design's best input-side cost %.3g at no lag, %.3g at the scan's best", servo, none,
             tried[lag])
    return servo, ratio


# ---- step 5: local refinement ------------------------------------------------------------------

@dataclass
class SearchTrace:
    """How the search went: design size and its evaluations, the starts refined and their forward cost,
    refinement steps, and what was searched again (``restarts`` at the exponent's limit, a fold, a fit worse
    than the line)."""

    generations: int = 0  # refinement steps (Gauss-Newton iterations) over every refinement
    best: list[float] = field(default_factory=list)  # cost of each refinement's result, in order
    spread: list[float] = field(default_factory=list)  # relative spread of the refined starts' results
    polish_iterations: int = 0
    stopped_early: bool = False
    restarts: int = 0  # refinements run again because the first settled at the exponent's upper limit
    restart_kept: bool = False  # the refinement run again fitted the training part better and was kept
    fold_deg: float | None = None  # where the first result's backbone folded inside the working range (deg)
    working_range_deg: tuple[float, float] | None = None
    # the refinement run again with the fold kept outside: "kept", "fits worse" (the data show the fold) or
    # "still folds" (it found no backbone without one); "" when the first did not fold
    fold_outcome: str = ""
    fold_train_rms: tuple[float, float] | None = None  # training RMS of the first result and of the one without
    design_size: int = 0
    starts: list[str] = field(default_factory=list)  # where each refined start came from
    start_costs: list[float] = field(default_factory=list)  # their forward costs (normalised) before refining
    line_restart: bool = False  # the result fitted the training part worse than the line: refined from it again
    line_train_rms: float = math.nan  # the best straight line's training RMS (deg)
    kept_start: str = ""
    global_search: bool = False  # the refined design starts disagreed: a global search ran (``model.ident_global``)
    global_kept: bool = False  # its refined result ran free over the training part better and was kept
    global_generations: int = 0
    global_train_rms: tuple[float, float] | None = None  # training RMS (deg) from the design and from the search
    lag_s: float = 0.0  # the servo lag the scan proposed (s; 0: none), kept or not
    lag_rate_mm_s: float = math.inf  # ... and the speed cap it proposed with it (inf: none)
    lag_train_rms: tuple[float, float] | None = None  # training RMS (deg) without the servo and with it


class Refiner:
    """Step 5's machinery: the search's and the polish's paths for one input (delayed or not) and the
    refinement from a list of starts."""

    def __init__(self, data: LogData, x_hat: np.ndarray, max_fit_points: int, fold: tuple[float, float] | None,
                 trace: SearchTrace, max_iter: int, progress, stage: str) -> None:
        self.data = data
        self.fold = fold
        self.search = Objective(FitPath.build(x_hat, data.w_hat, data.n_train_end,
                                              min(SEARCH_POINTS, max_fit_points), SEARCH_REVERSALS),
                                data.norm.c, fold=fold)
        self.x_hat = x_hat
        self.max_fit_points = max_fit_points
        self._polish: Objective | None = None
        self.trace = trace
        self.max_iter = max_iter
        self.progress = progress
        self.stage = stage
        self.lo, self.hi = data.bounds
        self.refined: list[tuple[float, np.ndarray, str]] = []  # (search cost, theta, label) of each refinement
        self.agreed = False  # two refined results agreed within ``AGREE``

    @property
    def polish_obj(self) -> Objective:
        if self._polish is None:
            self._polish = Objective(FitPath.build(self.x_hat, self.data.w_hat, self.data.n_train_end,
                                                   self.max_fit_points, POLISH_REVERSALS), self.data.norm.c,
                                     fold=self.fold)
        return self._polish

    @property
    def calls(self) -> int:
        return self.search.calls + (self._polish.calls if self._polish is not None else 0)

    def _cb(self, i: int) -> None:
        self.trace.generations += 1
        if self.progress:
            self.progress(self.stage, min(i, self.max_iter), self.max_iter)

    def rank(self, thetas: np.ndarray) -> np.ndarray:
        """Forward costs of the starts on the search's path."""
        return self.search.many(thetas)

    def run(self, thetas: np.ndarray, labels: list[str], n_refine: int) -> tuple[np.ndarray, float, str]:
        """(theta, polish cost, label): the ``n_refine`` best starts by forward cost refined on the search's
        path, the best of them refined again on the polish's."""
        costs = self.rank(thetas)
        order = [int(i) for i in np.argsort(costs) if np.isfinite(costs[i]) and costs[i] < FOLD_PENALTY]
        if not order:
            order = [int(np.argmin(costs))]
        # the best starts with hysteresis, however well a line starts (a wide loop's starts may all begin worse),
        # in order until two results agree within ``AGREE`` (at least ``n_refine``, at most ``MAX_REFINED``); then
        # the best start without hysteresis
        hyst = [i for i in order if labels[i] not in SIMPLE_STARTS] or order
        simple = [i for i in order if labels[i] in SIMPLE_STARTS]
        out = []
        for k, i in enumerate(hyst[:max(n_refine, MAX_REFINED)]):
            out.append(self._refine_one(thetas[i], labels[i], costs[i]))
            fs = sorted(x[0] for x in out)
            if k + 1 >= n_refine and len(fs) > 1 and fs[1] <= (1.0 + AGREE) * fs[0]:
                self.agreed = True
                break
        if simple and simple[0] not in hyst:
            out.append(self._refine_one(thetas[simple[0]], labels[simple[0]], costs[simple[0]]))
        self.refined = out
        fs = np.array([x[0] for x in out])
        self.trace.spread.append(float(np.std(fs) / max(abs(float(np.mean(fs))), 1e-300)))
        # the search's path starts every stretch afresh; the model must also run free over the whole training
        # part: the refined results are ranked by that (their training RMS), the search's cost breaking ties
        whole = [self.train_rms(x[1]) for x in out]
        best = min(range(len(out)), key=lambda j: (whole[j], out[j][0]))
        cost, theta, label = out[best]
        r = refine(self.polish_obj, theta, self.lo, self.hi, self.max_iter, self._polish_cb)
        return r.theta, r.cost, label

    def train_rms(self, theta: np.ndarray) -> float:
        """Training RMS (normalised warp) of the model run free over the whole training part of its input."""
        params = theta_to_normalised(theta, self.data.norm.c)
        n_end = self.data.n_train_end
        x, w = self.x_hat[:n_end], self.data.w_hat[:n_end]
        try:
            z0 = estimate_z0(params, x, w)
            pred = forward(params, x, z0=z0)[0]
        except ValueError:
            return math.inf
        v = float(np.sqrt(np.mean((pred - w) ** 2)))
        return v if math.isfinite(v) else math.inf

    def _refine_one(self, theta: np.ndarray, label: str, cost: float) -> tuple[float, np.ndarray, str]:
        r = refine(self.search, theta, self.lo, self.hi, self.max_iter, self._cb, tol=FIT_TOL_Z)
        self.trace.starts.append(label)
        self.trace.start_costs.append(float(cost))
        self.trace.best.append(float(r.cost))
        return r.cost, r.theta, label

    def _polish_cb(self, i: int) -> None:
        self.trace.polish_iterations += 1
        if self.progress:
            self.progress("polish", min(i, self.max_iter), self.max_iter)


# ---- step 6: delay -----------------------------------------------------------------------------

def delay_scan(data: LogData, theta0: np.ndarray, max_delay_s: float, fold, progress) -> tuple[float, np.ndarray, int]:
    """(delay s, theta to refine from, evaluations): the transport delay in front of the model that fits the
    training part best, by a short refinement at no delay and at each delay of ``DELAY_GRID_S`` on the
    search's path, each from the best model so far. The scan stops once two delays in a row cost half as much
    again as the best; a parabola through the best and its neighbours places the delay between grid points.
    No delay unless the best lowers the cost by ``DELAY_GAIN``."""
    t, n_end = data.t, data.n_train_end
    dur = float(t[n_end - 1] - t[0]) if n_end > 1 else 0.0
    grid = [d for d in DELAY_GRID_S if d <= max_delay_s and d <= 0.05 * dur]
    lo, hi = data.bounds
    calls = 0

    def fit_at(d: float, start: np.ndarray) -> tuple[np.ndarray, float]:
        nonlocal calls
        x = delayed(t, data.x_hat, d) if d > 0 else data.x_hat
        obj = Objective(FitPath.build(x, data.w_hat, n_end, SEARCH_POINTS, SEARCH_REVERSALS), data.norm.c, fold=fold)
        r = refine(obj, start, lo, hi, DELAY_SCAN_ITER, tol=FIT_TOL_Z)
        calls += obj.calls
        return r.theta, r.cost

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
    best_d = parabola_vertex(tried, best_d)
    log.info("transport delay %.1f ms: training cost at no delay %.3g, at the best delay of the scan %.3g",
             1e3 * best_d, cost0, best_cost)
    return best_d, best_th, calls


# ---- the result --------------------------------------------------------------------------------

@dataclass(frozen=True)
class Support:
    """Whether a log supports the identified model: it must beat a straight line on the held-out part."""

    supported: bool
    reason: str


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
    uncertainty: Uncertainty | None = field(default=None, repr=False)
    excitation: Excitation | None = None
    linear_train_rms: float = math.nan  # the best straight line's training RMS (deg)
    seed: int = 0  # the design's scramble (0: the default's)
    servo_tau_s: float = 0.0  # the servo's lag in front of the model (s): it sees u through a first-order lag
    servo_rate_mm_s: float = math.inf  # ... capped at this speed (mm/s; inf: no cap)

    def fit_dict(self) -> dict:
        d = {"train_rms_deg": self.train_rms, "heldout_rms_deg": self.heldout_rms, "noise_deg": self.noise,
             "linear_heldout_rms_deg": self.linear_heldout_rms, "n_train": self.n_train,
             "n_heldout": self.n_heldout, "split_time_s": self.split_time, "two_sided": self.two_sided,
             "evaluations": self.evaluations, "method": "variable-projection design + levenberg-marquardt",
             "z0_start_of_log": self.z0, "delay_s": self.delay_s, "servo_tau_s": self.servo_tau_s,
             "servo_rate_mm_s": self.servo_rate_mm_s if math.isfinite(self.servo_rate_mm_s) else None,
             "linear_train_rms_deg": self.linear_train_rms,
             "design_seed": self.seed}
        if self.travel_mm is not None:
            d["travel_mm"] = list(self.travel_mm)
        if self.support is not None:
            d |= {"supported": self.support.supported, "support": self.support.reason}
        if self.trace is not None and self.trace.restarts:  # the kept model came from the next start
            d |= {"searched_again": True, "second_search_kept": self.trace.restart_kept}
        if self.trace is not None and self.trace.fold_deg is not None:
            d |= {"backbone_fold_deg": self.trace.fold_deg, "working_range_deg": list(self.trace.working_range_deg),
                  "fold_search_kept": self.trace.fold_outcome == "kept",
                  "fold_train_rms_deg": list(self.trace.fold_train_rms or ())}
        if self.trace is not None:
            d |= {"design_size": self.trace.design_size, "start_kept": self.trace.kept_start,
                  "line_restart": self.trace.line_restart, "global_search": self.trace.global_search,
                  "global_search_kept": self.trace.global_kept}
            if self.trace.lag_train_rms is not None:
                d["servo_lag_train_rms_deg"] = list(self.trace.lag_train_rms)
        if self.excitation is not None:
            d["excitation"] = self.excitation.to_dict()
        if self.uncertainty is not None:
            d["uncertainty"] = self.uncertainty.to_dict()
        return d


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


# ---- the steps in order ------------------------------------------------------------------------

@dataclass
class Candidate:
    """A refined search vector with its delay, evaluated on the whole log."""

    theta: np.ndarray
    delay: float
    params: BoucWenParams
    z0: float
    w_pred: np.ndarray
    train_rms: float


def evaluate(data: LogData, theta: np.ndarray, delay: float) -> Candidate:
    """Physical parameters, z0, the prediction of the whole log and the training RMS of one search vector."""
    params = data.norm.to_physical(theta_to_normalised(theta, data.norm.c))
    x = delayed(data.t, data.x, delay) if delay > 0 else data.x
    n_end = data.n_train_end
    z0 = estimate_z0(params, x[:n_end], data.w[:n_end])
    w_pred, _, _ = forward(params, x, z0=z0)
    rms = float(np.sqrt(np.mean((w_pred - data.w)[data.train_mask] ** 2)))
    if not math.isfinite(rms):
        rms = math.inf
    return Candidate(theta, delay, params, z0, w_pred, rms)


def identify(t, u, w, *, heldout_frac: float = 0.25, seed: int = 0, popsize: int = 10, maxiter: int = 150,
             polish_evals: int = 2500, max_fit_points: int = 2500,
             prior: BoucWenParams | None = None, max_delay_s: float = 0.0, max_lag_s: float = LAG_GRID_S[-1],
             progress: Callable[[str, int, int], None] | None = None) -> IdentResult:
    """Identify the Bouc-Wen model (warp -> tendon) from a log by forward output error (see the module).

    ``t`` s, ``u`` mm, ``w`` deg, cleaned (finite, t strictly increasing). The last ``heldout_frac`` of the log
    (by time) is held out. ``seed`` selects the scramble of the start design (0: the fixed default; the answer
    does not depend on it beyond the refinements' tolerance); ``popsize`` distinct design starts are ranked on
    the forward error; each refinement takes at most ``maxiter`` Gauss-Newton steps and ``polish_evals``
    evaluations; ``prior`` (default: the paper's parameters) adds its shape to the design. ``max_lag_s`` bounds
    the servo lag the scan tries in front of the model (0: none), ``max_delay_s`` the transport delay (with a
    delay scan no lag is scanned: the delay stands for the servo, link and sensor lag together).
    ``progress(stage, i, n)`` is called once per refinement step."""
    data = read(t, u, w, heldout_frac)
    n_end = data.n_train_end
    exc = excitation_check(data.u[:n_end], data.w[:n_end], data.noise)
    trace = SearchTrace()
    lo, hi = data.bounds
    max_iter = max(1, min(maxiter, SEARCH_ITER, polish_evals // (lo.size + 1)))
    if progress:
        progress("design", 0, 1)
    S, labels = start_design(data, seed, prior)
    keep_starts = max(1, RANKED_PER_POPSIZE * popsize)
    # with a delay scan asked for, the delay stands for the servo, link and sensor lag together
    lag, lag_ratio = lag_scan(data, S, max_lag_s) if max_lag_s > 0 and max_delay_s <= 0 else (Servo(), 1.0)
    starts = linear_solve(data, S, labels, keep_starts)
    trace.design_size = int(S.shape[0])
    if progress:
        progress("design", 1, 1)
    calls = [starts.evaluations]
    refiners: list[Refiner] = []

    def search(thetas: np.ndarray, names: list[str], fold, stage: str, n_refine: int = REFINED_STARTS,
               ) -> tuple[np.ndarray, float]:
        """Steps 5-6 from these starts: (theta, delay)."""
        ref = Refiner(data, data.x_hat, max_fit_points, fold, trace, max_iter, progress, stage)
        refiners.append(ref)
        theta, cost, label = ref.run(thetas, names, n_refine)
        trace.kept_start = label
        calls[0] += ref.calls
        delay = 0.0
        if max_delay_s > 0:
            delay, x_start, scan_calls = delay_scan(data, theta, max_delay_s, fold, progress)
            calls[0] += scan_calls
            if delay > 0:
                ref_d = Refiner(data, delayed(data.t, data.x_hat, delay), max_fit_points, fold, trace, max_iter,
                                progress, stage)
                r = refine(ref_d.polish_obj, x_start, lo, hi, max_iter, ref_d._polish_cb)
                calls[0] += ref_d.calls
                if r.cost > (1.0 - DELAY_GAIN) * cost:
                    log.info("transport delay %.1f ms not kept: refined, it fits no better than none", 1e3 * delay)
                    delay = 0.0
                else:
                    theta = r.theta
        return theta, delay

    best = evaluate(data, *search(starts.thetas, starts.labels, None, "refine"))
    first = refiners[-1]
    if at_exponent_edge(best.theta, lo, hi, EDGE_FRAC) and trace.spread[-1] > EDGE_AGREE:
        # the exponent n trades against the saturation levels along a long, flat ridge, and a refinement can
        # walk up it to the box's upper limit; unless the refined starts all agree there (then the data put it
        # there), the next starts are refined, the better on training kept
        log.info("the refinement settled at the exponent's upper limit (n = %.3g): refining the next starts",
                 best.params.n)
        trace.restarts += 1
        costs = Refiner(data, data.x_hat, max_fit_points, None, trace, max_iter, None, "").rank(starts.thetas)
        order = [int(i) for i in np.argsort(costs)][REFINED_STARTS:] or list(range(len(starts.labels)))
        again = evaluate(data, *search(starts.thetas[order], [starts.labels[i] for i in order], None,
                                       "refine again"))
        if again.train_rms < best.train_rms:
            trace.restart_kept = True
            best = again
    if not first.agreed or best.train_rms > ESCALATE_NOISES * data.noise:
        best = escalate(data, best, first, starts, seed, trace, search, progress)
    best = fold_check(data, best, starts, trace, search)
    best = simpler_models(data, best, starts, trace, search, progress)
    if lag.active and lag_ratio > 1.0 - LAG_GAIN_SURE and not lag_checks(data, best.theta, lag):
        trace.lag_s, trace.lag_rate_mm_s = lag.tau_s, lag.rate_mm_s  # proposed, refused by the short refinement
        lag = Servo()
    if lag.active:  # the scan's servo: the design solved through it and refined, the model without it a start
        plain, data = data, data.with_servo(lag)
        kept_trace = {k: getattr(trace, k) for k in LAG_PASS_FIELDS}  # what the model without the lag did
        lag_starts = linear_solve(data, S, labels, keep_starts)
        th, d = search(np.vstack([best.theta, lag_starts.thetas]), ["no lag", *lag_starts.labels], None, "lag")
        with_lag = fold_check(data, evaluate(data, th, d), lag_starts, trace, search)
        with_lag = simpler_models(data, with_lag, lag_starts, trace, search, progress)
        trace.lag_s, trace.lag_rate_mm_s = lag.tau_s, lag.rate_mm_s
        trace.lag_train_rms = (best.train_rms, with_lag.train_rms)
        if lag_pays(best.train_rms, with_lag.train_rms, (best.w_pred - plain.w)[plain.train_mask], lag.parameters):
            best = with_lag
        else:
            log.info("servo %s not kept: the model fits the training part no better with it (%.4g deg "
                     "against %.4g without)", lag, with_lag.train_rms, best.train_rms)
            data = plain
            for k, v in kept_trace.items():
                setattr(trace, k, v)
    err = best.w_pred - data.w
    held_rms = float(np.sqrt(np.mean(err[data.held_mask] ** 2))) if data.held_mask.any() else float("nan")
    unc = uncertainty(data, best, exc)
    return IdentResult(
        params=best.params, train_rms=best.train_rms, heldout_rms=held_rms, noise=data.noise,
        linear_heldout_rms=linear_baseline(data.u, data.w, data.train_mask, data.held_mask),
        n_train=int(data.train_mask.sum()), n_heldout=int(data.held_mask.sum()), two_sided=data.two_sided,
        evaluations=calls[0], split_time=data.split_time, w_pred=best.w_pred, train_mask=data.train_mask,
        heldout_mask=data.held_mask, z0=best.z0, trace=trace,
        support=support_check(data.t, data.u, data.w, best.w_pred, data.train_mask, data.held_mask, data.noise),
        delay_s=best.delay, travel_mm=central_range(data.u), uncertainty=unc, excitation=exc,
        linear_train_rms=trace.line_train_rms, seed=seed, servo_tau_s=data.servo.tau_s,
        servo_rate_mm_s=data.servo.rate_mm_s)


def escalate(data: LogData, best: Candidate, first: Refiner, starts: Starts, seed: int, trace: SearchTrace,
             search, progress) -> Candidate:
    """Step 5's escalation: no two refined design starts agreed, or the result fits far above the noise
    floor, so the design may have missed the best basin. A global search (``model.ident_global``, seed derived
    from the design's) over the refinement's objective, its first population holding the refined results and
    the design's best starts; its best members are refined like the design's; the result that runs free over the
    training part better is kept."""
    lo, hi = data.bounds
    refined = sorted(first.refined, key=lambda x: x[0])
    seeded = np.vstack([np.array([x[1] for x in refined]).reshape(-1, lo.size), starts.thetas[:GLOBAL_SEEDED]])
    log.info("no two refined starts agree, or the fit is far above the noise floor (training RMS %.3g deg, noise "
             "%.3g): a global search (differential evolution) from the refined starts", best.train_rms, data.noise)
    trace.global_search = True

    def cb(i: int) -> None:
        if progress:
            progress("global", min(i, MAXITER_GLOBAL), MAXITER_GLOBAL)

    g = global_search(first.search, lo, hi, seeded, seed, popsize=POPSIZE_GLOBAL, maxiter=MAXITER_GLOBAL,
                      callback=cb)
    trace.global_generations = g.generations
    th, d = search(g.thetas, ["global"] * len(g.thetas), None, "global")
    cand = evaluate(data, th, d)
    log.info("global search: training RMS %.4g deg against %.4g deg from the design", cand.train_rms, best.train_rms)
    trace.global_train_rms = (best.train_rms, cand.train_rms)
    if cand.train_rms < best.train_rms:
        trace.global_kept = True
        trace.kept_start = "global"
        return cand
    return best


def fold_check(data: LogData, best: Candidate, starts: Starts, trace: SearchTrace, search) -> Candidate:
    """Step 7: a backbone that folds inside the working range is refined again from starts that do not fold,
    folding backbones rejected; the result is kept unless it fits the training part ``FOLD_KEEP`` worse."""
    w_lo, w_hi = working_range(data.w, data.two_sided)
    fold_hat = (w_lo / data.norm.ws, w_hi / data.norm.ws)
    if fold_depth(best.theta, data.norm.c, *fold_hat)[0] > 0:
        trace.fold_deg = float(data.norm.ws * backbone_vertex(best.theta, data.norm.c)[0])
        trace.working_range_deg = (w_lo, w_hi)
        log.info("the backbone folds at %.3g deg, inside the working range %.3g..%.3g deg: refining again with "
                 "the fold kept outside it", trace.fold_deg, w_lo, w_hi)
        flat = starts.thetas.copy()
        ok = fold_depth(flat, data.norm.c, *fold_hat) <= 0
        th2, d2 = search(flat[ok] if ok.any() else flat, [n for n, k in zip(starts.labels, ok, strict=True) if k]
                         if ok.any() else starts.labels, fold_hat, "refine without a fold")
        unfolded = evaluate(data, th2, d2)
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


def uncertainty(data: LogData, best: Candidate, exc: Excitation) -> Uncertainty | None:
    """Step 10: 95 % intervals of every parameter at the optimum (``model.ident_uncertainty``), on the
    polish's path of the model's own input (its delay applied)."""
    x = delayed(data.t, data.x_hat, best.delay) if best.delay > 0 else data.x_hat
    obj = Objective(FitPath.build(x, data.w_hat, data.n_train_end, 2500, POLISH_REVERSALS), data.norm.c)
    lo, hi = data.bounds
    try:
        J, r = jacobian(obj, best.theta, lo, hi)
    except (ValueError, FloatingPointError):
        return None
    norm = data.norm

    def to_physical(theta: np.ndarray) -> np.ndarray:
        return norm.to_physical(BoucWenParams.from_array(thetas_to_rows(theta, norm.c)[0])).to_array()

    names = THETA_NAMES[:best.theta.size]
    fixed = {"az": "the model's scale is fixed by az = 1 (z in mm of tendon)"}
    if not data.two_sided:
        fixed_b = "with warp of one sign only four combinations of b1..b6 act; the two others (asinh_D, asinh_E) are 0"
        fixed["b"] = fixed_b
    try:
        out = intervals(best.theta, names, J, r, norm.ws, lo, hi, to_physical, fixed)
    except (ValueError, np.linalg.LinAlgError):
        return None
    for note in exc.notes:
        log.info("excitation: %s", note)
    return out
