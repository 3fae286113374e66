"""The hysteretic state z0 at the start of a log, estimated from its first samples.

A log rarely starts at rest with z = 0: after the first bench run the tendon is
already loaded. The model is algebraic in z given u and w,

    z = (u - a1 w^2 - a2 w - a3) / az,

so the first samples give z0 directly, up to sensor noise. That value is
clamped to the band z can reach (the saturation limits of a long monotone
run) and then refined by a bounded one-dimensional search on the prediction
error over the log's opening stretch, as identification tools estimate initial
conditions. A model with a play (backlash, capstan stall) has a second
unknown, the edge the play's slack was last taken up on (by a pull, the
tendon loaded, or by a release): ``estimate_plant_start`` tries both and keeps
the release only on material evidence from the opening stretch. Units: u mm,
w deg, z in the model's units (mm when az = 1).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from warpbridge.model._jit import njit
from warpbridge.model.boucwen import BoucWenParams, forward
from warpbridge.model.effects import PULLED, RELEASED, apply_input_effects
from warpbridge.model.signals import noise_floor

GOLDEN = 0.5 * (np.sqrt(5.0) - 1.0)
OPENING_MAX = 2000  # samples over which z0 is refined (the state's influence fades after a few reversals)
FIRST_MAX = 25  # samples averaged for the algebraic value while the input has hardly moved


def algebraic_z(params: BoucWenParams, u, w) -> np.ndarray:
    """z that makes the model output u at warp w, sample by sample."""
    u = np.asarray(u, dtype=np.float64)
    w = np.asarray(w, dtype=np.float64)
    return (u - params.a1 * w * w - params.a2 * w - params.a3) / params.az


def reachable_band(params: BoucWenParams, w: float) -> tuple[float, float]:
    """(lo, hi) of z at warp w: the limits of long unloading and loading runs (may be infinite)."""
    hi, lo = params.z_saturation(1.0 if w >= 0 else -1.0)
    if lo > hi:
        lo, hi = hi, lo
    return float(lo), float(hi)


def _quiet_start(u: np.ndarray) -> int:
    """Number of leading samples before the input moves by more than 2 % of its span (at least 1)."""
    return int(_opening(np.ascontiguousarray(u, dtype=np.float64), np.zeros(0), 0.0, 0.0, 0.0, 1.0, FIRST_MAX)[0])


@njit(cache=True)
def _median_of(values, m):
    """``np.median`` of the first m of ``values`` (sorted in place), m > 0."""
    s = np.sort(values[:m])
    h = m // 2
    return s[h] if m % 2 == 1 else (s[h - 1] + s[h]) / 2.0


@njit(cache=True)
def _opening(u, w, a1, a2, a3, az, first_max):
    """What ``algebraic_z0`` takes from the log's first samples, in one compiled pass with numpy's arithmetic:
    (quiet samples k, median of the finite algebraic z over them or NaN, median of the non-NaN warps over
    them, whether one of those is finite). w may be empty (then only k)."""
    hi = -np.inf
    lo = np.inf
    for v in u:  # np.nanmax - np.nanmin; -inf with no number at all, which counts as no span, as NaN did
        if v > hi:
            hi = v
        if v < lo:
            lo = v
    span = hi - lo
    k = min(u.shape[0], first_max)
    if span > 0:
        for j in range(k):
            if abs(u[j] - u[0]) > 0.02 * span:
                k = max(1, j)
                break
    if w.shape[0] == 0:
        return k, math.nan, math.nan, False
    zs = np.empty(k)
    ws = np.empty(k)
    mz = 0
    mw = 0
    w_finite = False
    for j in range(k):
        z = (u[j] - a1 * w[j] * w[j] - a2 * w[j] - a3) / az
        if math.isfinite(z):
            zs[mz] = z
            mz += 1
        if not math.isnan(w[j]):
            ws[mw] = w[j]
            mw += 1
            w_finite = w_finite or math.isfinite(w[j])
    z_med = _median_of(zs, mz) if mz else math.nan
    w_med = _median_of(ws, mw) if mw else math.nan
    return k, z_med, w_med, w_finite


def algebraic_z0(params: BoucWenParams, u, w) -> float:
    """z0 from the first samples alone (median of the algebraic z), clamped to the reachable band.

    What the bridge uses at start with one tendon position and one sensor reading."""
    u = np.ascontiguousarray(u, dtype=np.float64)
    w = np.ascontiguousarray(w, dtype=np.float64)
    if w.size < min(u.size, FIRST_MAX):
        raise ValueError(f"{w.size} warp samples for {u.size} input samples")
    _, z, w_med, w_finite = _opening(u, w, params.a1, params.a2, params.a3, params.az, FIRST_MAX)
    if math.isnan(z):
        return 0.0
    lo, hi = reachable_band(params, w_med if w_finite else 0.0)
    return float(np.clip(z, lo, hi))


def algebraic_z0_rows(P: np.ndarray, u, w) -> np.ndarray:
    """``algebraic_z0`` for many parameter sets at once: P has one ``BoucWenParams.to_array()``
    layout per row (a1 a2 a3 az A n b1..b6). What a global search uses to start every candidate
    from the state the log's first samples imply."""
    P = np.atleast_2d(np.asarray(P, dtype=np.float64))
    u = np.asarray(u, dtype=np.float64)
    w = np.asarray(w, dtype=np.float64)
    k = _quiet_start(u)
    uk, wk = u[:k], w[:k]
    ok = np.isfinite(uk) & np.isfinite(wk)
    if not ok.any():
        return np.zeros(P.shape[0])
    uk, wk = uk[ok], wk[ok]
    a1, a2, a3, az = P[:, 0:1], P[:, 1:2], P[:, 2:3], P[:, 3:4]
    z = np.median((uk[None, :] - a1 * wk * wk - a2 * wk - a3) / az, axis=1)
    sw = 1.0 if float(np.median(wk)) >= 0 else -1.0
    A, n, b = P[:, 4], P[:, 5], P[:, 6:12]

    def psi(sdw: float, sz: float) -> np.ndarray:
        return (b[:, 0] * sdw * sz + b[:, 1] * sw * sdw + b[:, 2] * sw * sz + b[:, 3] * sdw + b[:, 4] * sz
                + b[:, 5] * sw)

    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        p_up, p_down = psi(1.0, 1.0), psi(-1.0, -1.0)
        hi = np.where(p_up > 0, (A / np.where(p_up > 0, p_up, 1.0)) ** (1.0 / n), np.inf)
        lo = np.where(p_down > 0, -(A / np.where(p_down > 0, p_down, 1.0)) ** (1.0 / n), -np.inf)
    # the band is [lo, hi] as z_saturation orders it (a model may have them the other way round)
    return np.clip(z, np.minimum(lo, hi), np.maximum(lo, hi))


