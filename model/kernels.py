"""Compiled (numba) kernels of the generalized Bouc-Wen tendon-sheath model.

The model maps warp ``w`` (deg) to tendon travel ``u`` (mm)::

    u = a1 w^2 + a2 w + a3 + az z
    dz/dw = A - |z|^n Psi,   Psi = b1 sgn(w' z) + b2 sgn(w w') + b3 sgn(w z)
                                  + b4 sgn(w') + b5 sgn(z) + b6 sgn(w)

It is rate independent, so ``z`` is integrated over ``w`` (never over time).
Each sub-step is no longer than ``H_MAX`` deg and no longer than
``K_STIFF / |df/dz|`` (after a reversal ``|z|^n Psi`` can reach ~60/deg, where a
single explicit step would overshoot), taken both where the step starts and,
when z moves far relative to itself, where an Euler step would land (z soft
near 0 can otherwise jump straight into a stiff saturation), and keeps its local error, estimated
from the derivatives of ``f``, below ``TOL_Z``: classical RK4 by default, a
cheaper Heun or Kutta-3 step when that already meets the tolerance, and an
L-stable linearly implicit Euler step where ``z`` rests at saturation. The
step sequence is a greedy march clipped to the end point, so ``z(w_end)`` is
continuous in ``w_end`` and the result does not depend on how the input was
sampled. ``|z|^n`` costs most (exp and log), so each step's last stage lends
it to the next through ``_carry_pow``.

Parameters travel as one float64 array ``p`` laid out as in ``P_*`` below.
Every kernel is NaN-safe: a non-finite input sample leaves the state unchanged,
and a diverging parameter set (possible while a global search explores) is
capped at ``Z_CAP`` and reported through the returned flag.
"""

from __future__ import annotations

import math

import numpy as np

from warpbridge.model._jit import njit

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
TRIAL_REACH = 8.0  # deg; before a bracket, a trial warp lies at most this (or twice the progress) past the last
BLOWUP_SPARE = 2.0  # a march ends as diverged once it runs this many times past where |z| must have blown up
THIRD = 1.0 / 3.0
SIXTH = 1.0 / 6.0


@njit(cache=True, inline="always")
def _sgn(x: float) -> float:
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return 0.0


@njit(cache=True, inline="always")
def _pow_n(az: float, n: float) -> float:
    """|z|^n for az = |z| > 0: exp(n log|z|) is within a few ulp of pow and ~20 % cheaper, and the
    kernels spend most of their time here."""
    return math.exp(n * math.log(az))


@njit(cache=True, inline="always")
def _carry_pow(z: float, zn: float, z_new: float, n: float) -> float:
    """|z_new|^n from zn = |z|^n when z_new is within 1e-4 of z relatively (the binomial series to
    x^4 is then exact to rounding); -1 (unknown) otherwise."""
    if zn < 0.0 or z == 0.0:
        return -1.0
    x = (z_new - z) / z
    if not abs(x) <= 1e-4:
        return -1.0
    s = 1.0 + (n - 2.0) * THIRD * x * (1.0 + 0.25 * (n - 3.0) * x)
    return zn * (1.0 + n * x * (1.0 + 0.5 * (n - 1.0) * x * s))


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
def _stage(p, zs: float, sdw: float, sw: float):
    """(dz/dw, |z|^n) at a stage value zs: a method's last stage lends its power to the next step."""
    a = abs(zs)
    if a == 0.0:
        return p[P_A], 0.0
    zn = _pow_n(a, p[P_N])
    return p[P_A] - zn * _psi(p, sdw, sw, _sgn(zs)), zn


@njit(cache=True, inline="always")
def dz_dw(p, z: float, sdw: float, sw: float) -> float:
    """Slope dz/dw of the hysteretic state moving in direction ``sdw``."""
    return _stage(p, z, sdw, sw)[0]


@njit(cache=True, inline="always")
def _rk4_limit(jac: float, f: float, h: float, tol: float) -> float:
    """Longest RK4 step up to h with h J <= K_STIFF and local error (h J)^5 / 120 |f| / J <= tol."""
    if h * jac > K_STIFF:
        h = K_STIFF / jac
    x = h * jac
    if f > 0.0 and x * x * x * x * x * f > 120.0 * tol * jac:
        h = _pow_n(120.0 * tol * jac / f, 0.2) / jac
    return h


