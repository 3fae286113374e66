"""Step 5 of identification, ``local refine``: the distinct best starts, with the straight line and the
quadratic backbone, scored on the forward output error (``path``) and the best few refined by
Levenberg-Marquardt, the best of them again on a larger part of the training data (``Refiner``);
``SearchTrace`` records how the search went, ``evaluate`` runs a refined vector over the whole log
(``Candidate``), and ``at_exponent_edge`` says when a result settled at the exponent's upper limit."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from warpbridge.model.boucwen import BoucWenParams, forward
from warpbridge.model.effects import delayed
from warpbridge.model.identification.data import LogData
from warpbridge.model.identification.path import (
    FIT_TOL_Z,
    FOLD_PENALTY,
    POLISH_REVERSALS,
    SEARCH_POINTS,
    SEARCH_REVERSALS,
    FitPath,
    Objective,
    refine,
)
from warpbridge.model.identification.space import theta_to_normalised
from warpbridge.model.initial_state import estimate_z0

# the starts refined from a list (``Refiner.run``): at least ``n_refine`` (``pipeline.REFINED_STARTS``) ...
MAX_REFINED = 6  # ... or more, up to this many, until two of them agree within AGREE
AGREE = 0.01
SIMPLE_STARTS = ("line", "quadratic")  # the starts without hysteresis, inside the class


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
    global_search: bool = False  # the refined design starts disagreed: a global search ran (``global_search``)
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


def at_exponent_edge(theta: np.ndarray, lo: np.ndarray, hi: np.ndarray, frac: float) -> bool:
    """True when the exponent n (theta[0]) lies within ``frac`` of its range from the box's upper end: a
    limit of the search, not of the model (n = 1, the lower end, is the classical Bouc-Wen and Dahl form)."""
    return bool(theta[0] >= hi[0] - frac * (hi[0] - lo[0]))