def estimate_z0(params: BoucWenParams, u, w, *,
                simulate: Callable[[float, int], np.ndarray] | None = None,
                opening: int | None = None) -> float:
    """z0 that best explains the log's opening stretch, starting from the algebraic value.

    ``simulate(z0, n)`` predicts the first n warps from state z0 (default: the
    Bouc-Wen forward map on u); give it when the model carries effects. The
    search runs over the reachable band, widened to contain the algebraic value's
    neighbourhood when the band is unbounded."""
    u = np.asarray(u, dtype=np.float64)
    w = np.asarray(w, dtype=np.float64)
    if u.size == 0:
        return 0.0
    z_alg = algebraic_z0(params, u, w)
    n = min(u.size, opening or OPENING_MAX)
    ok = np.isfinite(w[:n])
    if ok.sum() < 3:
        return z_alg
    if simulate is None:
        def simulate(z0: float, m: int) -> np.ndarray:
            return forward(params, u[:m], z0=z0)[0]

    def cost(z0: float) -> float:
        pred = simulate(z0, n)
        e = pred[:n][ok] - w[:n][ok]
        v = float(np.dot(e, e))
        return v if np.isfinite(v) else np.inf

    lo, hi = reachable_band(params, float(w[0]) if np.isfinite(w[0]) else 0.0)
    zs = algebraic_z(params, u[:n][ok], w[:n][ok])
    zs = zs[np.isfinite(zs)]
    scale = float(np.ptp(zs)) if zs.size else 1.0
    scale = max(scale, 1e-6)
    a = max(lo, z_alg - scale) if np.isfinite(lo) else z_alg - scale
    b = min(hi, z_alg + scale) if np.isfinite(hi) else z_alg + scale
    if not a < b:
        return z_alg
    z_best, c_best = z_alg, cost(z_alg)
    # golden-section search on [a, b]; the cost is smooth and near-unimodal in z0
    x1, x2 = b - GOLDEN * (b - a), a + GOLDEN * (b - a)
    f1, f2 = cost(x1), cost(x2)
    for _ in range(40):
        if f1 <= f2:
            b, x2, f2 = x2, x1, f1
            x1 = b - GOLDEN * (b - a)
            f1 = cost(x1)
        else:
            a, x1, f1 = x1, x2, f2
            x2 = a + GOLDEN * (b - a)
            f2 = cost(x2)
        if b - a < 1e-6 * scale:
            break
    for x, f in ((x1, f1), (x2, f2)):
        if f < c_best:
            z_best, c_best = x, f
    return float(z_best)