@njit(cache=True, fastmath=False, error_model="numpy")
def integrate_z(p, w0: float, z0: float, w1: float) -> float:
    """State z after moving monotonically from (w0, z0) to w1.

    Returns NaN only if the parameter set diverges (|z| > Z_CAP or too stiff to integrate)."""
    return integrate_z_from(p, w0, z0, -1.0, w1)[0]


@njit(cache=True, fastmath=False, error_model="numpy")
def integrate_z_from(p, w0: float, z0: float, zn0: float, w1: float):
    """``integrate_z`` carrying zn = |z|^n (-1 when not known): returns (z, zn) at w1, taking
    ``zn0`` = |z0|^n if already known. Powers are the kernels' costliest operation; the value at
    the end of a step is carried from the nearest stage by ``_carry_pow`` (exact to rounding)."""
    z, zc, _, _, _, _ = _march(p, w0, z0, zn0, w1, MAX_SUBSTEPS, TOL_Z, False)
    return z, zc


@njit(cache=True, fastmath=False, error_model="numpy")
def _march(p, w0: float, z0: float, zn0: float, w1: float, max_steps: int, tol: float, end_blowup: bool):
    """The greedy sub-step march from (w0, z0) to w1, at most ``max_steps`` sub-steps of local
    error at most ``tol``.

    Returns (z, zn, wm, zm, znm, steps): the state at w1 (NaN if diverged or out of
    steps), the start (wm, zm, znm) of the march's last sub-step, and the sub-steps
    taken. Every sub-step before (wm, zm) was sized without regard to w1, so a
    march from w0 to any w1' beyond wm passes through (wm, zm) bit for bit and
    may resume there: the forward solve's iterations do, instead of integrating
    from the sample's start again each time. ``end_blowup``: a march bound to pass a
    blow-up of |z| ends as diverged at once (the same NaN, far fewer sub-steps). On in
    the unbudgeted forward solve only: off where sub-steps are counted against a budget
    (identification, whose search the count steers) and in the inverse map (a fitted
    model does not blow up there, and the control loop would pay for the check)."""
    wm = w0
    zm = z0
    znm = zn0
    if not (w1 == w1) or w1 == w0:
        return z0, zn0, wm, zm, znm, 0
    sdw = 1.0 if w1 > w0 else -1.0
    n = p[P_N]
    A = p[P_A]
    w = w0
    z = z0
    zc = zn0  # |z|^n if known
    for step in range(max_steps):
        remaining = (w1 - w) * sdw
        if remaining <= 0.0:
            return z, zc, wm, zm, znm, step
        wm = w
        zm = z
        znm = zc
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
        zn = 0.0
        js = 0.0
        jac = 0.0
        inv_z = 0.0
        if az > 0.0:
            zn = zc if zc >= 0.0 else _pow_n(az, n)
            sz = _sgn(z)
            psi = _psi(p, sdw, sw, sz)
            k1 = A - zn * psi
            inv_z = 1.0 / z
            if end_blowup and n > 1.0:
                # d|z|/ds = q |z|^n + sz sdw A with q = -sz sdw Psi, constant while sgn(w) holds. Where
                # rate = q |z|^n + min(sz sdw A, 0) > 0 (so q > 0), |z| passes any cap within
                # |z| / ((n - 1) rate). Marching there takes thousands of ever shorter sub-steps (the
                # tolerance is absolute), so a march that far or further (``BLOWUP_SPARE`` times, to
                # spare) ends as diverged at once.
                rate = -sz * sdw * psi * zn + min(sz * sdw * A, 0.0)
                span = remaining if w * sdw >= 0.0 else min(remaining, -w * sdw)
                if rate > 0.0 and BLOWUP_SPARE * az < span * (n - 1.0) * rate:
                    return np.nan, -1.0, wm, zm, znm, step + 1
            js = -n * zn * inv_z * psi * sdw  # d(dz/ds)/dz along the path s = |w - w0|
            jac = abs(js)
            if jac > 0.0:
                f = abs(k1)
                h_rk = _rk4_limit(jac, f, h, tol)
                if js < 0.0 and h * f <= 0.05 * az:
                    # z rests near its saturation: an L-stable linearly implicit Euler step
                    # (error ~ h^2 J |f| / 2) goes further than RK4 may, or as far for one power
                    # instead of three (not where z changes much relative to itself, near 0: there
                    # the linear error model misses the curvature of |z|^n)
                    h_be = h if h * h * jac * f <= 2.0 * tol else math.sqrt(2.0 * tol / (jac * f))
                    if h_be >= h_rk:
                        h = h_be
                        implicit = True
                if not implicit and h_rk < h:
                    h = h_rk
                    last = False
                elif implicit and h < remaining:
                    last = False
        else:
            k1 = A
        if not implicit:
            # where z moves far relative to itself (leaving 0 after a reversal, or from rest), the
            # stiffness at the start says little: bound the step by the stiffness where an Euler
            # step would land, so RK4 never jumps from the soft middle into the stiff saturation.
            # The bound shrinks the step at most by half at a time: the bound at the landing point of
            # a long step (deep in the saturation) is far shorter than the one at the landing point of
            # the step it leads to, and taking it at once crawls through the middle of a stiff model
            for _ in range(60):
                if h * abs(k1) <= 0.25 * az:
                    break
                ze = z + h * sdw * k1
                aze = abs(ze)
                if aze == 0.0:
                    break
                zne = _pow_n(aze, n)
                psie = _psi(p, sdw, sw, _sgn(ze))
                je = n * zne / aze * abs(psie)
                if je == 0.0:
                    break
                h_lim = _rk4_limit(je, max(abs(k1), abs(A - zne * psie)), h, tol)
                if h <= h_lim:
                    break
                h = max(h_lim, 0.5 * h)
                last = False
        hs = h * sdw
        order = 4
        if not implicit and az > 0.0 and h * abs(k1) <= 0.05 * az:
            # the cheapest explicit method whose local error, C h^(q+1) |z^(q+1)|, is within half the
            # tolerance; the solution's derivatives follow from f's (f2, f3: its 2nd and 3rd), taken
            # where the step starts, so only where z changes by less than 5 % over the step
            f = abs(k1)
            f2 = abs((n - 1.0) * inv_z * js)
            d3 = jac * jac * f + f2 * f * f
            if h * h * h * d3 <= 3.0 * tol:
                order = 2
            else:
                f3 = abs((n - 2.0) * inv_z) * f2
                d4 = jac * jac * jac * f + 4.0 * f2 * jac * f * f + f3 * f * f * f
                if h * h * h * h * d4 <= 12.0 * tol:
                    order = 3
        if implicit:
            z_new = z + hs * k1 / (1.0 - h * js)
            zc = _carry_pow(z, zn, z_new, n)
        elif order == 2:
            # Heun: its last stage sits next to the end point, so |z|^n carries over
            z2 = z + hs * k1
            k2, zn2 = _stage(p, z2, sdw, sw)
            z_new = z + 0.5 * hs * (k1 + k2)
            zc = _carry_pow(z2, zn2, z_new, n)
        elif order == 3:
            # Kutta's third-order method; its last stage too sits next to the end point
            k2 = dz_dw(p, z + 0.5 * hs * k1, sdw, sw)
            z3 = z + hs * (2.0 * k2 - k1)
            k3, zn3 = _stage(p, z3, sdw, sw)
            z_new = z + hs * (k1 + 4.0 * k2 + k3) * SIXTH
            zc = _carry_pow(z3, zn3, z_new, n)
        else:
            k2 = dz_dw(p, z + 0.5 * hs * k1, sdw, sw)
            k3 = dz_dw(p, z + 0.5 * hs * k2, sdw, sw)
            z4 = z + hs * k3
            k4, zn4 = _stage(p, z4, sdw, sw)
            z_new = z + hs * (k1 + 2.0 * k2 + 2.0 * k3 + k4) * SIXTH
            zc = _carry_pow(z4, zn4, z_new, n)
        z = z_new
        if z == 0.0:
            zc = 0.0
        if not (abs(z) < Z_CAP):
            return np.nan, -1.0, wm, zm, znm, step + 1
        if last:
            return z, zc, wm, zm, znm, step + 1
        w = w + hs
        if (w1 - w) * sdw <= 0.0:
            return z, zc, wm, zm, znm, step + 1
    return np.nan, -1.0, wm, zm, znm, max_steps  # too stiff to integrate: treat as diverged


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
    w, z, _, st = forward_step_zn(p, w0, z0, -1.0, u)
    return w, z, st


