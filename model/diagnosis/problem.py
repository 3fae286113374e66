"""Fitting the effects' augmentations of a nominal model to a log, on training segments only.

``Problem`` holds a cleaned log, the nominal model (Bouc-Wen parameters, the
effects it already carries, z0) and a blocked train/score split. It predicts
the measured warp for any ``Effects`` with the same operators, in the same
order, as ``model.plant.Plant.simulate``, and caches the expensive part (the
Bouc-Wen forward map, which depends only on the input-side effects, the
capstan stall among them, and the friction scale and pivot). An effect with several
forms (friction: the band scaled, or the capstan stall; pre-tension: the
backbone moved alone, or the whole loop; ``forms_for``) is fitted in each and
the form with the lower training error kept.

The output side is affine in the linear parameters (aero load gain and offset,
drift), even through the sensor lag, which is a linear filter::

    w_meas = lag(w_core) - g lag(q w_core) - c lag(q) + d D(t - t0; tau)

so those are solved by least squares inside every evaluation (variable
projection) and the searches run only over the nonlinear parameters: a grid
for a good start, then bounded Brent (one parameter) or Nelder-Mead (more),
in a box normalised to [0, 1] per parameter.

When the nominal model carries a model-error model (``model.model_error``,
learned from the bench residual), its correction is added to the core's
output for every candidate, so effects are fitted to what changed since the
bench. The initial hysteretic state follows each candidate's input: the
nominal's estimate, moved by the change of the algebraic state that the
candidate's input effects make at the first samples (a pre-tension offset
moves z0 with it), clamped to the reachable band.

A candidate that drives the log beyond the model's monotone range is not
one, judged against the nominal: when the nominal itself leaves that range
on the log (a wing the model does not carry over to), a candidate may leave
it as often as the nominal does, and output-side candidates reuse the
nominal's own run, which is kept for the whole search (uncapped, as ``predict``
runs it, if it must be).

Each thread keeps its last few core runs. The runs of the starting grids are
also kept for all threads, up to ``GRID_CACHE_BYTES``: a later fit of the same
effect beside an output-side one (a sensor lag, an aero load) or without it
(the backward check) walks the same grid through the same cores. And a search
that starts from the same effects over the same boxes as an earlier one takes
its end (the backward check's fit without an output-side effect can retrace
the first round's). Results are the same; on a slow capstan-sheath pair the
core runs went from 5 087 to 4 146. On worker processes (``pool``) each
worker keeps its own runs; the search ends go to every worker with the jobs.
"""

from __future__ import annotations

import itertools
import logging
import math
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from warpbridge.model.boucwen import BoucWenParams, forward, rest_warp
from warpbridge.model.diagnosis.blocks import Split, make_split
from warpbridge.model.diagnosis.kernels import fill_along_travel, forward_run_capped, travel_grid
from warpbridge.model.diagnosis.records import Record
from warpbridge.model.effect_registry import CORE_FIELDS, EFFECT_FIELDS, LOAD_EFFECT, Box, forms_for
from warpbridge.model.effects import (
    PULLED,
    RELEASED,
    Effects,
    added_on_warp,
    apply_input_effects,
    core_params,
    drift_shape,
    dynamic_pressure_kpa,
    form_fields,
    form_parameters,
    sensor_filtered,
)
from warpbridge.model.initial_state import (
    OPENING_MAX,
    algebraic_z0,
    reachable_band,
    released_start_wins,
    squared_error,
)
from warpbridge.model.model_error import ErrorModel
from warpbridge.model.signals import central_range, noise_floor, reversal_indices

log = logging.getLogger(__name__)

LINEAR_FIELDS = ("aero_gain_per_kpa", "aero_deg_per_kpa", "drift_deg_s")
GRID_CACHE_BYTES = 128 * 2 ** 20  # the starting grids' core runs kept for every thread (``Problem.core``)
BOUND_TOL = 0.03  # of a box's width: a fitted coordinate this close to an edge sits at it (``Fit.bound_hits``)
BRENT_MAX_ITER = 30  # a one-parameter search's iterations (``Problem._brent``)
MAX_SATURATED = 0.01  # a candidate driving more of the log than this beyond the model's range is rejected
TRAVEL_STEP = 1.0 / 200  # of the input span: the core runs on a sample per this much travel, and every reversal