def estimate_plant_z0(plant, t, u, w, airspeed=None, *, opening: int | None = None) -> float:
    """``estimate_z0`` for a ``model.plant.Plant`` with effects or an error correction: the algebraic value
    from the core model on the input the sheath sees, refined by simulating the whole chain."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    u = np.ascontiguousarray(u, dtype=np.float64)
    if u.size == 0:
        return 0.0
    if not plant.effects.active() and plant.error_model is None:
        return estimate_z0(plant.params, u, w, opening=opening)
    a = None if airspeed is None else np.asarray(airspeed, dtype=np.float64)

    def simulate(z0: float, m: int) -> np.ndarray:
        return plant.simulate(t[:m], u[:m], None if a is None else a[:m], z0=z0)[1]

    x = apply_input_effects(plant.effects, t, u, plant.slack_side)
    return estimate_z0(plant.core_params(), x, w, simulate=simulate, opening=opening)


def estimate_plant_start(plant, t, u, w, airspeed=None, *, opening: int | None = None) -> tuple[float, float]:
    """(z0, slack side): the whole initial state of a ``model.plant.Plant`` from the log's opening stretch.

    A model with a play (backlash, capstan stall) has a second unknown at the first sample: whether the last
    motion before the log took its slack up by a pull or by a release (``effects.PULLED`` / ``RELEASED``).
    Until the input first crosses the play the two predict warps a whole play apart, so each side gets its z0
    (``estimate_plant_z0``) and the release is kept when it explains the opening stretch materially better
    (``released_start_wins``)."""
    z_pull = estimate_plant_z0(replace(plant, slack_side=PULLED), t, u, w, airspeed, opening=opening)
    if not plant.effects.has_slack:
        return z_pull, PULLED
    t = np.ascontiguousarray(t, dtype=np.float64)
    u = np.ascontiguousarray(u, dtype=np.float64)
    w = np.asarray(w, dtype=np.float64)
    n = min(u.size, opening or OPENING_MAX)
    ok = np.isfinite(w[:n])
    a = None if airspeed is None else np.asarray(airspeed, dtype=np.float64)[:n]
    z_rel = estimate_plant_z0(replace(plant, slack_side=RELEASED), t, u, w, airspeed, opening=opening)
    cost = [squared_error(replace(plant, slack_side=side).simulate(t[:n], u[:n], a, z0=z)[1][ok], w[:n][ok])
            for side, z in ((PULLED, z_pull), (RELEASED, z_rel))]
    if released_start_wins(cost[0], cost[1], int(ok.sum()), noise_floor(w[np.isfinite(w)])):
        return z_rel, RELEASED
    return z_pull, PULLED


def squared_error(pred: np.ndarray, w: np.ndarray) -> float:
    """Sum of squared prediction errors (inf when not finite)."""
    e = np.asarray(pred, dtype=np.float64) - w
    c = float(np.dot(e, e))
    return c if np.isfinite(c) else np.inf


def released_start_wins(cost_pulled: float, cost_released: float, n: int, noise: float) -> bool:
    """A play starts on its releasing edge only when that lowers the opening's squared error (``n`` samples)
    by at least the noise variance per sample: material evidence, as a decision asks of an effect. Less, or
    a tie, keeps the pull (the tendon loaded, the usual start)."""
    margin = n * noise ** 2 if np.isfinite(noise) else 0.0
    return cost_released < cost_pulled - margin
