"""Jitter removed from a signal: between its real turning points, the least-squares monotone fit.

Used by identification's start design (``model.identification.design``). It sits apart from ``model.signals``
because it needs SciPy, which the flight path (``warpbridge run``) never loads.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import isotonic_regression

from warpbridge.model.signals import turning_indices


def monotone_between_turns(x: np.ndarray, threshold: float, fit: np.ndarray | None = None) -> np.ndarray:
    """x with its jitter removed: between consecutive turning points of x (``turning_indices``) the
    least-squares monotone fit (isotonic regression, rising or falling as the run does) of ``fit`` (default
    x), so that the only reversals left are real ones and a plateau sits at its mean."""
    x = np.asarray(x, dtype=np.float64)
    y = x if fit is None else np.asarray(fit, dtype=np.float64)
    out = y.copy()
    turns = turning_indices(x, threshold)
    edges = np.concatenate([[0], turns, [x.size]]).astype(np.int64)
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        if b - a < 2:
            continue
        rising = x[min(b, x.size - 1)] >= x[a]
        out[a:b] = isotonic_regression(y[a:b], increasing=bool(rising)).x
    return out
