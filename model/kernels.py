"""Compiled (numba) kernels of the generalized Bouc-Wen tendon-sheath model.

The model maps warp ``w`` (deg) to tendon travel ``u`` (mm)::

    u = a1 w^2 + a2 w + a3 + az z
    dz/dw = A - |z|^n Psi,   Psi = b1 sgn(w' z) + b2 sgn(w w') + b3 sgn(w z)
                                  + b4 sgn(w') + b5 sgn(z) + b6 sgn(w)

It is rate independent, so ``z`` is integrated over ``w`` (never over time).
Integration uses classical RK4 with sub-steps no longer than ``H_MAX`` deg and
no longer than ``K_STIFF / |df/dz|``: after a reversal ``|z|^n Psi`` can reach
~60/deg, where a single explicit step would overshoot. The step sequence is a
greedy march clipped to the end point, so ``z(w_end)`` is continuous in
``w_end`` and the result does not depend on how the input was sampled.

Parameters travel as one float64 array ``p`` laid out as in ``P_*`` below.
Every kernel is NaN-safe: a non-finite input sample leaves the state unchanged,
and a diverging parameter set (possible while a global search explores) is
capped at ``Z_CAP`` and reported through the returned flag.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

# layout of the parameter vector
P_A1, P_A2, P_A3, P_AZ, P_A, P_N = 0, 1, 2, 3, 4, 5
P_B = 6  # b1..b6 at 6..11
N_PARAMS = 12

H_MAX = 0.25  # deg, longest RK4 sub-step in w
K_STIFF = 1.5  # longest sub-step in units of the local time constant 1/|df/dz| (RK4 is stable to 2.78)
TOL_Z = 1e-8  # local error allowed per sub-step, in units of z
NEWTON_ACCEPT = 1e-6  # relative Newton correction below which the forward solve stops
Z_CAP = 1.0e6  # |z| beyond this is a diverged parameter set
MAX_SUBSTEPS = 20_000  # per sample; beyond this a parameter set counts as diverged


@njit(cache=True, inline="always")
def _sgn(x: float) -> float:
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return 0.0


@njit(cache=True, inline="always")
def _psi(p, sdw: float, sw: float, sz: float) -> float:
    return (
        p[P_B] * sdw * sz
        + p[P_B + 1] * sw * sdw
        + p[P_B + 2] * sw * sz
        + p[P_B + 3] * sdw
        + p[P_B + 4] * sz
        + p[P_B + 5] * sw
    )


@njit(cache=True, inline="always")
def dz_dw(p, z: float, sdw: float, sw: float) -> float:
    """Slope dz/dw of the hysteretic state moving in direction ``sdw``."""
    az = abs(z)
    if az == 0.0:
        return p[P_A]
    return p[P_A] - az ** p[P_N] * _psi(p, sdw, sw, _sgn(z))


@njit(cache=True, fastmath=False, error_model="numpy")
def integrate_z(p, w0: float, z0: float, w1: float) -> float:
    """State z after moving monotonically from (w0, z0) to w1.

    Returns NaN only if the parameter set diverges (|z| > Z_CAP or too stiff to integrate)."""
    if not (w1 == w1) or w1 == w0:
        return z0
    sdw = 1.0 if w1 > w0 else -1.0
    n = p[P_N]
    A = p[P_A]
    w = w0
    z = z0
    for _ in range(MAX_SUBSTEPS):
        remaining = (w1 - w) * sdw
        if remaining <= 0.0:
            return z
        # Step size from the local error of RK4 on the linearised ODE,
        # err ~ (h J)^5 / 120 * |f| / J with J = |df/dz|, and h J <= K_STIFF for stability;
        # where z rests near saturation an L-stable step is taken instead.
        h = H_MAX
        last = False
        if h >= remaining:
            h = remaining
            last = True
        # never step across w = 0 (sgn(w) switches there)
        if w * sdw < 0.0 and h > -w * sdw:
            h = -w * sdw
            last = False
        sw = _sgn(w + 0.5 * h * sdw)
        az = abs(z)
        implicit = False
        if az > 0.0:
            zn = az ** n
            psi = _psi(p, sdw, sw, _sgn(z))
            k1 = A - zn * psi
            js = -n * zn / z * psi * sdw  # d(dz/ds)/dz along the path s = |w - w0|
            jac = abs(js)
            if jac > 0.0:
                f = abs(k1)
                h_rk = h
                if h_rk * jac > K_STIFF:
                    h_rk = K_STIFF / jac
                if f > 0.0 and (h_rk * jac) ** 5 * f > 120.0 * TOL_Z * jac:
                    h_rk = (120.0 * TOL_Z * jac / f) ** 0.2 / jac
                if h_rk < h and js < 0.0:
                    # z rests near its saturation: an L-stable linearly implicit Euler step
                    # (error ~ h^2 J |f| / 2) goes further than RK4 may
                    h_be = h if f == 0.0 else min(h, math.sqrt(2.0 * TOL_Z / (jac * f)))
                    if h_be > h_rk:
                        h = h_be
                        implicit = True
                if not implicit and h_rk < h:
                    h = h_rk
                    last = False
                elif implicit and h < remaining:
                    last = False
        else:
            k1 = A
        hs = h * sdw
        if implicit:
            z = z + hs * k1 / (1.0 - h * js)
        else:
            k2 = dz_dw(p, z + 0.5 * hs * k1, sdw, sw)
            k3 = dz_dw(p, z + 0.5 * hs * k2, sdw, sw)
            k4 = dz_dw(p, z + hs * k3, sdw, sw)
            z = z + hs * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0
        if not (abs(z) < Z_CAP):
            return np.nan
        if last:
            return z
        w = w + hs
        if (w1 - w) * sdw <= 0.0:
            return z
    return np.nan  # too stiff to integrate: treat as diverged


@njit(cache=True, inline="always")
def output_u(p, w: float, z: float) -> float:
    """Tendon travel u (mm) for warp w (deg) and state z."""
    return p[P_A1] * w * w + p[P_A2] * w + p[P_A3] + p[P_AZ] * z


@njit(cache=True, inline="always")
def slope_du_dw(p, w: float, z: float, sdw: float) -> float:
    """du/dw along the path moving in direction sdw."""
    return 2.0 * p[P_A1] * w + p[P_A2] + p[P_AZ] * dz_dw(p, z, sdw, _sgn(w) if w != 0.0 else sdw)


@njit(cache=True, fastmath=False, error_model="numpy")
def inverse_step(p, w_prev: float, z_prev: float, w: float):
    """One sample of the inverse map: returns (u, z) for the new warp w."""
    if not (w == w):
        return output_u(p, w_prev, z_prev), z_prev
    z = integrate_z(p, w_prev, z_prev, w)
    if not (z == z):
        return np.nan, z_prev
    return output_u(p, w, z), z


@njit(cache=True, fastmath=False, error_model="numpy")
def inverse_run(p, w, w0: float, z0: float, u_out, z_out) -> int:
    """Inverse map over an array; returns the number of diverged samples."""
    bad = 0
    wp = w0
    zp = z0
    for k in range(w.shape[0]):
        wk = w[k]
        if not (wk == wk):
            u_out[k] = output_u(p, wp, zp)
            z_out[k] = zp
            continue
        z = integrate_z(p, wp, zp, wk)
        if not (z == z):
            bad += 1
            z = zp
            wk = wp
        wp = wk
        zp = z
        u_out[k] = output_u(p, wp, zp)
        z_out[k] = zp
    return bad


@njit(cache=True, fastmath=False, error_model="numpy")
def forward_step(p, w0: float, z0: float, u: float):
    """One sample of the forward map: warp reached when the tendon moves to u.

    Solves u = a1 w^2 + a2 w + a3 + az z(w) exactly (safeguarded Newton with a
    bracket) for w on the monotone branch leaving (w0, z0). If u lies beyond
    the model's monotone range the warp stops where du/dw reaches zero.
    Returns (w, z, status): status 0 ok, 1 saturated, 2 diverged/failed."""
    if not (u == u):
        return w0, z0, 0
    u0 = output_u(p, w0, z0)
    du = u - u0
    if du == 0.0:
        return w0, z0, 0
    sdw = 1.0 if du > 0.0 else -1.0
    scale = abs(p[P_A2]) + abs(p[P_AZ] * p[P_A]) + 1e-12
    tol_u = 1e-13 * (abs(u) + scale)
    d0 = slope_du_dw(p, w0, z0, sdw)
    if d0 <= 1e-12 * scale:
        d0 = scale
    lo = w0  # G(lo)*sdw < 0
    hi = np.nan  # G(hi)*sdw > 0 once known
    lo_z = z0
    # second-order guess: u(w0 + d) ~ u0 + D d + D' d^2 / 2
    w = w0 + du / d0
    if z0 != 0.0:
        sw0 = _sgn(w0) if w0 != 0.0 else sdw
        psi0 = _psi(p, sdw, sw0, _sgn(z0))
        azn = abs(z0) ** p[P_N]
        f0 = p[P_A] - azn * psi0
        dfdz = -p[P_N] * azn / z0 * psi0
        d1 = 2.0 * p[P_A1] + p[P_AZ] * dfdz * f0
        corr = 1.0 - d1 * du / (2.0 * d0 * d0)
        if corr > 0.5 and corr < 1.5:
            w = w0 + du / d0 * corr
    best_w = w0
    best_z = z0
    status = 0
    for _ in range(100):
        z = integrate_z(p, w0, z0, w)
        if not (z == z):
            # diverged on the way: shrink toward lo
            hi = w
            w = 0.5 * (lo + hi)
            status = 2
            continue
        g = output_u(p, w, z) - u
        if abs(g) <= tol_u:
            return w, z, 0
        f_end = dz_dw(p, z, sdw, _sgn(w) if w != 0.0 else sdw)
        d = 2.0 * p[P_A1] * w + p[P_A2] + p[P_AZ] * f_end
        if g * sdw < 0.0:
            if d <= 0.0:
                # past the turning point of u(w): cannot reach u on this branch
                hi = w
                status = 1
            else:
                lo = w
                lo_z = z
        else:
            hi = w
        best_w = lo
        best_z = lo_z
        if hi == hi and abs(hi - lo) <= 1e-13 * (abs(lo) + 1.0):
            break
        # Newton proposal; once the correction is negligible take it and stop
        wn = w - g / d if d > 0.0 else np.nan
        if wn == wn and abs(wn - w) <= NEWTON_ACCEPT * (abs(w) + 1.0) and (
                hi != hi or ((wn - lo) * sdw > 0.0 and (hi - wn) * sdw > 0.0)):
            # a move this small needs no sub-steps: Euler error ~ (wn - w)^2 * |df/dw|
            return wn, z + f_end * (wn - w), 0
        if hi == hi:
            inside = wn == wn and (wn - lo) * sdw > 0.0 and (hi - wn) * sdw > 0.0
            if not inside or status == 1:
                wn = 0.5 * (lo + hi)
        else:
            if not (wn == wn) or (wn - lo) * sdw <= 0.0:
                wn = lo + 2.0 * (lo - w0) + sdw * 1e-6 * (abs(lo) + 1.0)
        w = wn
        if status == 1 and hi == hi:
            # find where du/dw vanishes: bisect on the slope instead of g
            for _ in range(80):
                wm = 0.5 * (lo + hi)
                zm = integrate_z(p, w0, z0, wm)
                if zm == zm and slope_du_dw(p, wm, zm, sdw) > 0.0 and (output_u(p, wm, zm) - u) * sdw < 0.0:
                    lo = wm
                    lo_z = zm
                else:
                    hi = wm
                if abs(hi - lo) <= 1e-13 * (abs(lo) + 1.0):
                    break
            return lo, lo_z, 1
    if status == 2:
        return best_w, best_z, 2
    return best_w, best_z, status


@njit(cache=True, fastmath=False, error_model="numpy")
def forward_run(p, u, w0: float, z0: float, w_out, z_out) -> int:
    """Forward map over an array; returns the number of saturated/failed samples."""
    flagged = 0
    wp = w0
    zp = z0
    for k in range(u.shape[0]):
        w, z, st = forward_step(p, wp, zp, u[k])
        if st != 0:
            flagged += 1
        wp = w
        zp = z
        w_out[k] = w
        z_out[k] = z
    return flagged


@njit(cache=True, fastmath=False, error_model="numpy")
def forward_sse(p, u, w_meas, weight, w0: float, z0: float) -> float:
    """Weighted sum of squared output error of the forward map (for fitting)."""
    sse = 0.0
    wp = w0
    zp = z0
    for k in range(u.shape[0]):
        w, z, st = forward_step(p, wp, zp, u[k])
        if st != 0:  # diverged, or u beyond the model's monotone range: not a candidate
            return np.inf
        wp = w
        zp = z
        e = w - w_meas[k]
        sse += weight[k] * e * e
    return sse


@njit(cache=True, parallel=True)
def forward_sse_many(P, u, w_meas, weight, w0: float, z0: float, out) -> None:
    """forward_sse for each row of P, in parallel over the rows (both cores)."""
    for i in prange(P.shape[0]):
        out[i] = forward_sse(P[i], u, w_meas, weight, w0, z0)
