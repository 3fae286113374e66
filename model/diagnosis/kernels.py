"""Compiled (numba) kernel for the diagnosis: the Bouc-Wen forward map that gives up on hopeless inputs.

While a search explores effect parameters, a candidate can push the tendon
input far beyond the model's monotone range (a pre-tension gain of 2, say);
every such sample then needs a slow search for the turning point of u(w).
``forward_run_capped`` is ``model.kernels.forward_run`` that stops as soon as
more than ``max_flagged`` samples were saturated or failed, so such a candidate
costs a few samples instead of minutes.

``travel_grid`` and ``fill_along_travel`` run the map on a compressed path:
the model is rate independent, so its output between two kept samples (the
input monotone in between) follows the input's travel; keeping a sample per
small step of travel and every reversal costs a third of the samples of a
500 Hz log at an interpolation error far below a sensor's noise.
"""

from __future__ import annotations

import numpy as np

from warpbridge.model import kernels as K
from warpbridge.model._jit import njit


@njit(cache=True, fastmath=False, error_model="numpy")
def forward_run_capped(p, u, w0: float, z0: float, w_out, z_out, max_flagged: int) -> int:
    """Forward map over an array; returns the number of flagged samples, or -1 once it exceeds max_flagged."""
    flagged = 0
    wp = w0
    zp = z0
    zn = -1.0
    for k in range(u.shape[0]):
        w, z, zn, st = K.forward_step_zn(p, wp, zp, zn, u[k])
        if st != 0:
            flagged += 1
            if flagged > max_flagged:
                return -1
        wp = w
        zp = z
        w_out[k] = w
        z_out[k] = z
    return flagged


@njit(cache=True)
def travel_grid(x, step):
    """Indices of a rate-independent path compression of x: the ends, every direction change, and a sample
    each time the input has travelled ``step`` since the last one kept."""
    n = x.shape[0]
    keep = np.empty(n, dtype=np.int64)
    m = 0
    keep[m] = 0
    m += 1
    last = x[0]
    direction = 0.0
    for k in range(1, n - 1):
        dx = x[k + 1] - x[k]
        s = 1.0 if dx > 0 else (-1.0 if dx < 0 else 0.0)
        turn = s != 0.0 and direction != 0.0 and s != direction
        if s != 0.0:
            direction = s
        if turn or abs(x[k] - last) >= step:
            keep[m] = k
            m += 1
            last = x[k]
    if n > 1:
        keep[m] = n - 1
        m += 1
    return keep[:m]


@njit(cache=True)
def fill_along_travel(x, idx, w_kept, out):
    """Warp at every sample from the warp at the kept ones, linear in the travel between them (the input
    is monotone between kept samples, and a rate-independent map follows the input's path only)."""
    for j in range(idx.shape[0] - 1):
        a = idx[j]
        b = idx[j + 1]
        wa = w_kept[j]
        wb = w_kept[j + 1]
        dx = x[b] - x[a]
        out[a] = wa
        for k in range(a + 1, b):
            out[k] = wa + (wb - wa) * ((x[k] - x[a]) / dx) if dx != 0.0 else wa
    out[idx[idx.shape[0] - 1]] = w_kept[w_kept.shape[0] - 1]
