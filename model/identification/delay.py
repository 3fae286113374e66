"""Step 6 of identification, ``delay``: with ``max_delay_s``, a scan of transport delays in front of the
model (a short refinement each, from the best model so far), its best placed between grid points by a
parabola (``parabola_vertex``, which the servo's scan uses too); ``identify`` refines the model at the best
delay and keeps it only when it lowers the training cost by ``DELAY_GAIN`` against the model without it."""

from __future__ import annotations

import logging
import math

import numpy as np

from warpbridge.model.effects import delayed
from warpbridge.model.identification.data import LogData
from warpbridge.model.identification.path import FIT_TOL_Z, SEARCH_POINTS, SEARCH_REVERSALS, FitPath, Objective, refine

log = logging.getLogger(__name__)

DELAY_GRID_S = (0.005, 0.01, 0.02, 0.03, 0.045, 0.065, 0.09, 0.12, 0.16)  # transport delays the scan tries (s)
DELAY_SCAN_ITER = 6  # refinement steps at each delay of the scan
DELAY_GAIN = 0.02  # a delay is kept only when it lowers the training cost by this share of the no-delay cost


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