# ---- forms ---------------------------------------------------------------------------------------

def form_supported(f: Fit) -> bool:
    """False for a capstan stall whose slack travel sits at the lower edge of its search. Such a stall hardly
    grows with the tension across the log: a dead band of fixed width, which is backlash's form, not friction's,
    and the held-out test cannot tell the two apart."""
    return not any((h.parameter, h.bound) == ("capstan_zero_mm", "lower") for h in f.bound_hits())


def effect_of(field_name: str) -> str:
    """The effect whose parameters hold ``field_name``."""
    return next(n for n, (fs, _, _) in EFFECT_FIELDS.items() if field_name in fs)


def _reachable(p: BoucWenParams, x: np.ndarray) -> bool:
    """False when the input clearly leaves the range where u grows with w (the quadratic's turning point,
    with z at its saturation): the forward map would saturate on most samples."""
    if p.a1 == 0.0:
        return True
    w_turn = -p.a2 / (2.0 * p.a1)
    try:
        z_hi, z_lo = p.z_saturation(1.0 if w_turn > 0 else -1.0)
    except (ValueError, ZeroDivisionError, OverflowError):
        return True
    zs = [v for v in (z_hi, z_lo) if np.isfinite(v)]
    if not zs:
        return True
    u_turn = p.a1 * w_turn ** 2 + p.a2 * w_turn + p.a3
    margin = abs(p.az) * max(abs(v) for v in zs)
    if p.a1 < 0:  # u has a maximum
        return float(np.max(x)) <= u_turn + margin
    return float(np.min(x)) >= u_turn - margin


def linear_fields(name: str) -> tuple[str, ...]:
    """The effect's parameters that enter the output affinely (solved by least squares)."""
    return tuple(f for f in EFFECT_FIELDS[name][0] if f in LINEAR_FIELDS)


# ---- the problem -------------------------------------------------------------------------------

@dataclass(frozen=True)
class BoundHit(Record):
    """A nonlinear parameter fitted at an edge of its search box: the effect, the parameter, which edge
    ("lower" or "upper"), the edge's value and the fitted one; ``meaning`` is what the report reads into it
    (``readings.bound_meaning``), once read."""

    OPTIONAL = ("meaning",)

    effect: str
    parameter: str
    bound: str
    limit: float
    value: float | None
    meaning: str | None = None


@dataclass
class Fit:
    """Fitted augmentation: the full effects (nominal's plus fitted), its prediction and errors."""

    names: tuple[str, ...]
    effects: Effects
    w_pred: np.ndarray = field(repr=False)
    train_mse: float
    score_mse: float
    n_params: int
    evaluations: int = 0
    coords: dict[str, float] = field(default_factory=dict)  # search coordinate in [0, 1] per nonlinear field
    boxes: list[Box] = field(default_factory=list, repr=False)
    params_of: dict[str, int] = field(default_factory=dict)  # parameters each named effect's fitted form has
    widened: tuple[str, ...] = ()  # fields searched again past their first limit (``Problem._search_wider``)

    def bound_hits(self, tol: float = BOUND_TOL) -> list[BoundHit]:
        """Nonlinear parameters fitted at an edge of their search box (within ``tol`` of its width). An edge
        that means "no effect" (no limit, no stall, no second sensor stage) is a value, not a bound."""
        out = []
        for b in self.boxes:
            s = self.coords.get(b.field)
            if s is None:
                continue
            for edge, hit, limit in (("lower", s <= tol and not b.neutral_at_lo, b.lo),
                                     ("upper", s >= 1.0 - tol and not b.neutral_at_hi, b.hi)):
                if hit:
                    out.append(BoundHit(effect_of(b.field), b.field, edge, limit,
                                        _jsonable(getattr(self.effects, b.field))))
        return out


    def values(self, names=None) -> dict[str, dict[str, float]]:
        """{effect: {parameter: value}} of the named (default: fitted) effects, in the form fitted."""
        return {n: {f: _jsonable(getattr(self.effects, f)) for f in form_fields(n, self.effects)}
                for n in names or self.names}


