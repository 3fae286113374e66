"""The start design of identification: the backbone and state coefficients solved exactly per trial shape.

In the paper's form the tendon travel is linear in the backbone and state
coefficients once the hysteretic state's trajectory is fixed:

    u = a1 w^2 + a2 w + a3 + az z(w; A, n, b)

and z's trajectory depends on the warp path and the shape alone. With the scale
fixed by A = 1 (z then counts warp until it saturates), each trial shape costs one
integration of z over the measured warp and a four-column least-squares solve
(separable least squares, variable projection, on the input-side error). The
trial shapes are a deterministic, well-spread design: a scrambled Sobol' sequence
with a fixed seed, the paper's shape and the prior's; the straight line and the
quadratic without hysteresis (az = 0) are inside every solve. The best
distinct shapes are handed on, in the search's parameter vector (``space``),
to the refinement on the forward warp error. Steps 3 (``start_design``) and 4
(``linear_solve``) of ``identify`` run it on a log's ``LogData``; the straight
line and the quadratic backbone are appended to the starts it hands on.

The warp path the state is integrated over is the measured warp with its
jitter removed: every reversal smaller than a few noise deviations would
otherwise be a real reversal of the model, and its state would jump by the
loop's width (``monotone.monotone_between_turns``). A state that diverges or
needs more sub-steps than its budget marks its trial shape as no model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import median_filter
from scipy.stats import qmc

from warpbridge.model import kernels as K
from warpbridge.model._jit import njit, prange
from warpbridge.model.boucwen import BoucWenParams
from warpbridge.model.identification.data import LogData
from warpbridge.model.identification.space import normalised_to_theta, thetas_to_rows
from warpbridge.model.monotone import monotone_between_turns
from warpbridge.model.signals import linear_fit, noise_floor, reversal_indices, turning_indices

DESIGN_SEED = 20170101  # the Sobol' scramble of the default design (fixed: the default answer is reproducible)
DESIGN_LOG2 = 9  # 2^9 trial shapes
DESIGN_POINTS = 1500  # samples of the warp path the design scores on, at most ...
DESIGN_REVERSALS = 80  # ... and reversals (in evenly spread stretches beyond that)
DESIGN_TOL_Z = 1e-6  # local error per sub-step of the state's integration (z counts warp half-ranges)
DESIGN_BUDGET_POINT, DESIGN_BUDGET_REVERSAL = 40, 1000  # sub-steps a trial shape may spend
JITTER_NOISES = 8.0  # reversals of the smoothed warp smaller than this many of its noise deviations are jitter
SMOOTH_SHARE, SMOOTH_MAX = 0.05, 51  # the warp's moving median (edges kept): this share of its median run between turns
# the shape vector s (A = 1): n, log10 zsat_load, log10 (zsat_unload / zsat_load), asinh r_unload, asinh r_load,
# [asinh D, asinh E]; the design box
SHAPE_BOUNDS_ONE_SIDED = [(1.0, 5.0), (-2.0, 0.5), (-1.0, 1.0), (-7.0, 0.85), (-7.0, 0.85)]
SHAPE_BOUNDS_TWO_SIDED = SHAPE_BOUNDS_ONE_SIDED + [(-4.0, 4.0), (-4.0, 4.0)]
DISTINCT = 0.08  # starts closer than this (share of the design box, RMS over coordinates) are one start
LOOP_FLOOR = 1e-3  # az (normalised) of a start without hysteresis: a loop too narrow to matter
LINE_ZSAT = -3.5  # log10 of the state's saturation (normalised) of the straight-line and quadratic starts


@dataclass
class WarpPath:
    """The training part's warp path, jitter removed and compressed, with the tendon input at its samples
    (normalised units); ``offsets`` bound stretches that each start with z = 0 and are scored from their
    first turn on (``weight``)."""

    w: np.ndarray
    u: np.ndarray
    weight: np.ndarray
    offsets: np.ndarray
    budgets: np.ndarray

    @classmethod
    def build(cls, u_hat: np.ndarray, w_hat: np.ndarray, n_end: int, noise_hat: float,
              turns_from: str = "input") -> WarpPath:
        """The path with the runs cut at the input's turns (``turns_from="input"``, ``dejitter``) or at the
        warp's own (``"warp"``, ``dejitter_warp``)."""
        if turns_from == "input":
            ws, _ = dejitter(u_hat[:n_end], w_hat[:n_end], noise_hat)
        else:
            ws, _ = dejitter_warp(w_hat[:n_end], noise_hat)
        turns = reversal_indices(ws)
        if turns.size > DESIGN_REVERSALS:  # evenly spread stretches holding DESIGN_REVERSALS turns together
            pieces = 4
            per = DESIGN_REVERSALS // pieces
            ranges = []
            for j in range(pieces):
                k = int(j * turns.size / pieces)
                a = 0 if j == 0 else int(turns[max(k - 1, 0)])
                b = int(turns[min(k + per, turns.size - 1)]) + 1
                ranges.append((a, b))
        else:
            ranges = [(0, n_end)]
        span = sum(b - a for a, b in ranges)
        every = max(1, int(math.ceil(span / DESIGN_POINTS)))
        wl, ul, wt, offs, budgets = [], [], [], [0], []
        for a, b in ranges:
            seg = ws[a:b]
            rev = reversal_indices(seg)
            idx = np.unique(np.concatenate([np.arange(0, seg.size, every), rev, [0, seg.size - 1]]))
            first_turn = int(rev[0]) if rev.size else seg.size
            wgt = ((idx % every == 0) & (idx > first_turn)).astype(np.float64)
            wl.append(seg[idx])
            ul.append(u_hat[a:b][idx])
            wt.append(wgt)
            offs.append(offs[-1] + idx.size)
            budgets.append(DESIGN_BUDGET_POINT * idx.size + DESIGN_BUDGET_REVERSAL * (rev.size + 1))
        return cls(np.concatenate(wl), np.concatenate(ul), np.concatenate(wt), np.array(offs, dtype=np.int64),
                   np.array(budgets, dtype=np.int64))


