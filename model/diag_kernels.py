"""Compiled (numba) kernel for the diagnosis: the Bouc-Wen forward map that gives up on hopeless inputs.

While a search explores effect parameters, a candidate can push the tendon
input far beyond the model's monotone range (a pre-tension gain of 2, say);
every such sample then needs a slow search for the turning point of u(w).
``forward_run_capped`` is ``model.kernels.forward_run`` that stops as soon as
more than ``max_flagged`` samples were saturated or failed, so such a candidate
costs a few samples instead of minutes.
"""

from __future__ import annotations

from numba import njit

from warpbridge.model import kernels as K


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
