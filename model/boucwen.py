"""The generalized Bouc-Wen tendon-sheath model: parameters, both maps, a stepper.

``inverse`` maps warp w (deg) to tendon travel u (mm), the paper's direction and
what the feed-forward needs. ``forward`` maps tendon travel to warp by exact
per-sample inversion of the same model; the two round-trip to numerical
precision. ``Stepper`` does either one sample at a time (for the controller)
with results identical to the whole-array functions.

The 12 parameters carry one redundancy: z -> c z, A -> c A,
b -> c^(1-n) b, az -> az / c leaves u unchanged. ``BoucWenParams.canonical``
fixes it by az = 1, which makes z the hysteretic part of the tendon travel in mm.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from warpbridge.model import _jit
from warpbridge.model import kernels as K

PAPER_B = (19.8351, -8.6135, 0.8325, -3.1266, 10.6984, -18.5)


@dataclass(frozen=True)
class BoucWenParams:
    """u = a1 w^2 + a2 w + a3 + az z,  dz/dw = A - |z|^n (b . phi).

    Units: w deg, u mm, a1 mm/deg^2, a2 mm/deg, a3 mm, az mm per unit z,
    A in z per deg, b in z^(1-n) per deg."""

    a1: float
    a2: float
    a3: float
    az: float
    A: float
    n: float
    b: tuple[float, float, float, float, float, float] = field(default=PAPER_B)

    def __post_init__(self) -> None:
        vals = [self.a1, self.a2, self.a3, self.az, self.A, self.n, *self.b]
        if len(self.b) != 6:
            raise ValueError("b must have 6 entries (b1..b6)")
        if not all(np.isfinite(v) for v in vals):
            raise ValueError("Bouc-Wen parameters must be finite")
        if self.n < 1.0:
            raise ValueError(f"exponent n must be >= 1 (got {self.n:g})")
        if self.az == 0.0:
            raise ValueError("az must be non-zero")
        object.__setattr__(self, "b", tuple(float(x) for x in self.b))

    @classmethod
    def paper(cls) -> BoucWenParams:
        """The parameters identified in Lee et al. (2017), eq. (2)."""
        return cls(a1=-0.0205, a2=0.7120, a3=0.7958, az=0.5369, A=3.9953, n=3.1179, b=PAPER_B)

    def scaled(self, c: float) -> BoucWenParams:
        """The same model with z -> c z (output unchanged)."""
        if not c > 0:
            raise ValueError("scale must be positive")
        f = c ** (1.0 - self.n)
        return BoucWenParams(
            a1=self.a1, a2=self.a2, a3=self.a3, az=self.az / c, A=self.A * c, n=self.n,
            b=tuple(f * x for x in self.b),
        )

    def canonical(self) -> BoucWenParams:
        """The representative with az = 1 (z in mm of tendon)."""
        return self.scaled(abs(self.az)) if self.az > 0 else self

    def to_array(self) -> np.ndarray:
        return np.array([self.a1, self.a2, self.a3, self.az, self.A, self.n, *self.b], dtype=np.float64)

    @classmethod
    def from_array(cls, p) -> BoucWenParams:
        p = [float(x) for x in p]
        if len(p) != K.N_PARAMS:
            raise ValueError(f"expected {K.N_PARAMS} parameters, got {len(p)}")
        return cls(a1=p[0], a2=p[1], a3=p[2], az=p[3], A=p[4], n=p[5], b=tuple(p[6:12]))

    def to_dict(self) -> dict:
        return {"a1": self.a1, "a2": self.a2, "a3": self.a3, "az": self.az, "A": self.A, "n": self.n,
                "b": list(self.b)}

    @classmethod
    def from_dict(cls, d: dict) -> BoucWenParams:
        try:
            return cls(a1=float(d["a1"]), a2=float(d["a2"]), a3=float(d["a3"]), az=float(d["az"]),
                       A=float(d["A"]), n=float(d["n"]), b=tuple(float(x) for x in d["b"]))
        except KeyError as e:
            raise ValueError(f"Bouc-Wen parameters lack {e.args[0]!r}") from None
        except (TypeError, ValueError) as e:
            raise ValueError(f"bad Bouc-Wen parameters: {e}") from None

    def z_saturation(self, w_sign: float = 1.0) -> tuple[float, float]:
        """Limits of z on a long monotone loading / unloading run at warp sign ``w_sign``."""
        p = self.to_array()
        hi = _saturation(p, +1.0, w_sign)
        lo = _saturation(p, -1.0, w_sign)
        return hi, lo


def _saturation(p: np.ndarray, sdw: float, sw: float) -> float:
    psi = K._psi(p, sdw, sw, sdw)  # z ends with the sign of the motion
    if psi <= 0:
        return float("inf") * sdw
    return sdw * (p[K.P_A] / psi) ** (1.0 / p[K.P_N])


def _as_array(x, name: str) -> np.ndarray:
    a = np.ascontiguousarray(x, dtype=np.float64)
    if a.ndim != 1:
        raise ValueError(f"{name} must be one-dimensional")
    return a


def inverse(params: BoucWenParams, w, z0: float = 0.0, w0: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Tendon travel u (mm) and state z along a warp trajectory w (deg).

    The model starts at rest at (w0, z0); w0 defaults to w[0]."""
    w = _as_array(w, "w")
    u = np.empty_like(w)
    z = np.empty_like(w)
    if w.size == 0:
        return u, z
    start = float(w[0]) if w0 is None else float(w0)
    if not np.isfinite(start):
        start = 0.0
    K.inverse_run(_jit.vector(params.to_array()), w, start, float(z0), u, z)
    return u, z