def dejitter(u: np.ndarray, w: np.ndarray, noise_w: float) -> tuple[np.ndarray, float]:
    """(the warp with its jitter removed, the input's turn threshold). The forward map is monotone, so the warp
    moves the way the tendon does: the input's real turns (``JITTER_NOISES`` of its own noise deviations,
    after a centred moving median over ``SMOOTH_SHARE`` of its median run between turns) cut the log into runs,
    and in each the warp is replaced by its least-squares monotone fit (``monotone_between_turns``). Turns of
    the input in the model's dead zone move the warp by less than its noise; found on the warp they were lost."""
    span = float(np.ptp(u))
    d2 = np.diff(u, 2)
    quiet = d2.size == 0 or float(np.median(np.abs(d2 - np.median(d2)))) == 0.0  # piecewise linear: no noise
    noise_u = 0.0 if quiet else noise_floor(u)
    if not (math.isfinite(noise_u) and noise_u > 0):
        noise_u = 1e-9 * span
    turns = turning_indices(u, max(0.05 * span, 2.0 * JITTER_NOISES * noise_u))
    run = float(np.median(np.diff(turns))) if turns.size > 2 else float(u.size)
    m = 2 * int(max(0, min(SMOOTH_MAX, SMOOTH_SHARE * run)) // 2) + 1  # odd: centred, no lag
    um = median_filter(u, m, mode="nearest") if m > 1 else u
    thr = max(JITTER_NOISES * noise_u * math.sqrt(0.5 * math.pi / m), 1e-9 * span)
    if not (math.isfinite(noise_w) and noise_w > 0):
        return w.copy(), thr
    return monotone_between_turns(um, thr, w), thr


def dejitter_warp(w: np.ndarray, noise: float) -> tuple[np.ndarray, float]:
    """``dejitter`` with the runs cut at the warp's own turns: where the input is noisy itself (a closed loop's
    command reacts to the sensor's noise), its turns are not the warp's."""
    if not (math.isfinite(noise) and noise > 0):
        return w.copy(), 0.0
    turns = turning_indices(w, max(0.05 * float(np.ptp(w)), 2.0 * JITTER_NOISES * noise))
    run = float(np.median(np.diff(turns))) if turns.size > 2 else float(w.size)
    m = 2 * int(max(0, min(SMOOTH_MAX, SMOOTH_SHARE * run)) // 2) + 1
    wm = median_filter(w, m, mode="nearest") if m > 1 else w
    thr = JITTER_NOISES * noise * math.sqrt(0.5 * math.pi / m)
    return monotone_between_turns(wm, thr, w), thr


@njit(cache=True)
def _state_row(p, w, offsets, budgets, tol, out) -> bool:
    """z along the warp path (each stretch from z = 0), within each stretch's budget of sub-steps."""
    for j in range(offsets.shape[0] - 1):
        a, b = offsets[j], offsets[j + 1]
        z = 0.0
        zn = 0.0
        used = 0
        out[a] = 0.0
        for i in range(a + 1, b):
            cap = budgets[j] - used
            if cap <= 0:
                return False
            zz, zc, _, _, _, taken = K._march(p, w[i - 1], z, zn, w[i], cap, tol, True)
            used += taken
            if not (zz == zz):
                return False
            z = zz
            zn = zc
            out[i] = z
    return True


@njit(cache=True, parallel=True)
def _state_rows(P, w, offsets, budgets, tol, Z, ok):
    for i in prange(P.shape[0]):
        ok[i] = _state_row(P[i], w, offsets, budgets, tol, Z[i])


def shape_rows(S: np.ndarray) -> np.ndarray:
    """Model parameter rows (A = 1, no backbone, az = 1) of shape vectors: the state's dynamics alone."""
    S = np.atleast_2d(S)
    th = np.zeros((S.shape[0], 9 + max(0, S.shape[1] - 5)))
    th[:, 0] = S[:, 0]
    th[:, 1] = 0.0
    th[:, 2] = S[:, 1]
    th[:, 3] = S[:, 1] + S[:, 2]
    th[:, 4] = S[:, 3]
    th[:, 5] = S[:, 4]
    if S.shape[1] > 5:
        th[:, 9:11] = S[:, 5:7]
    return thetas_to_rows(th)


@dataclass
class LinearSolve:
    """Per trial shape: the input-side cost (mean squared weighted residual, normalised u), the backbone
    (alpha1, alpha2, alpha3 around c), az, and whether the state could be integrated."""

    cost: np.ndarray
    alpha: np.ndarray
    az: np.ndarray
    ok: np.ndarray


class InputSide:
    """The separable least-squares problem on a ``WarpPath``: for each shape, z by integration, then
    (alpha, az) by least squares with az >= 0 (az = 0: the quadratic alone, inside every solve)."""

    def __init__(self, path: WarpPath, c: float) -> None:
        self.path = path
        self.c = c
        sw = np.sqrt(path.weight)
        self.sw = sw
        x = path.w - c
        B = np.column_stack([x * x, x, np.ones_like(x)]) * sw[:, None]
        self.Q, self.R = np.linalg.qr(B)
        self.ub = path.u * sw
        self.ru = self.ub - self.Q @ (self.Q.T @ self.ub)
        self.m = max(float(np.sum(path.weight)), 1.0)
        self.evaluations = 0

    def states(self, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        P = shape_rows(S)
        Z = np.zeros((P.shape[0], self.path.w.size))
        ok = np.zeros(P.shape[0], dtype=np.bool_)
        _state_rows(P, self.path.w, self.path.offsets, self.path.budgets, DESIGN_TOL_Z, Z, ok)
        self.evaluations += P.shape[0]
        return Z, ok

    def _projected(self, S: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(ok, weighted states, their part orthogonal to the backbone, its product with the input's, az >= 0)."""
        Z, ok = self.states(S)
        Zb = Z * self.sw[None, :]
        rz = Zb - (Zb @ self.Q) @ self.Q.T
        zz = np.einsum("ij,ij->i", rz, rz)
        zu = rz @ self.ru
        with np.errstate(divide="ignore", invalid="ignore"):
            az = np.where(ok & (zz > 0), np.maximum(zu / zz, 0.0), 0.0)
        return ok, Zb, rz, zu, az

    def solve(self, S: np.ndarray) -> LinearSolve:
        ok, Zb, _, zu, az = self._projected(S)
        cost = (float(self.ru @ self.ru) - az * zu) / self.m
        cost = np.where(ok, cost, np.inf)
        rhs = (self.ub[None, :] - az[:, None] * Zb) @ self.Q
        alpha = np.linalg.lstsq(self.R, rhs.T, rcond=None)[0].T  # a narrow band may leave R singular
        return LinearSolve(cost, alpha, az, ok)

    def residuals(self, S: np.ndarray) -> np.ndarray:
        """Weighted input-side residuals of each shape with its linear coefficients solved (rows)."""
        ok, _, rz, _, az = self._projected(S)
        R = self.ru[None, :] - az[:, None] * rz
        R[~ok] = 10.0 * np.sqrt(self.m) * max(float(np.std(self.ub)), 1e-12)
        return R


def shape_bounds(two_sided: bool) -> tuple[np.ndarray, np.ndarray]:
    b = SHAPE_BOUNDS_TWO_SIDED if two_sided else SHAPE_BOUNDS_ONE_SIDED
    return np.array([x[0] for x in b]), np.array([x[1] for x in b])


def sobol_design(two_sided: bool, seed: int = DESIGN_SEED, log2: int = DESIGN_LOG2) -> np.ndarray:
    """2^log2 shapes of a scrambled Sobol' sequence over the design box (deterministic for a seed)."""
    lo, hi = shape_bounds(two_sided)
    x = qmc.Sobol(d=lo.size, scramble=True, seed=seed).random_base2(log2)
    return qmc.scale(x, lo, hi)


def theta_to_shape(theta: np.ndarray) -> np.ndarray:
    """The shape vector of a search vector (its A and saturation levels moved to the A = 1 scale)."""
    th = np.asarray(theta, dtype=np.float64)
    s = [th[0], th[2] - th[1], th[3] - th[2], th[4], th[5]]
    if th.size > 9:
        s += [th[9], th[10]]
    return np.array(s)


def shapes_to_thetas(S: np.ndarray, sol: LinearSolve, az_floor: float) -> np.ndarray:
    """Search vectors (az = 1 scale) of shapes with their linear solution: A = az, zsat -> az zsat. A shape
    whose az came out 0 (no hysteresis) gets ``az_floor``: a loop too narrow to matter."""
    S = np.atleast_2d(S)
    az = np.maximum(sol.az, az_floor)
    la = np.log10(az)
    th = np.zeros((S.shape[0], 9 + max(0, S.shape[1] - 5)))
    th[:, 0] = S[:, 0]
    th[:, 1] = la
    th[:, 2] = S[:, 1] + la
    th[:, 3] = S[:, 1] + S[:, 2] + la
    th[:, 4] = S[:, 3]
    th[:, 5] = S[:, 4]
    th[:, 6:9] = sol.alpha
    if S.shape[1] > 5:
        th[:, 9:11] = S[:, 5:7]
    return th


def distinct_best(S: np.ndarray, cost: np.ndarray, k: int, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Indices of the k cheapest shapes that lie at least ``DISTINCT`` apart (finite costs only)."""
    order = np.argsort(cost)
    chosen: list[int] = []
    X = (S - lo) / (hi - lo)
    for i in order:
        if not np.isfinite(cost[i]):
            break
        if all(np.sqrt(np.mean((X[i] - X[j]) ** 2)) >= DISTINCT for j in chosen):
            chosen.append(int(i))
            if len(chosen) >= k:
                break
    return np.asarray(chosen, dtype=np.int64)


# ---- steps 3-4: start design and linear solve --------------------------------------------------

@dataclass
class Starts:
    """Search vectors to refine, best first by input-side cost, with the straight line and the quadratic
    backbone (no hysteresis) appended; ``evaluations`` of the linear solve."""

    thetas: np.ndarray
    input_rms: np.ndarray
    labels: list[str]
    evaluations: int


def start_design(data: LogData, seed: int, prior: BoucWenParams | None) -> tuple[np.ndarray, list[str]]:
    """Step 3: the trial shapes (A = 1 scale): the Sobol' design (scramble ``DESIGN_SEED + seed``), the
    paper's shape and the prior's."""
    S = sobol_design(data.two_sided, seed=DESIGN_SEED + seed)
    labels = ["design"] * S.shape[0]
    lo, hi = shape_bounds(data.two_sided)
    for name, p in (("paper", BoucWenParams.paper()), ("prior", prior)):
        if p is None:
            continue
        th = normalised_to_theta(data.norm.to_normalised(p), data.two_sided, data.norm.c)
        if th is not None:
            S = np.vstack([S, np.clip(theta_to_shape(th), lo, hi)])
            labels.append(name)
    return S, labels


def linear_solve(data: LogData, S: np.ndarray, labels: list[str], keep: int) -> Starts:
    """Step 4: (a1, a2, a3, az) solved exactly for every trial shape on the input-side error; the ``keep``
    distinct best as search vectors, then the straight line and the quadratic backbone."""
    lo, hi = shape_bounds(data.two_sided)
    thetas, rms, names, evaluations = [], [], [], 0
    for turns_from in ("input", "warp"):  # runs cut at the input's turns, and at the warp's: half the starts each
        wp = WarpPath.build(data.x_hat, data.w_hat, data.n_train_end, data.noise / data.norm.ws, turns_from)
        problem = InputSide(wp, data.norm.c)
        sol = problem.solve(S)
        evaluations += problem.evaluations
        best = distinct_best(S, sol.cost, max(1, (keep + 1) // 2), lo, hi)
        sub = LinearSolve(sol.cost[best], sol.alpha[best], sol.az[best], sol.ok[best])
        thetas.append(shapes_to_thetas(S[best], sub, LOOP_FLOOR))
        rms.append(np.sqrt(sol.cost[best]))
        names += [labels[i] for i in best]
        if turns_from == "input":
            quad = np.linalg.lstsq(problem.R, problem.Q.T @ problem.ub, rcond=None)[0]
    extra = [simple_theta(data, quad), simple_theta(data, line_alpha(data))]
    blo, bhi = data.bounds
    all_thetas = np.clip(np.vstack([*thetas, *extra]), blo, bhi)
    return Starts(all_thetas, np.concatenate([*rms, [np.nan, np.nan]]), names + ["quadratic", "line"], evaluations)


def line_alpha(data: LogData) -> np.ndarray:
    """Backbone (alpha1, alpha2, alpha3 around c, normalised) of the best straight line w = c0 + c1 u fitted
    on the training samples, written as u of w."""
    c0, c1 = linear_fit(data.x_hat, data.w_hat, data.train_mask)
    a2 = 1.0 / c1 if c1 != 0 else 1.0
    return np.array([0.0, a2, (data.norm.c - c0) * a2])


def simple_theta(data: LogData, alpha: np.ndarray) -> np.ndarray:
    """A search vector with backbone ``alpha`` and a state saturating at 10^LINE_ZSAT (no hysteresis)."""
    th = np.zeros(11 if data.two_sided else 9)
    th[0] = 2.0
    th[1] = 0.0
    th[2] = th[3] = LINE_ZSAT
    th[6:9] = alpha
    return th