@njit(cache=True, fastmath=False, error_model="numpy")
def forward_step_zn(p, w0: float, z0: float, zn0: float, u: float):
    """``forward_step`` that also takes and returns zn = |z|^n (-1 when not known): a run of
    samples carries it, saving one power per sample. Returns (w, z, zn, status)."""
    w, z, zn, st, _ = _forward_solve(p, w0, z0, zn0, u, -1, TOL_Z)
    return w, z, zn, st


@njit(cache=True, inline="always")
def _within_reach(w: float, lo: float, w0: float, sdw: float) -> float:
    """A trial warp before the target is bracketed, kept within ``TRIAL_REACH`` (or twice the progress from
    the sample's start w0) past lo, the furthest point known short of it: from a near-flat slope (1e-7
    where a candidate is degenerate) a Newton guess lands millions of degrees out, and each march there
    runs out of sub-steps before it is bisected back."""
    reach = max(TRIAL_REACH, 2.0 * abs(lo - w0))
    return lo + sdw * reach if (w - lo) * sdw > reach else w


@njit(cache=True, fastmath=False, error_model="numpy")
def _forward_solve(p, w0: float, z0: float, zn0: float, u: float, budget: int, tol: float):
    """``forward_step_zn`` within a budget of sub-steps (-1: none beyond MAX_SUBSTEPS per march), with
    local error ``tol`` per sub-step.

    Returns (w, z, zn, status, substeps); status 3 when the budget ran out. Each
    iteration resumes the march from the last sub-step below the bracket's lower
    end instead of the sample's start, so a sample costs about one march over its
    interval however many iterations the solve takes."""
    if not (u == u):
        return w0, z0, zn0, 0, 0
    u0 = output_u(p, w0, z0)
    du = u - u0
    if du == 0.0:
        return w0, z0, zn0, 0, 0
    sdw = 1.0 if du > 0.0 else -1.0
    scale = abs(p[P_A2]) + abs(p[P_AZ] * p[P_A]) + 1e-12
    tol_u = 1e-13 * (abs(u) + scale)
    sw0 = _sgn(w0) if w0 != 0.0 else sdw
    # |z0|^n, shared by the guess and the first sub-step
    azn = 0.0 if z0 == 0.0 else (zn0 if zn0 >= 0.0 else _pow_n(abs(z0), p[P_N]))
    psi0 = _psi(p, sdw, sw0, _sgn(z0))
    f0 = p[P_A] - azn * psi0
    d0 = 2.0 * p[P_A1] * w0 + p[P_A2] + p[P_AZ] * f0
    if d0 <= 1e-12 * scale:
        d0 = scale
    lo = w0  # G(lo)*sdw < 0
    hi = np.nan  # G(hi)*sdw > 0 once known
    lo_z = z0
    # where the march to lo may resume (bit for bit the march from w0 up to there)
    rw = w0
    rz = z0
    rzn = azn
    used = 0
    # second-order guess: u(w0 + d) ~ u0 + D d + D' d^2 / 2
    inv_d0 = 1.0 / d0
    step = du * inv_d0
    w = w0 + step
    if z0 != 0.0:
        dfdz = -p[P_N] * azn / z0 * psi0
        d1 = 2.0 * p[P_A1] + p[P_AZ] * dfdz * f0
        corr = 1.0 - 0.5 * d1 * step * inv_d0
        if corr > 0.5 and corr < 1.5:
            w = w0 + step * corr
    w = _within_reach(w, w0, w0, sdw)
    best_w = w0
    best_z = z0
    status = 0
    for _ in range(100):
        cap = MAX_SUBSTEPS if budget < 0 else min(MAX_SUBSTEPS, budget - used)
        if cap <= 0:
            return best_w, best_z, -1.0, 3, used
        z, zc, mw, mz, mzn, taken = _march(p, rw, rz, rzn, w, cap, tol, budget < 0)
        used += taken
        if not (z == z):
            if budget >= 0 and used >= budget:
                return best_w, best_z, -1.0, 3, used
            # diverged on the way: shrink toward lo
            hi = w
            w = 0.5 * (lo + hi)
            status = 2
            continue
        g = output_u(p, w, z) - u
        zn_w = zc if zc >= 0.0 else (_pow_n(abs(z), p[P_N]) if z != 0.0 else 0.0)
        if abs(g) <= tol_u:
            return w, z, zn_w, 0, used
        f_end = p[P_A] - zn_w * _psi(p, sdw, _sgn(w) if w != 0.0 else sdw, _sgn(z))
        d = 2.0 * p[P_A1] * w + p[P_A2] + p[P_AZ] * f_end
        if g * sdw < 0.0:
            if d <= 0.0:
                # past the turning point of u(w): cannot reach u on this branch
                hi = w
                status = 1
            else:
                lo = w
                lo_z = z
                rw, rz, rzn = mw, mz, mzn
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
            z_new = z + f_end * (wn - w)
            return wn, z_new, (0.0 if z_new == 0.0 else _carry_pow(z, zn_w, z_new, p[P_N])), 0, used
        if hi == hi:
            inside = wn == wn and (wn - lo) * sdw > 0.0 and (hi - wn) * sdw > 0.0
            if not inside or status == 1:
                wn = 0.5 * (lo + hi)
        else:
            if not (wn == wn) or (wn - lo) * sdw <= 0.0:
                wn = lo + 2.0 * (lo - w0) + sdw * 1e-6 * (abs(lo) + 1.0)
            wn = _within_reach(wn, lo, w0, sdw)
        w = wn
        if status == 1 and hi == hi:
            # find where du/dw vanishes: bisect on the slope instead of g
            for _ in range(80):
                wm = 0.5 * (lo + hi)
                cap = MAX_SUBSTEPS if budget < 0 else min(MAX_SUBSTEPS, budget - used)
                if cap <= 0:
                    return lo, lo_z, -1.0, 3, used
                zm, _, mw, mz, mzn, taken = _march(p, rw, rz, rzn, wm, cap, tol, budget < 0)
                used += taken
                if zm == zm and slope_du_dw(p, wm, zm, sdw) > 0.0 and (output_u(p, wm, zm) - u) * sdw < 0.0:
                    lo = wm
                    lo_z = zm
                    rw, rz, rzn = mw, mz, mzn
                else:
                    hi = wm
                if abs(hi - lo) <= 1e-13 * (abs(lo) + 1.0):
                    break
            return lo, lo_z, -1.0, 1, used
    return best_w, best_z, -1.0, status, used


