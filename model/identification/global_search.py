"""The escalation of ``identify``: a bounded global search when the design's refined starts disagree.

On a log with a very wide two-sided loop the design's few refined starts can all
settle in different local minima, none of them in the basin of the best fit.
Then a differential evolution (``scipy.optimize.differential_evolution``) runs
over the same forward output error the refinement uses (``path.Objective``
on the search's path), with a fixed seed derived from the design's, a modest
budget, and the design's best starts and the refined results placed in its first
population (the rest of it a Latin hypercube over the box). Its best distinct
members are then refined like the design's starts; the caller keeps whichever
result runs free over the training part with the lowest error.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import differential_evolution
from scipy.stats import qmc

from warpbridge.model.identification.path import FOLD_PENALTY, Objective

GLOBAL_SEED = 7919  # added to the design's scramble: the search's own fixed seed
POPSIZE = 60  # members of the population (at least the seeded starts plus a Latin hypercube)
MAXITER = 60  # generations at most
TOL = 1e-3  # it stops once the population's costs spread less than this share of their mean
KEEP = 4  # distinct best members handed on to the refinement
DISTINCT = 0.05  # members closer than this share of the box (max over coordinates) are one


@dataclass
class GlobalResult:
    """The search's best distinct members (best first), their costs, generations run and evaluations."""

    thetas: np.ndarray
    costs: np.ndarray
    generations: int
    evaluations: int


def first_population(seeded: np.ndarray, lo: np.ndarray, hi: np.ndarray, size: int, seed: int) -> np.ndarray:
    """``size`` members: the ``seeded`` vectors (clipped into the box, duplicates dropped), then a scrambled
    Latin hypercube over the box with the fixed ``seed``."""
    rows: list[np.ndarray] = []
    span = hi - lo
    for th in np.atleast_2d(seeded):
        th = np.clip(th, lo, hi)
        if np.all(np.isfinite(th)) and all(np.max(np.abs(th - r) / span) > 1e-9 for r in rows):
            rows.append(th)
        if len(rows) >= size // 2:
            break
    n_fill = max(size - len(rows), 5)
    fill = lo + span * qmc.LatinHypercube(d=lo.size, seed=np.random.default_rng(seed)).random(n_fill)
    return np.vstack([*rows, fill]) if rows else fill


def distinct_members(pop: np.ndarray, cost: np.ndarray, k: int, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Indices of the ``k`` best members by cost that are ``DISTINCT`` apart from each better one."""
    span = hi - lo
    out: list[int] = []
    for i in np.argsort(cost):
        if not np.isfinite(cost[i]) or cost[i] >= FOLD_PENALTY:
            continue
        if all(np.max(np.abs(pop[i] - pop[j]) / span) > DISTINCT for j in out):
            out.append(int(i))
        if len(out) >= k:
            break
    return np.array(out, dtype=np.int64)


def global_search(obj: Objective, lo: np.ndarray, hi: np.ndarray, seeded: np.ndarray, seed: int, *,
                  popsize: int = POPSIZE, maxiter: int = MAXITER, keep: int = KEEP,
                  callback: Callable[[int], None] | None = None) -> GlobalResult:
    """Differential evolution of ``obj`` over the box [lo, hi] from a first population holding ``seeded``
    (see the module); deterministic for a given ``seed``. The ``keep`` best distinct members are returned."""
    calls0 = obj.calls
    init = first_population(seeded, lo, hi, popsize, GLOBAL_SEED + seed)
    gens = [0]

    def cb(*_args, **_kw) -> None:
        gens[0] += 1
        if callback is not None:
            callback(gens[0])

    res = differential_evolution(
        lambda X: obj.many(np.atleast_2d(X.T)), list(zip(lo, hi, strict=True)), init=init, maxiter=maxiter,
        tol=TOL, atol=0.0, mutation=(0.5, 1.0), recombination=0.9, rng=np.random.default_rng(GLOBAL_SEED + seed),
        polish=False, updating="deferred", vectorized=True, callback=cb)
    pop = np.asarray(res.population)
    cost = np.asarray(res.population_energies)
    best = distinct_members(pop, cost, keep, lo, hi)
    if best.size == 0:
        best = np.array([int(np.argmin(cost))])
    return GlobalResult(pop[best], cost[best], gens[0], obj.calls - calls0)
