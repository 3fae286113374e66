"""The search space of identification: normalised units and a parameter vector with the scale fixed.

Normalised units, w / Ws and (u - uc) / Us, make the search box the same for any
wing; the model's form is unchanged by this scaling (sgn(w) is kept). The
parameter vector theta fixes the model's scale redundancy (z -> c z, A -> c A,
b -> c^(1-n) b, az -> az / c) by az = 1 and describes the loop physically: the
saturation levels of z on loading and unloading, the return ratios after a
reversal, A and n, then the quadratic backbone around the data's middle. With
warp on one side of zero only four combinations of b are identifiable; two
more (D, E) are fitted when the log holds warp of both signs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from warpbridge.model import kernels as K
from warpbridge.model.boucwen import BoucWenParams
from warpbridge.model.signals import central_range

# parameter vector theta (normalised units):
#   0 n, 1 log10 A, 2 log10 zsat_load, 3 log10 zsat_unload, 4 asinh r_unload, 5 asinh r_load,
#   6-8 the quadratic alpha1 (w - c)^2 + alpha2 (w - c) + alpha3 around the data's middle c,
#   [9 asinh D, 10 asinh E  (two-sided warp only)]
THETA_NAMES = ("n", "log10_A", "log10_zsat_load", "log10_zsat_unload", "asinh_r_unload", "asinh_r_load",
               "alpha1", "alpha2", "alpha3", "asinh_D", "asinh_E")
# return ratios r = Psi(return quadrant) / Psi(saturating quadrant) < 1: after a reversal z must head for
# the other branch (r > 1 would push it away and the ODE would blow up)
BOUNDS_ONE_SIDED = [(1.0, 5.0), (-2.0, 2.5), (-2.5, 0.5), (-2.5, 0.5), (-8.0, 0.85), (-8.0, 0.85),
                    (-1.5, 1.5), (-0.5, 3.0), (-2.0, 2.0)]
BOUNDS_TWO_SIDED = BOUNDS_ONE_SIDED + [(-8.0, 8.0), (-8.0, 8.0)]


def backbone_vertex(thetas: np.ndarray, c: float) -> np.ndarray:
    """Normalised warp at which each search vector's backbone alpha1 (w - c)^2 + alpha2 (w - c) turns back
    (inf or nan for a straight one)."""
    th = np.atleast_2d(thetas)
    with np.errstate(divide="ignore", invalid="ignore"):
        return c - th[:, 7] / (2.0 * th[:, 6])


def fold_depth(thetas: np.ndarray, c: float, lo: float, hi: float) -> np.ndarray:
    """How deep inside [lo, hi] (normalised warp) each search vector's backbone folds: the distance of its
    vertex from the nearer end, as a share of the range; 0 when it does not fold inside."""
    v = backbone_vertex(thetas, c)
    with np.errstate(invalid="ignore"):
        d = np.minimum(v - lo, hi - v) / (hi - lo)
    return np.where(np.isfinite(d) & (d > 0), d, 0.0)


@dataclass(frozen=True)
class Normaliser:
    """w_hat = w / ws,  u_hat = (u - uc) / us; the quadratic is searched around c = w_mid / ws.

    ws is the warp's half-range (not its peak), so the search box fits one-sided
    warp far from zero as well as two-sided warp; sgn(w) is kept."""

    ws: float
    uc: float
    us: float
    c: float = 0.0

    @classmethod
    def from_data(cls, u: np.ndarray, w: np.ndarray) -> Normaliser:
        wlo, whi = central_range(w)
        ws = (whi - wlo) / 2.0
        lo, hi = central_range(u)
        us = (hi - lo) / 2.0
        if not ws > 0 or not us > 0:
            raise ValueError("the log's warp or tendon input does not vary")
        return cls(ws=ws, uc=float(np.median(u)), us=us, c=float(0.5 * (wlo + whi)) / ws)

    def to_physical(self, q: BoucWenParams) -> BoucWenParams:
        """Parameters of the normalised model expressed in mm and deg (az = 1 gauge)."""
        ws, uc, us = self.ws, self.uc, self.us
        n = q.n
        # u = us*u_hat + uc, w = ws*w_hat, z_mm = us*z_hat (with az_hat = 1)
        A = us * q.A / ws
        b = tuple(x * us ** (1.0 - n) / ws for x in q.b)
        return BoucWenParams(a1=us * q.a1 / ws ** 2, a2=us * q.a2 / ws, a3=us * q.a3 + uc,
                             az=q.az, A=A, n=n, b=b).canonical()

    def to_normalised(self, p: BoucWenParams) -> BoucWenParams:
        """Inverse of ``to_physical`` (returns the az = 1 representative)."""
        ws, uc, us = self.ws, self.uc, self.us
        p = p.canonical()
        n = p.n
        return BoucWenParams(a1=p.a1 * ws ** 2 / us, a2=p.a2 * ws / us, a3=(p.a3 - uc) / us, az=1.0,
                             A=p.A * ws / us, n=n, b=tuple(x * ws / us ** (1.0 - n) for x in p.b))


def thetas_to_rows(thetas: np.ndarray, c: float = 0.0) -> np.ndarray:
    """Normalised Bouc-Wen parameters (az = 1), one ``BoucWenParams.to_array()`` row per search vector;
    the quadratic in theta is alpha1 (w - c)^2 + alpha2 (w - c) + alpha3."""
    th = np.atleast_2d(np.asarray(thetas, dtype=np.float64))
    n = th[:, 0]
    A = 10.0 ** th[:, 1]
    with np.errstate(over="ignore"):
        p1 = A / (10.0 ** th[:, 2]) ** n
        p3 = A / (10.0 ** th[:, 3]) ** n
    p2 = np.sinh(th[:, 4]) * p1
    p4 = np.sinh(th[:, 5]) * p3
    d = np.sinh(th[:, 9]) * p1 if th.shape[1] > 9 else 0.0
    e = np.sinh(th[:, 10]) * p1 if th.shape[1] > 10 else 0.0
    s = (p1 - p2 - p3 + p4) / 4
    t = (p1 + p2 - p3 - p4) / 4
    al1, al2, al3 = th[:, 6], th[:, 7], th[:, 8]
    P = np.empty((th.shape[0], K.N_PARAMS))
    P[:, 0] = al1
    P[:, 1] = al2 - 2 * al1 * c
    P[:, 2] = al1 * c * c - al2 * c + al3
    P[:, 3] = 1.0
    P[:, 4] = A
    P[:, 5] = n
    P[:, 6] = (p1 - p2 + p3 - p4) / 4
    P[:, 7] = (s + d) / 2
    P[:, 8] = (t + e) / 2
    P[:, 9] = (s - d) / 2
    P[:, 10] = (t - e) / 2
    P[:, 11] = (p1 + p2 + p3 + p4) / 4
    return P


def theta_to_normalised(theta: np.ndarray, c: float = 0.0) -> BoucWenParams:
    """Normalised Bouc-Wen parameters (az = 1) from one search vector (see ``thetas_to_rows``)."""
    return BoucWenParams.from_array(thetas_to_rows(theta, c)[0])


def normalised_to_theta(q: BoucWenParams, two_sided: bool, c: float = 0.0) -> np.ndarray | None:
    """Search vector for normalised parameters, or None if they are outside the search's form
    (e.g. z does not saturate on loading)."""
    q = q.canonical()
    p = q.to_array()
    b1, b2, b3, b4, b5, b6 = q.b
    s, t = b2 + b4, b3 + b5
    p1 = b1 + s + t + b6
    p2 = -b1 - s + t + b6
    p3 = b1 - s - t + b6
    p4 = -b1 + s - t + b6
    if p1 <= 0 or p3 <= 0 or q.A <= 0:
        return None
    al1 = q.a1
    al2 = q.a2 + 2 * al1 * c
    al3 = q.a3 - al1 * c * c + al2 * c
    theta = [q.n, math.log10(q.A), math.log10((q.A / p1) ** (1 / q.n)), math.log10((q.A / p3) ** (1 / q.n)),
             math.asinh(p2 / p1), math.asinh(p4 / p3), al1, al2, al3]
    if two_sided:
        theta += [math.asinh((b2 - b4) / p1), math.asinh((b3 - b5) / p1)]
    del p
    return np.array(theta)