@njit(cache=True, fastmath=False, error_model="numpy")
def forward_run(p, u, w0: float, z0: float, w_out, z_out) -> int:
    """Forward map over an array; returns the number of saturated/failed samples."""
    flagged = 0
    wp = w0
    zp = z0
    zn = -1.0
    for k in range(u.shape[0]):
        w, z, zn, st = forward_step_zn(p, wp, zp, zn, u[k])
        if st != 0:
            flagged += 1
        wp = w
        zp = z
        w_out[k] = w
        z_out[k] = z
    return flagged


@njit(cache=True, fastmath=False, error_model="numpy")
def forward_sse_budget(p, u, w_meas, weight, w0: float, z0: float, budget: int, tol: float):
    """Weighted sum of squared output error of the forward map from (w0, z0), within a total budget of
    sub-steps of local error ``tol``: inf when the parameter set needs more, or diverges. A sample beyond
    the model's monotone range is held at its edge, as ``forward_run`` holds it.

    A global search meets parameter sets that are not models of any wing (a state stuck
    where it is unstable, a saturation far stiffer than the data): without a budget each
    can cost a thousand ordinary ones before it is found to diverge."""
    sse = 0.0
    wp = w0
    zp = z0
    zn = -1.0
    used = 0
    for k in range(u.shape[0]):
        w, z, zn, st, taken = _forward_solve(p, wp, zp, zn, u[k], budget - used, tol)
        used += taken
        if st > 1:  # diverged or out of budget; a saturated sample (1) is held where forward_run holds it
            return np.inf
        wp = w
        zp = z
        e = w - w_meas[k]
        sse += weight[k] * e * e
    return sse
