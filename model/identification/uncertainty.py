"""How well a log determines each identified parameter: confidence intervals from the local curvature.

At the optimum of the forward output error the Gauss-Newton matrix J^T J of the
residuals (per kept sample, normalised warp) with the residual variance gives
the covariance of the search vector theta. A log's residuals are not
independent (a model error follows the loop, the sensor may be filtered), so the
variance is scaled by n / n_eff, the effective sample count from the residuals'
autocorrelation (``signals.effective_samples``). The search box is a weak
prior (each coordinate within it, its width four standard deviations): a
direction the data do not constrain gets an interval as wide as the box, not an
infinite one, so a short log still says how far each parameter may be off. The
physical parameters' intervals follow by the delta method through the map from
theta to the model in mm and deg (az = 1 fixes the scale, so az has none).

A parameter counts as determined when its 95 % interval is narrower than its
own size (half-width below |value|), and, for the search coordinates, than a
tenth of the search box; otherwise the result names it. Step 10 of ``identify``
(``uncertainty``) computes them at the optimum.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from warpbridge.model.boucwen import BoucWenParams
from warpbridge.model.effects import delayed
from warpbridge.model.identification.data import LogData
from warpbridge.model.identification.excitation import Excitation
from warpbridge.model.identification.path import POLISH_REVERSALS, FitPath, Objective, jacobian
from warpbridge.model.identification.refine import Candidate
from warpbridge.model.identification.space import THETA_NAMES, thetas_to_rows
from warpbridge.model.signals import effective_samples

log = logging.getLogger(__name__)

Z95 = 1.959963984540054
RCOND = 1e-6  # singular values of J below this share of the largest are directions the data do not constrain
PRIOR_BOX_SDS = 4.0  # the search box spans this many standard deviations of the weak prior it stands for
BOX_SHARE = 0.1  # a search coordinate whose 95 % half-width exceeds this share of its box is not determined
PARAM_NAMES = ("a1", "a2", "a3", "az", "A", "n", "b1", "b2", "b3", "b4", "b5", "b6")


@dataclass
class Interval:
    """One parameter's estimate, standard error and 95 % interval; ``determined`` as the module says."""

    value: float
    se: float
    lo: float
    hi: float
    determined: bool

    def to_dict(self) -> dict:
        def f(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None
        return {"value": f(self.value), "se": f(self.se), "lo": f(self.lo), "hi": f(self.hi),
                "determined": self.determined}


@dataclass
class Uncertainty:
    """Intervals of the physical parameters (``params``, keyed a1..b6) and of the search coordinates
    (``search``, keyed by ``space.THETA_NAMES``), the residual standard deviation (deg), the kept
    samples and their effective count, and the names the data do not determine."""

    params: dict[str, Interval]
    search: dict[str, Interval]
    residual_sd_deg: float
    samples: int
    effective_samples: float
    undetermined: list[str] = field(default_factory=list)
    fixed: dict[str, str] = field(default_factory=dict)
    level: float = 0.95

    def to_dict(self) -> dict:
        return {"level": self.level, "method": "gauss-newton curvature, residual variance scaled by n/n_eff",
                "residual_sd_deg": self.residual_sd_deg, "samples": self.samples,
                "effective_samples": self.effective_samples,
                "params": {k: v.to_dict() for k, v in self.params.items()},
                "search": {k: v.to_dict() for k, v in self.search.items()},
                "undetermined": list(self.undetermined), "fixed": dict(self.fixed)}


def theta_covariance(J: np.ndarray, r: np.ndarray, n_eff: float, prior_sd: np.ndarray | None = None) -> np.ndarray:
    """Covariance of theta from the Jacobian J (m x p) and residuals r at the optimum: s^2 (J^T J)^-1 with
    s^2 = r.r / (m - p), times m / n_eff; with ``prior_sd`` (one per coordinate) the prior's precision is
    added to the data's, (J^T J / s^2 + diag(prior_sd^-2))^-1; without it, inf on the diagonal along
    directions J does not constrain."""
    m, p = J.shape
    s2 = float(r @ r) / max(m - p, 1)
    scale = s2 * m / max(n_eff, 1.0)
    if not np.all(np.isfinite(J)):
        return np.full((p, p), np.inf)
    if prior_sd is not None and scale > 0:
        # the SVD of the stacked square roots, not the eigenvalues of the sum: the data's precision can
        # outweigh the prior's by more than the float's precision along the directions the data do pin down
        A = np.vstack([J / math.sqrt(scale), np.diag(1.0 / np.asarray(prior_sd, dtype=np.float64))])
        _, sv, Vt = np.linalg.svd(A, full_matrices=False)
        return (Vt.T / sv ** 2) @ Vt
    ev, V = np.linalg.eigh(J.T @ J)  # singular values of J squared: the normal matrix is p x p
    keep = ev > RCOND ** 2 * max(float(ev[-1]), 0.0)
    inv = np.where(keep, 1.0 / np.where(keep, ev, 1.0), 0.0)
    cov = (V * inv) @ V.T * scale
    if not keep.all():  # a coordinate that loads on an unconstrained direction has no finite variance
        loose = np.any(np.abs(V[:, ~keep]) > 1e-3, axis=1)
        cov[loose, :] = np.inf
        cov[:, loose] = np.inf
    return cov


def _interval(value: float, var: float, determined_if: float) -> Interval:
    se = math.sqrt(var) if var >= 0 and math.isfinite(var) else math.inf
    half = Z95 * se
    return Interval(value, se, value - half, value + half, bool(half < determined_if))


def intervals(theta: np.ndarray, names: tuple[str, ...], J: np.ndarray, r: np.ndarray, ws: float,
              lo: np.ndarray, hi: np.ndarray, to_physical: Callable[[np.ndarray], np.ndarray],
              fixed: dict[str, str] | None = None) -> Uncertainty:
    """The intervals of one fit: ``J`` and ``r`` the residuals' Jacobian and values at ``theta`` (normalised
    warp, whose unit is ``ws`` deg), [lo, hi] the search box and ``to_physical(theta)`` the 12 parameters
    a1..b6 in mm and deg."""
    m, p = J.shape
    n_eff = effective_samples(r)
    cov = theta_covariance(J, r, n_eff, (hi - lo) / PRIOR_BOX_SDS)
    search = {names[i]: _interval(float(theta[i]), float(cov[i, i]), BOX_SHARE * float(hi[i] - lo[i]))
              for i in range(p)}
    phys = to_physical(theta)
    G = np.empty((phys.size, p))
    for j in range(p):  # delta method: central differences of the map to physical parameters
        h = 1e-6 * max(1.0, abs(float(theta[j])))
        tp, tm = theta.copy(), theta.copy()
        tp[j] += h
        tm[j] -= h
        G[:, j] = (to_physical(tp) - to_physical(tm)) / (2.0 * h)
    with np.errstate(invalid="ignore"):
        finite = np.isfinite(np.diag(cov))
        cp = np.full((phys.size, phys.size), np.inf)
        Gf = G[:, finite]
        cp_f = Gf @ cov[np.ix_(finite, finite)] @ Gf.T
        loose = np.any(np.abs(G[:, ~finite]) > 1e-12, axis=1)
        var_phys = np.where(loose, np.inf, np.diag(cp_f))
    del cp
    fixed = dict(fixed or {})
    params = {}
    for i, name in enumerate(PARAM_NAMES):
        if name in fixed:
            params[name] = Interval(float(phys[i]), 0.0, float(phys[i]), float(phys[i]), True)
            continue
        params[name] = _interval(float(phys[i]), float(var_phys[i]), abs(float(phys[i])))
    undetermined = [k for k, v in params.items() if not v.determined]
    undetermined += [k for k, v in search.items() if not v.determined and k not in undetermined]  # n: in both
    sd = math.sqrt(float(r @ r) / max(m, 1)) * ws
    return Uncertainty(params, search, sd, int(m), float(n_eff), undetermined, fixed)


# ---- step 10: uncertainty ----------------------------------------------------------------------

def uncertainty(data: LogData, best: Candidate, exc: Excitation) -> Uncertainty | None:
    """Step 10: 95 % intervals of every parameter at the optimum (``intervals``), on the
    polish's path of the model's own input (its delay applied)."""
    x = delayed(data.t, data.x_hat, best.delay) if best.delay > 0 else data.x_hat
    obj = Objective(FitPath.build(x, data.w_hat, data.n_train_end, 2500, POLISH_REVERSALS), data.norm.c)
    lo, hi = data.bounds
    try:
        J, r = jacobian(obj, best.theta, lo, hi)
    except (ValueError, FloatingPointError):
        return None
    norm = data.norm

    def to_physical(theta: np.ndarray) -> np.ndarray:
        return norm.to_physical(BoucWenParams.from_array(thetas_to_rows(theta, norm.c)[0])).to_array()

    names = THETA_NAMES[:best.theta.size]
    fixed = {"az": "the model's scale is fixed by az = 1 (z in mm of tendon)"}
    if not data.two_sided:
        fixed_b = "with warp of one sign only four combinations of b1..b6 act; the two others (asinh_D, asinh_E) are 0"
        fixed["b"] = fixed_b
    try:
        out = intervals(best.theta, names, J, r, norm.ws, lo, hi, to_physical, fixed)
    except (ValueError, np.linalg.LinAlgError):
        return None
    for note in exc.notes:
        log.info("excitation: %s", note)
    return out