def forward(params: BoucWenParams, u, z0: float = 0.0, w0: float | None = None,
            ) -> tuple[np.ndarray, np.ndarray, int]:
    """Warp w (deg) and state z reached along a tendon trajectory u (mm).

    Starts at rest at (w0, z0); w0 defaults to the warp where the model gives
    u[0] from z0 on its loading branch. Returns (w, z, flagged) where flagged
    counts samples beyond the model's monotone range (held at its edge)."""
    u = _as_array(u, "u")
    w = np.empty_like(u)
    z = np.empty_like(u)
    if u.size == 0:
        return w, z, 0
    p = _jit.vector(params.to_array())
    start = rest_warp(params, float(u[0]), z0) if w0 is None else float(w0)
    flagged = K.forward_run(p, u, start, float(z0), w, z)
    return w, z, int(flagged)


def rest_warp(params: BoucWenParams, u0: float, z0: float = 0.0) -> float:
    """Warp at which the model with state z0 (held fixed) outputs u0."""
    a1, a2 = params.a1, params.a2
    c = params.a3 + params.az * z0 - u0
    if abs(a1) < 1e-15:
        return -c / a2
    disc = a2 * a2 - 4 * a1 * c
    if disc < 0:
        return -a2 / (2 * a1)
    r = np.sqrt(disc)
    # root on the rising branch (du/dw > 0)
    for w in ((-a2 + r) / (2 * a1), (-a2 - r) / (2 * a1)):
        if 2 * a1 * w + a2 > 0:
            return float(w)
    return float((-a2 + r) / (2 * a1))


class Stepper:
    """One-sample-at-a-time Bouc-Wen model with the same results as the array maps.

    ``inverse_step(w)`` returns the tendon travel for a new warp (feed-forward);
    ``forward_step(u)`` returns the warp for a new tendon travel (simulation)."""

    def __init__(self, params: BoucWenParams, w0: float = 0.0, z0: float = 0.0) -> None:
        self.set_params(params)
        self.w = float(w0)
        self.z = float(z0)

    def set_params(self, params: BoucWenParams) -> None:
        self.params = params
        self._p = _jit.vector(params.to_array())
        self._zn = -1.0  # |z|^n carried between forward steps, as the array map does (-1: not known)

    def reset(self, w0: float = 0.0, z0: float = 0.0) -> None:
        self.w = float(w0)
        self.z = float(z0)
        self._zn = -1.0

    @property
    def u(self) -> float:
        return float(K.output_u(self._p, self.w, self.z))

    def inverse_step(self, w: float) -> float:
        u, z = K.inverse_step(self._p, self.w, self.z, float(w))
        if np.isfinite(w) and np.isfinite(z) and np.isfinite(u):
            self.w, self.z, self._zn = float(w), float(z), -1.0
        return float(K.output_u(self._p, self.w, self.z))

    def forward_step(self, u: float) -> float:
        w, z, zn, _ = K.forward_step_zn(self._p, self.w, self.z, self._zn, float(u))
        self.w, self.z, self._zn = float(w), float(z), float(zn)
        return self.w
