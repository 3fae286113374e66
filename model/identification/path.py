"""What a fit is scored on, and the local refinements: the compressed training path and its costs.

The model is rate independent, so its output at a kept sample depends only on
the input's extrema before it: keeping every reversal plus a decimated grid
gives the same outputs at a fraction of the cost (``FitPath``). A log holding
more reversals than a fit needs is scored on evenly spread stretches of it,
each started from the state its own first samples imply. Every candidate may
spend at most a budget of sub-steps: a parameter set that needs more is no
model of a wing and is rejected at a bounded cost.

``Objective`` gives the mean squared forward output error of many candidates
at once (compiled, over both cores) and the per-sample residuals a
Gauss-Newton step needs; ``refine`` is a bounded Levenberg-Marquardt
(trust-region) refinement on those residuals with a Jacobian computed in
parallel, ``polish`` a Nelder-Mead polish for the short delay scans.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from warpbridge.model import kernels as K
from warpbridge.model._jit import njit, prange
from warpbridge.model.identification.space import fold_depth, thetas_to_rows
from warpbridge.model.initial_state import algebraic_z0_rows
from warpbridge.model.signals import compress_path, noise_floor, reversal_indices, turning_indices

REVERSAL_NOISES = 3.0  # a noisy input's reversal counts when it turns back by this many noise deviations
FOLD_PENALTY = 1e3  # cost of a backbone folding inside the working range (a fit costs well under 1), plus its depth
FAIL_RESIDUAL = 10.0  # residual (normalised warp) of each sample a candidate cannot follow
REFINE_TOL_Z = 1e-8  # local error per sub-step in the refinement: its finite differences need smooth costs
JAC_STEP = 1e-5  # relative step of the refinement's finite-difference Jacobian
LM_LAMBDA0 = 1e-3  # Levenberg-Marquardt's first damping (times the diagonal of J^T J)
LM_TRIES = 8  # dampings tried per step before the refinement stops
LM_FTOL, LM_XTOL = 1e-9, 1e-9  # it stops once a step gains less than this share of the cost, or moves less

FIT_TOL_Z = 1e-6  # local error per sub-step while fitting (normalised z: a millionth of the tendon half-range)
BUDGET_PER_POINT = 40  # sub-steps an evaluation may spend per kept sample ...
BUDGET_PER_REVERSAL = 1000  # ... and per reversal (a whole transition between saturations takes 100-250)
SEARCH_POINTS, SEARCH_REVERSALS = 1200, 60  # what one candidate of the global search is scored on, at most
POLISH_REVERSALS = 120  # the polish scores on at most this many reversals (and ``max_fit_points`` samples)
STRETCHES = 4  # when a log holds more, evenly spread stretches of it
START_SAMPLES = 25  # raw samples given to the algebraic initial state of a stretch


def input_reversals(u: np.ndarray) -> np.ndarray:
    """The input's reversals that matter to a fit: every one of a clean input; of a noisy one (a closed
    loop's command reacting to the sensor's noise) those it turns back from by ``REVERSAL_NOISES`` noise
    deviations (``signals.turning_indices``). A jitter reversal moves the warp by less than the noise."""
    d2 = np.diff(u, 2)
    if d2.size == 0 or float(np.median(np.abs(d2 - np.median(d2)))) == 0.0:
        return reversal_indices(u)
    noise = noise_floor(u)
    if not (math.isfinite(noise) and noise > 0):
        return reversal_indices(u)
    return turning_indices(u, REVERSAL_NOISES * noise)


def fit_stretches(u: np.ndarray, n_end: int, max_reversals: int, pieces: int = STRETCHES) -> list[tuple[int, int]]:
    """Raw sample ranges [a, b) of u[:n_end] to score on: all of it when it holds at most
    ``max_reversals`` reversals, else ``pieces`` evenly spaced stretches that hold that many together.

    The Bouc-Wen state is (w, z) and z follows from u and w, so each stretch starts from the state
    its own first samples imply: a fit's cost is bounded by these limits, not by the log."""
    rev = input_reversals(u[:n_end])
    if rev.size <= max_reversals:
        return [(0, n_end)]
    per = max(1, max_reversals // pieces)
    out = []
    for j in range(pieces):
        a = int(j * n_end / pieces)
        nxt = int((j + 1) * n_end / pieces)
        k = int(np.searchsorted(rev, a, side="right"))
        b = int(rev[k + per]) if k + per < rev.size else n_end
        out.append((a, max(a + 2, min(b, nxt))))
    return out


@dataclass
class FitPath:
    """Stretches of the compressed training path (normalised units), concatenated; ``offsets`` bound them."""

    u: np.ndarray
    w: np.ndarray
    weight: np.ndarray
    offsets: np.ndarray
    starts: list[tuple[np.ndarray, np.ndarray]]
    budgets: np.ndarray

    @classmethod
    def build(cls, u_hat: np.ndarray, w_hat: np.ndarray, n_end: int, max_points: int,
              max_reversals: int) -> FitPath:
        ranges = fit_stretches(u_hat, n_end, max_reversals)
        span = sum(b - a for a, b in ranges)
        keep_every = max(1, int(math.ceil(span / max_points)))
        us, ws, wts, offs, starts, budgets = [], [], [], [0], [], []
        for a, b in ranges:
            idx = compress_path(u_hat[a:b], keep_every)  # every reversal, jitter's too: the model sees them
            wt = np.zeros(idx.size)
            wt[idx % keep_every == 0] = 1.0
            us.append(u_hat[a:b][idx])
            ws.append(w_hat[a:b][idx])
            wts.append(wt)
            offs.append(offs[-1] + idx.size)
            starts.append((u_hat[a:min(b, a + START_SAMPLES)], w_hat[a:min(b, a + START_SAMPLES)]))
            budgets.append(BUDGET_PER_POINT * idx.size + BUDGET_PER_REVERSAL * (reversal_indices(us[-1]).size + 1))
        return cls(np.concatenate(us), np.concatenate(ws), np.concatenate(wts), np.array(offs, dtype=np.int64),
                   starts, np.array(budgets, dtype=np.int64))

    @property
    def reversals(self) -> int:
        return int(sum(reversal_indices(self.u[a:b]).size for a, b in zip(self.offsets[:-1], self.offsets[1:],
                                                                           strict=True)))


def rest_warp_rows(P: np.ndarray, u0: float, z0: np.ndarray) -> np.ndarray:
    """Per row of P: the warp at which the model holding state z0 outputs u0 (rising root of the quadratic)."""
    a1, a2 = P[:, 0], P[:, 1]
    c = P[:, 2] + P[:, 3] * z0 - u0
    with np.errstate(divide="ignore", invalid="ignore"):
        disc = a2 * a2 - 4.0 * a1 * c
        r = np.sqrt(np.maximum(disc, 0.0))
        lin = -c / a2
        root1 = (-a2 + r) / (2.0 * a1)
        root2 = (-a2 - r) / (2.0 * a1)
        quad = np.where(2.0 * a1 * root1 + a2 > 0, root1, np.where(2.0 * a1 * root2 + a2 > 0, root2, root1))
        quad = np.where(disc < 0, -a2 / (2.0 * a1), quad)
    return np.where(np.abs(a1) < 1e-15, lin, quad)


class Objective:
    """Mean squared forward output error on a ``FitPath`` (normalised units).

    Every candidate starts each stretch from the state that stretch's first samples imply for it
    (``algebraic_z0``), and may spend at most a budget of sub-steps: a parameter set that needs
    more is no model of a wing (a state stuck where it is unstable, or a saturation far stiffer
    than the data) and is rejected at a bounded cost instead of a thousand ordinary evaluations'."""

    def __init__(self, path: FitPath, c: float = 0.0, tol: float = FIT_TOL_Z,
                 fold: tuple[float, float] | None = None) -> None:
        self.path = path
        self.c = c
        self.fold = fold  # (lo, hi) normalised warp: backbones folding inside cost FOLD_PENALTY (None: no check)
        self.wsum = float(path.weight.sum())
        self.tol = float(tol)
        self.calls = 0

    def params_matrix(self, thetas: np.ndarray) -> np.ndarray:
        return thetas_to_rows(thetas, self.c)

    def start(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(w0, z0), one column per stretch: the state its first samples imply, consistent with its first u."""
        m = len(self.path.starts)
        W0, Z0 = np.empty((P.shape[0], m)), np.empty((P.shape[0], m))
        for j, (us, ws) in enumerate(self.path.starts):
            z0 = algebraic_z0_rows(P, us, ws)
            Z0[:, j] = np.where(np.isfinite(z0), z0, 0.0)
            W0[:, j] = rest_warp_rows(P, float(us[0]), Z0[:, j])
        return W0, Z0

    def many(self, thetas: np.ndarray) -> np.ndarray:
        """Vectorised cost for DE: thetas has shape (S, N)."""
        thetas = np.atleast_2d(thetas)
        self.calls += thetas.shape[0]
        depth = fold_depth(thetas, self.c, *self.fold) if self.fold is not None else np.zeros(thetas.shape[0])
        out = FOLD_PENALTY * (1.0 + depth)  # a folding backbone is not simulated
        run = depth <= 0
        if run.any():
            P = self.params_matrix(thetas[run])
            sse = np.empty(P.shape[0])
            W0, Z0 = self.start(P)
            pa = self.path
            rows = _sse_rows if P.shape[0] >= 4 else _sse_rows_serial
            rows(P, pa.u, pa.w, pa.weight, pa.offsets, W0, Z0, pa.budgets, self.tol, sse)
            sse = sse / self.wsum
            sse[~np.isfinite(sse)] = 1e6
            out[run] = sse
        return out

    def one(self, theta: np.ndarray) -> float:
        return float(self.many(theta[None, :])[0])


@njit(cache=True)
def _sse_row(p, u, w, weight, offsets, w0, z0, budgets, tol) -> float:
    s = 0.0
    for j in range(offsets.shape[0] - 1):
        a, b = offsets[j], offsets[j + 1]
        s += K.forward_sse_budget(p, u[a:b], w[a:b], weight[a:b], w0[j], z0[j], budgets[j], tol)
        if not s < np.inf:
            break
    return s


@njit(cache=True, parallel=True)
def _sse_rows(P, u, w, weight, offsets, W0, Z0, budgets, tol, out):
    for i in prange(P.shape[0]):
        out[i] = _sse_row(P[i], u, w, weight, offsets, W0[i], Z0[i], budgets, tol)


@njit(cache=True)
def _sse_rows_serial(P, u, w, weight, offsets, W0, Z0, budgets, tol, out):
    """One candidate at a time (the polish): a parallel region per evaluation would wait for a second
    thread to be scheduled, which on a busy machine costs more than the evaluation."""
    for i in range(P.shape[0]):
        out[i] = _sse_row(P[i], u, w, weight, offsets, W0[i], Z0[i], budgets, tol)


@njit(cache=True)
def _resid_row(p, u, w, weight, offsets, w0, z0, budgets, tol, out) -> bool:
    """Residuals (model - measured, times sqrt(weight)) at the weighted samples of every stretch; False (and
    ``FAIL_RESIDUAL`` from the first sample it cannot follow) when the candidate fails."""
    k = 0
    ok = True
    for j in range(offsets.shape[0] - 1):
        a, b = offsets[j], offsets[j + 1]
        wp = w0[j]
        zp = z0[j]
        zn = -1.0
        used = 0
        for i in range(a, b):
            if ok:
                wn, zz, zn, st, taken = K._forward_solve(p, wp, zp, zn, u[i], budgets[j] - used, tol)
                used += taken
                if st > 1:  # diverged or out of budget; saturated (1): held where the forward map holds it
                    ok = False
                else:
                    wp = wn
                    zp = zz
            if weight[i] > 0.0:
                out[k] = math.sqrt(weight[i]) * (wp - w[i]) if ok else FAIL_RESIDUAL
                k += 1
    return ok


@njit(cache=True, parallel=True)
def _resid_rows(P, u, w, weight, offsets, W0, Z0, budgets, tol, out, ok):
    for i in prange(P.shape[0]):
        ok[i] = _resid_row(P[i], u, w, weight, offsets, W0[i], Z0[i], budgets, tol, out[i])


def residuals_many(obj: Objective, thetas: np.ndarray, tol: float = REFINE_TOL_Z) -> tuple[np.ndarray, np.ndarray]:
    """(R, ok): per candidate the weighted residuals on the objective's path (normalised warp), and whether it
    followed the whole path. Folding backbones (``obj.fold``) are not simulated: their residuals are
    ``FAIL_RESIDUAL``."""
    thetas = np.atleast_2d(thetas)
    pa = obj.path
    m = int(np.count_nonzero(pa.weight > 0))
    R = np.full((thetas.shape[0], m), FAIL_RESIDUAL)
    ok = np.zeros(thetas.shape[0], dtype=np.bool_)
    run = np.ones(thetas.shape[0], dtype=bool)
    if obj.fold is not None:
        run = fold_depth(thetas, obj.c, *obj.fold) <= 0
    if run.any():
        P = obj.params_matrix(thetas[run])
        W0, Z0 = obj.start(P)
        Rr = np.empty((P.shape[0], m))
        okr = np.zeros(P.shape[0], dtype=np.bool_)
        _resid_rows(P, pa.u, pa.w, pa.weight, pa.offsets, W0, Z0, pa.budgets, tol, Rr, okr)
        R[run] = Rr
        ok[run] = okr
    obj.calls += thetas.shape[0]
    return R, ok


def jacobian(obj: Objective, theta: np.ndarray, lo: np.ndarray, hi: np.ndarray, r0: np.ndarray | None = None,
             tol: float = REFINE_TOL_Z) -> tuple[np.ndarray, np.ndarray]:
    """(J, r0): forward-difference Jacobian of the residuals at theta (all columns at once, in parallel),
    each step taken inward where theta sits at a bound."""
    n = theta.size
    h = JAC_STEP * np.maximum(1.0, np.abs(theta))
    h = np.where(theta + h > hi, -h, h)
    X = np.tile(theta, (n + (1 if r0 is None else 0), 1))
    X[np.arange(n), np.arange(n)] += h
    R, _ = residuals_many(obj, X, tol)
    if r0 is None:
        r0 = R[n]
    J = (R[:n] - r0[None, :]).T / h[None, :]
    return J, r0


@dataclass
class Refined:
    """The outcome of one local refinement: theta, its cost (mean squared weighted residual), iterations."""

    theta: np.ndarray
    cost: float
    iterations: int


def refine(obj: Objective, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray, max_iter: int,
           callback=None, tol: float = REFINE_TOL_Z) -> Refined:
    """Levenberg-Marquardt from ``x0`` on the objective's residuals inside the box [lo, hi] (a step leaving it
    is projected back), with Marquardt's scaling and the Jacobian by ``jacobian``; at most ``max_iter``
    Jacobians. Normal equations of the parameters' size only: a step costs the residuals, not a
    factorisation of the Jacobian. The start is returned when nothing better is found."""
    x = np.clip(np.asarray(x0, dtype=np.float64), lo, hi)
    r = residuals_many(obj, x[None, :], tol)[0][0]
    f = float(r @ r)
    lam = LM_LAMBDA0
    it = 0
    for it in range(1, max_iter + 1):
        if callback is not None:
            callback(it)
        J, _ = jacobian(obj, x, lo, hi, r, tol)
        if not np.all(np.isfinite(J)):
            break
        H = J.T @ J
        g = J.T @ r
        d = np.maximum(np.diag(H), 1e-12 * max(float(np.max(np.diag(H))), 1e-300))
        accepted = False
        for _ in range(LM_TRIES):
            try:
                step = -np.linalg.solve(H + lam * np.diag(d), g)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            xn = np.clip(x + step, lo, hi)
            rn = residuals_many(obj, xn[None, :], tol)[0][0]
            fn = float(rn @ rn)
            if fn < f:
                accepted = True
                gain = f - fn
                moved = float(np.max(np.abs(xn - x) / np.maximum(1.0, np.abs(x))))
                x, r, f = xn, rn, fn
                lam = max(lam * 0.3, 1e-9)
                break
            lam *= 10.0
        if not accepted or gain <= LM_FTOL * f or moved <= LM_XTOL:
            break
    return Refined(x, f / max(r.size, 1), it)


def polish(obj: Objective, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray, evals: int,
           callback=None) -> tuple[np.ndarray, float]:
    """Nelder-Mead from ``x0`` inside the box [lo, hi] (a penalty outside it): (theta, its cost)."""

    def clipped(th):
        pen = float(np.sum(np.maximum(th - hi, 0) + np.maximum(lo - th, 0)))
        return obj.one(np.clip(th, lo, hi)) + 10.0 * pen

    f0 = obj.one(x0)
    nm = minimize(clipped, x0, method="Nelder-Mead", callback=callback,
                  options={"maxfev": evals, "xatol": 1e-7, "fatol": 1e-14, "adaptive": True})
    if not nm.fun <= f0:
        return x0, f0
    best = np.clip(nm.x, lo, hi)
    return best, obj.one(best)