def _jsonable(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


@dataclass(frozen=True)
class FitJob:
    """One of ``Problem.fit``'s independent pieces: one combination of the moving effects' forms, called
    without arguments; ``args`` alone (``Problem.fit_form_job``) fit it on a copy of the problem."""

    problem: Problem = field(repr=False, compare=False)
    args: tuple

    def __call__(self) -> Fit:
        return self.problem.fit_form_job(self.args)

    @property
    def expected_runs(self) -> int:
        """About how many core runs the job costs, from its search alone: a Nelder-Mead of ``max_evals`` for
        two free parameters or more, a Brent of up to ``BRENT_MAX_ITER`` for one, next to nothing for none
        (its linear parameters are solved). Only the order jobs are handed out in follows it (the longest
        first, so that no worker is left with a long one while the others idle); the fits do not depend on it."""
        forms, max_evals = self.args[2], self.args[5]
        free = sum(not b.fixed for form in forms for b in form)
        return max_evals if free >= 2 else (BRENT_MAX_ITER if free == 1 else 1)


class Problem:
    """A log and a nominal model to be augmented; see the module docstring."""

    def __init__(self, t, u, w, airspeed, params: BoucWenParams, effects: Effects, z0: float = 0.0,
                 split: Split | None = None, error_model: ErrorModel | None = None,
                 travel_step: float = TRAVEL_STEP, slack_side: float = PULLED) -> None:
        self.t = np.ascontiguousarray(t, dtype=np.float64)
        self.u = np.ascontiguousarray(u, dtype=np.float64)
        self.w = np.ascontiguousarray(w, dtype=np.float64)
        self.airspeed = None if airspeed is None else np.ascontiguousarray(airspeed, dtype=np.float64)
        self.q = None if self.airspeed is None else dynamic_pressure_kpa(self.airspeed)
        self.params = params
        self.base = effects
        self.z0 = float(z0)
        self.error_model = error_model if error_model is not None and error_model.theta.size else None
        self.travel = central_range(self.u)
        self.travel_step = travel_step * max(self.travel[1] - self.travel[0], 1e-9)  # 0: every sample
        self.split = split or make_split(self.t, self.u)
        self.tau = self.t - self.t[0]
        self._local = threading.local()  # per thread: the core cache and its evaluation count (``fit``)
        self._count_lock = threading.Lock()
        self._evaluations = 0
        self._grid_cache: OrderedDict[tuple, np.ndarray] = OrderedDict()  # every thread's grid runs
        self._kept_lock = threading.Lock()  # guards what is kept for every thread: grid runs, search ends
        self._grid_slots = GRID_CACHE_BYTES // (8 * self.t.size)
        self._searches: dict[tuple, np.ndarray] = {}  # each search's end by where it started (``_search``)
        self.has_airspeed = self.q is not None and float(np.max(self.q)) > 0.0
        self._opening = min(self.t.size, OPENING_MAX)
        self._noise = noise_floor(self.w)
        x = apply_input_effects(effects, self.t, self.u, slack_side)  # the nominal's, as z0 was estimated
        p = self._core_params(effects)
        self._z0_alg = algebraic_z0(p, x, self.w) * p.az  # in mm of tendon: comparable across friction scales
        # the candidates run on the compressed path, and so does the nominal they are compared with. A candidate
        # that drives the log beyond the model's monotone range is rejected, measured against the nominal: when
        # the nominal itself leaves that range on this log, candidates may go as far as it does
        self._extra_flags = 0
        self._check_reach = _reachable(p, x)
        self._pinned: tuple[tuple, np.ndarray] | None = None
        w_nom = self.core(effects)
        if not np.all(np.isfinite(w_nom)):
            self._core.clear()
            self._extra_flags = max(self._grid_run(p, x, capped=False)[0], 0)
            w_nom = self.core(effects)
            if not np.all(np.isfinite(w_nom)):  # run uncapped, exactly as ``predict`` would
                w_nom = self._corrected(x, forward(p, x, z0=self.z0)[0], effects)
        self._pinned = (self._key(effects), w_nom)  # never evicted: every output-side candidate reuses it

    @property
    def _core(self) -> OrderedDict[tuple, np.ndarray]:
        """The last few core runs of this thread (candidate fits may run side by side, ``Explorer.round``)."""
        cache = getattr(self._local, "core", None)
        if cache is None:
            cache = self._local.core = OrderedDict()
        return cache

    @property
    def evaluations(self) -> int:
        """Core runs so far, all threads together."""
        return self._evaluations

    def _thread_evaluations(self) -> int:
        return getattr(self._local, "evaluations", 0)

    def _counted(self) -> None:
        self._local.evaluations = self._thread_evaluations() + 1
        with self._count_lock:
            self._evaluations += 1

    @staticmethod
    def _key(eff: Effects) -> tuple:
        return tuple(getattr(eff, f) for f in CORE_FIELDS) + eff.added_core_key

    def _core_params(self, eff: Effects) -> BoucWenParams:
        return core_params(self.params, eff)

    def _corrected(self, x: np.ndarray, w: np.ndarray, eff: Effects) -> np.ndarray:
        return w if self.error_model is None else self.error_model.corrected(self.t, x, w, eff.band_scale)

    def z0_for(self, p: BoucWenParams, x: np.ndarray) -> float:
        """Initial state for a candidate's core: the nominal's, moved as the algebraic state moves."""
        shift = algebraic_z0(p, x, self.w) * p.az - self._z0_alg
        z = (self.z0 * self.params.az + shift) / p.az
        lo, hi = reachable_band(p, float(self.w[0]))
        return float(np.clip(z, lo, hi))

    # -- prediction --
    def core(self, eff: Effects) -> np.ndarray:
        """Bouc-Wen forward warp for the input-side effects and friction of ``eff`` (cached)."""
        key = self._key(eff)
        if self._pinned is not None and key == self._pinned[0]:  # (None only while the nominal is computed)
            return self._pinned[1]
        hit = self._core.get(key)
        if hit is not None:
            self._core.move_to_end(key)
            return hit
        with self._kept_lock:
            hit = self._grid_cache.get(key)
            if hit is not None:
                self._grid_cache.move_to_end(key)
        if hit is not None:
            self._keep(key, hit)
            return hit
        p = self._core_params(eff)
        x = self.input_path(eff, p)
        self._counted()
        w = np.empty_like(x)
        if (self._check_reach and not _reachable(p, x)) or (run := self._grid_run(p, x, capped=True))[0] < 0:
            w[:] = np.nan  # beyond the model's monotone range: not a candidate
        else:
            fill_along_travel(x, run[1], run[2], w)
        w = self._corrected(x, w, eff)
        self._keep(key, w)
        if self._grid_slots and getattr(self._local, "on_grid", False):
            with self._kept_lock:
                self._grid_cache[key] = w
                if len(self._grid_cache) > self._grid_slots:
                    self._grid_cache.popitem(last=False)
        return w

    def _keep(self, key: tuple, w: np.ndarray) -> None:
        """Keep ``w`` among this thread's last few core runs."""
        self._core[key] = w
        if len(self._core) > 8:
            self._core.popitem(last=False)

    def input_path(self, eff: Effects, p: BoucWenParams) -> np.ndarray:
        """The tendon travel into the core for ``eff``; a play starts on its releasing edge when that core run,
        from its own ``z0_for``, explains the log's opening stretch materially better than the pull's
        (``initial_state.released_start_wins``), as ``initial_state.estimate_plant_start`` chooses for a whole
        model."""
        x = apply_input_effects(eff, self.t, self.u)
        if not eff.has_slack:
            return x
        x_rel = apply_input_effects(eff, self.t, self.u, RELEASED)
        cost = [self._opening_cost(p, xs) for xs in (x, x_rel)]
        return x_rel if released_start_wins(cost[0], cost[1], self._opening, self._noise) else x

    def _opening_cost(self, p: BoucWenParams, x: np.ndarray) -> float:
        """Squared error of the core from ``z0_for`` over the log's opening stretch; inf when the start drives
        more of the opening beyond the model's monotone range than a candidate may (``_run_capped``, as the
        whole-log run): such a start is not a candidate, and each such sample costs a slow search for the
        range's edge (a whole opening of them took seconds per start on a heavy-friction rig)."""
        m = self._opening
        flagged, w = self._run_capped(p, np.ascontiguousarray(x[:m]), self.z0_for(p, x), capped=True)
        return math.inf if flagged < 0 else squared_error(w, self.w[:m])

    def _grid_run(self, p: BoucWenParams, x: np.ndarray, capped: bool) -> tuple[int, np.ndarray, np.ndarray]:
        """(samples of the compressed path beyond the model's monotone range, or -1 once past the candidates'
        allowance when ``capped``; the path's indices; the core warp on them)."""
        idx = travel_grid(x, self.travel_step) if self.travel_step > 0 else np.arange(x.size)
        flagged, wk = self._run_capped(p, np.ascontiguousarray(x[idx]), self.z0_for(p, x), capped)
        return flagged, idx, wk

    def _run_capped(self, p: BoucWenParams, x: np.ndarray, z0: float, capped: bool) -> tuple[int, np.ndarray]:
        """(samples beyond the model's monotone range, or -1 once past a candidate's allowance when ``capped``:
        ``MAX_SATURATED`` of them, at least 10, plus the nominal's own excess; the core warp) along ``x`` from
        rest at state ``z0``."""
        w, z = np.empty_like(x), np.empty_like(x)
        cap = max(10, int(MAX_SATURATED * x.size)) + self._extra_flags if capped else x.size
        return forward_run_capped(p.to_array(), x, rest_warp(p, float(x[0]), z0), z0, w, z, cap), w

    def _lag(self, x: np.ndarray, eff: Effects) -> np.ndarray:
        return sensor_filtered(eff, self.t, x)

    def affine(self, eff: Effects, free: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
        """(base, basis): w_meas = base + basis @ theta for the free linear fields (others fixed)."""
        wc = added_on_warp(eff, self.t, self.core(eff))
        base = self._lag(wc, eff)
        cols = []
        aero = self.q is not None
        g, c, d = eff.aero_gain_per_kpa, eff.aero_deg_per_kpa, eff.drift_deg_s
        if aero and ("aero_gain_per_kpa" in free or g != 0.0):
            lqw = self._lag(self.q * wc, eff)
            if "aero_gain_per_kpa" in free:
                cols.append(-lqw)
            else:
                base = base - g * lqw
        if aero and ("aero_deg_per_kpa" in free or c != 0.0):
            lq = self._lag(self.q, eff)
            if "aero_deg_per_kpa" in free:
                cols.append(-lq)
            else:
                base = base - c * lq
        if "drift_deg_s" in free:
            cols.append(drift_shape(self.tau, eff.drift_tau_s))
        elif d != 0.0:
            base = base + d * drift_shape(self.tau, eff.drift_tau_s)
        basis = np.column_stack(cols) if cols else np.zeros((self.t.size, 0))
        return base, basis

    def predict(self, eff: Effects) -> np.ndarray:
        """Measured warp the augmented model predicts (identical to ``Plant.simulate``)."""
        base, _ = self.affine(eff, ())
        return base

    def solve_linear(self, eff: Effects, free: tuple[str, ...],
                     mask: np.ndarray | None = None) -> tuple[Effects, np.ndarray]:
        """Least-squares values of the free linear fields on the training samples (or on ``mask``)."""
        # in the column order of ``affine``
        free = tuple(f for f in LINEAR_FIELDS if f in free and (f == "drift_deg_s" or self.q is not None))
        base, basis = self.affine(eff, free)
        if not free or not np.all(np.isfinite(base)):
            return eff, base
        m = self.split.train if mask is None else mask
        y = self.w[m] - base[m]
        A = basis[m]
        scale = np.sqrt(np.sum(A ** 2, axis=0))
        scale[scale == 0] = 1.0
        theta, *_ = np.linalg.lstsq(A / scale, y, rcond=None)
        theta = theta / scale
        if not np.all(np.isfinite(theta)):
            theta = np.zeros(len(free))
        eff = replace(eff, **{f: float(v) for f, v in zip(free, theta, strict=True)})
        return eff, base + basis @ theta

    def mse(self, w_pred: np.ndarray, mask: np.ndarray) -> float:
        e = self.w[mask] - w_pred[mask]
        v = float(np.mean(e * e)) if e.size else math.nan
        return v if math.isfinite(v) else math.inf

    # -- fitting --
    def fit(self, names, start: Effects | None = None, free_nonlinear=None, max_evals: int = 200,
            grid_for: str | None = None, run: Callable[[list], list] | None = None) -> Fit:
        """Fit the effects ``names`` (their parameters on top of ``start``, default the nominal's).

        ``free_nonlinear`` limits which effects' nonlinear parameters move (default: all of ``names``);
        linear ones of every named effect are always solved. ``grid_for`` names the effect whose
        parameters get a starting grid (default: the last of ``names``). ``run`` maps a list of
        argument-free jobs to their results (default: one after the other; it may run them side by side)."""
        jobs = self.fit_jobs(names, start, free_nonlinear, max_evals, grid_for)
        return self.best_of(run(jobs) if run is not None else [job() for job in jobs])

    def fit_jobs(self, names, start: Effects | None = None, free_nonlinear=None, max_evals: int = 200,
                 grid_for: str | None = None) -> list[FitJob]:
        """``fit``'s independent pieces, one per combination of the moving effects' forms (``best_of`` picks)."""
        names = tuple(names)
        start = start or self.base
        movers = tuple(names if free_nonlinear is None else free_nonlinear)
        lin = tuple(f for n in names for f in linear_fields(n))
        if LOAD_EFFECT in names and self.q is None:
            raise ValueError(f"{LOAD_EFFECT} needs airspeed in the log")
        return [FitJob(self, (names, movers, forms, start, lin, max_evals, grid_for or names[-1]))
                for forms in itertools.product(*(forms_for(n, self.t, self.u) for n in movers))]

    @staticmethod
    def best_of(fits: list[Fit]) -> Fit:
        """The form that fits the training blocks best (a supported one when there is); its ``evaluations``
        are those of every form tried."""
        best = min([f for f in fits if form_supported(f)] or fits, key=lambda f: f.train_mse)
        best.evaluations = sum(f.evaluations for f in fits)
        return best

    def fit_form_job(self, args: tuple) -> Fit:
        """The fit of a ``FitJob``'s arguments (``_fit_form``'s), its core runs counted in ``evaluations``."""
        return self._counted_fit_form(*args)

    def search_ends(self, start: int = 0) -> list[tuple[tuple, np.ndarray]]:
        """The kept search ends (``_search``), from the ``start``-th kept on."""
        with self._kept_lock:
            return list(itertools.islice(self._searches.items(), start, None))

    def keep_search_ends(self, ends: list[tuple[tuple, np.ndarray]]) -> int:
        """Keep search ends found elsewhere (a worker's copy of this problem): the same search ends there.
        Returns how many are kept now."""
        with self._kept_lock:
            for key, s in ends:
                self._searches.setdefault(key, s)
            return len(self._searches)

    def count_runs(self, n: int) -> None:
        """Add ``n`` core runs made elsewhere (a worker process's copy of this problem) to ``evaluations``."""
        with self._count_lock:
            self._evaluations += n

    def _counted_fit_form(self, *args) -> Fit:
        evals0 = self._thread_evaluations()
        f = self._fit_form(*args)
        f.evaluations = self._thread_evaluations() - evals0
        return f

    def _fit_form(self, names, movers, forms, start: Effects, lin, max_evals: int, grid_for: str) -> Fit:
        """``fit`` with one form per moving effect; the fields of a mover's other forms go back to the nominal's."""
        boxes = [b for form in forms for b in form if not b.fixed]
        flags = {b.field: b.lo for form in forms for b in form if b.fixed}
        own = {b.field for b in boxes} | set(flags)
        reset = {f: getattr(self.base, f) for n in movers for f in EFFECT_FIELDS[n][0]
                 if f not in own and f not in lin}
        start = start.with_values(**reset, **flags)
        params_of = {n: form_parameters(n, start) for n in names}  # held effects: the form they carry
        for n, form in zip(movers, forms, strict=True):
            params_of[n] = sum(not b.fixed for b in form) + len(linear_fields(n))
        tm = self.split.train

        def over(boxes: list[Box]):
            def build(s: np.ndarray) -> Effects:
                return start.with_values(**{b.field: b.value(x) for b, x in zip(boxes, s, strict=True)})

            def cost(s: np.ndarray) -> float:
                eff, wp = self.solve_linear(build(s), lin)
                return self.mse(wp, tm)
            return build, cost

        build, cost = over(boxes)
        s0 = np.array([b.coord(getattr(start, b.field)) for b in boxes])
        if boxes:
            s0 = self._grid_start(boxes, s0, cost, grid_for, movers)
            s0 = self._search(boxes, s0, build, cost, lin, max_evals)
            boxes, s0, build = self._search_wider(boxes, s0, build, cost, over, lin, max_evals)
        eff, wp = self.solve_linear(build(s0), lin)
        first = {b.field: b for form in forms for b in form}
        return Fit(names, eff, wp, self.mse(wp, tm), self.mse(wp, self.split.score), sum(params_of.values()),
                   0, {b.field: float(x) for b, x in zip(boxes, s0, strict=True)}, boxes, params_of,
                   tuple(b.field for b in boxes if b != first[b.field]))

    def refit_whole(self, fit: Fit, max_evals: int) -> Fit:
        """``fit``'s effects fitted again on every analysed sample (the training and the scored blocks), from
        where the training fit ended, in its forms and boxes: once the held-out blocks have chosen the effects,
        their sizes are estimated on the whole log, as a model chosen by cross-validation is refitted on all
        of its data. The refit's ``score_mse`` is not held out; ``fit`` is returned when the refit is no better
        on the whole log (or not finite)."""
        if not fit.names:
            return fit
        whole = self.split.train | self.split.score
        lin = tuple(f for n in fit.names for f in linear_fields(n))
        boxes = list(fit.boxes)

        def build(s: np.ndarray) -> Effects:
            return fit.effects.with_values(**{b.field: b.value(x) for b, x in zip(boxes, s, strict=True)})

        def cost(s: np.ndarray) -> float:
            return self.mse(self.solve_linear(build(s), lin, whole)[1], whole)

        s0 = np.array([fit.coords.get(b.field, b.coord(getattr(fit.effects, b.field))) for b in boxes])
        # not through ``_search``: its kept ends are the training fits', from the same starts. Brent and
        # Nelder-Mead return the start unless they find better
        s1 = s0 if not boxes else self._brent(cost, s0) if len(boxes) == 1 else self._nelder_mead(cost, s0,
                                                                                                 max_evals)
        eff, wp = self.solve_linear(build(s1), lin, whole)
        if not math.isfinite(self.mse(wp, whole)):
            return fit
        return replace(fit, effects=eff, w_pred=wp, train_mse=self.mse(wp, self.split.train),
                       score_mse=self.mse(wp, self.split.score),
                       coords={b.field: float(x) for b, x in zip(boxes, s1, strict=True)})

    def _search_wider(self, boxes: list[Box], s0: np.ndarray, build, cost, over, lin, max_evals: int):
        """When the search ends at an edge that only limits the effect's size (a backlash as wide as 0.4 of the
        travel, a servo slewing at 2 % of the input's fastest rate), search again with that edge moved to its
        wider limit: from the best of five points between the old edge and the new one, then as ``_search``.
        The wider search is kept when it fits the training blocks better; its boxes are then the fit's, so
        ``Fit.bound_hits`` reads the wider limits. Returns (boxes, end, build)."""
        wide = list(boxes)
        for i, b in enumerate(boxes):
            edge = "lower" if s0[i] <= BOUND_TOL else "upper" if s0[i] >= 1.0 - BOUND_TOL else None
            w = b.widened(edge) if edge else None
            if w is not None:
                wide[i] = w
        if wide == boxes:
            return boxes, s0, build
        build2, cost2 = over(wide)
        s1 = np.array([w.coord(b.value(x)) for b, w, x in zip(boxes, wide, s0, strict=True)])
        best, best_c = s1, cost2(s1)
        for i, (b, w) in enumerate(zip(boxes, wide, strict=True)):
            if w is b:
                continue
            grown_below = w.lo != b.lo  # the new part of the range: below the old edge, or above it
            points = np.linspace(0.0, s1[i], 6)[:-1] if grown_below else np.linspace(s1[i], 1.0, 6)[1:]
            for p in points:
                s = best.copy()
                s[i] = p
                c = cost2(s)
                if c < best_c:
                    best, best_c = s, c
        s1 = self._search(wide, best, build2, cost2, lin, max_evals)
        if cost2(s1) < cost(s0):
            log.debug("searched again with wider limits (%s): kept", ", ".join(
                w.field for w, b in zip(wide, boxes, strict=True) if w is not b))
            return wide, s1, build2
        return boxes, s0, build

    def _search(self, boxes: list[Box], s0: np.ndarray, build, cost, lin, max_evals: int) -> np.ndarray:
        """Bounded Brent (one box) or Nelder-Mead (more) from ``s0``. A search that starts from the same effects
        over the same boxes has the same cost everywhere and takes the same path: its end is kept (the backward
        check's fit without an output-side effect retraces the first round's fit of the one left)."""
        key = (repr(build(s0)), repr(boxes), lin, max_evals)
        with self._kept_lock:
            hit = self._searches.get(key)
        if hit is not None:
            return hit.copy()
        s = self._brent(cost, s0) if len(boxes) == 1 else self._nelder_mead(cost, s0, max_evals)
        with self._kept_lock:
            self._searches[key] = s.copy()
        return s

    def _grid_start(self, boxes: list[Box], s0: np.ndarray, cost, grid_name: str, movers) -> np.ndarray:
        """The best point of a starting grid over the effect ``grid_name``'s parameters (13 points for one,
        7 x 5 for two; a box ``grid_like`` another follows it instead of adding a dimension)."""
        names = EFFECT_FIELDS[grid_name][0] if grid_name in movers else ()
        idx = [i for i, b in enumerate(boxes) if b.field in names and b.grid_like is None]
        if not idx:
            return s0
        pos = {b.field: i for i, b in enumerate(boxes)}
        tied = [(i, pos[b.grid_like]) for i, b in enumerate(boxes) if b.field in names and b.grid_like is not None]
        if len(idx) == 1:
            pts = [np.array([g]) for g in np.linspace(0.0, 1.0, 13)]
        else:
            g = np.linspace(0.0, 1.0, 7)
            pts = [np.array([a, b]) for a in g for b in g[1:-1]]
        self._local.on_grid = True  # these cores are kept for every thread (``core``)
        try:
            best, best_c = s0, cost(s0)
            for p in pts:
                s = s0.copy()
                s[idx] = p
                for i, j in tied:
                    s[i] = s[j]
                c = cost(s)
                if c < best_c:
                    best, best_c = s, c
        finally:
            self._local.on_grid = False
        return best

    @staticmethod
    def _brent(cost, s0: np.ndarray) -> np.ndarray:
        x0 = float(s0[0])
        lo, hi = max(0.0, x0 - 1.0 / 12), min(1.0, x0 + 1.0 / 12)
        c0 = cost(s0)
        r = minimize_scalar(lambda x: cost(np.array([x])), bounds=(lo, hi), method="bounded",
                            options={"xatol": 5e-4, "maxiter": BRENT_MAX_ITER})
        return np.array([r.x]) if r.fun <= c0 else s0

    @staticmethod
    def _nelder_mead(cost, s0: np.ndarray, max_evals: int) -> np.ndarray:
        d = s0.size
        simplex = [s0]
        for i in range(d):
            s = s0.copy()
            s[i] = s[i] + 0.06 if s[i] + 0.06 <= 1.0 else s[i] - 0.06
            simplex.append(s)
        c0 = cost(s0)
        r = minimize(cost, s0, method="Nelder-Mead", bounds=[(0.0, 1.0)] * d,
                     options={"initial_simplex": np.array(simplex), "maxfev": max_evals, "xatol": 2e-4,
                              "fatol": 1e-12 * max(c0, 1e-12), "adaptive": d > 2})
        return np.clip(r.x, 0.0, 1.0) if r.fun <= c0 else s0


def input_reversal_count(u: np.ndarray) -> int:
    """Number of direction changes of the tendon input."""
    return int(reversal_indices(u).size)
