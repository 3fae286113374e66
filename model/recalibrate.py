"""Pre-flight re-identification of what rigging changes: pre-tension offset and gain, hysteresis width.

Each time the wing is unfolded and rigged the tendon's pre-tension differs
(Lee et al. 2017, sec. 6), so the bench model's loop shifts in input and scales.
That change is three numbers on top of the bench (base) model: the pre-tension
``offset`` (mm) and ``gain`` of the command-side rigging (u_eff = gain (u - offset),
``model.effects.fold_rigging``) and
a hysteresis width scale (``az_scale``: the band of z scaled, the ``friction`` effect). They fold
exactly into Bouc-Wen parameters (``model.adapt.fold_pretension``), so the
controller needs nothing new to use them.

``excitation`` is the warp setpoint a calibration flies (on the ground, in
feed-forward only, within a safe range): a slow sweep over the whole range,
which wipes the hysteresis memory, then a low-passed random signal.
``refit`` fits the three numbers (plus the servo's lag, a nuisance parameter)
by forward output error with bounded least squares on the first part and
scores both the new and the old model on the held-out last part; ``accept``
is the acceptance rule. ``refit_full`` re-identifies the whole model
(``model.identification``) on the same data, judged by the same rule.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from warpbridge.model import excitation as X
from warpbridge.model.adapt import fold_pretension
from warpbridge.model.boucwen import BoucWenParams, forward
from warpbridge.model.effects import servo_follow
from warpbridge.model.identification import identify
from warpbridge.model.signals import noise_floor
from warpbridge.model.transform import Transform

SWEEP_S = 4.0  # the opening sweep: up to the top of the range, down to the bottom
WARMUP_S = 2.0  # not scored: the model's state is unknown until the sweep has wiped it
NO_CHANGE = Transform()  # the base model as it is


@dataclass(frozen=True)
class FitBounds:
    """What a calibration may find; a fit at a bound is refused."""

    max_offset_mm: float = 3.0
    gain: tuple[float, float] = (0.6, 1.6)
    az_scale: tuple[float, float] = (0.3, 3.0)
    lag_s: tuple[float, float] = (0.0, 0.15)


@dataclass(frozen=True)
class AcceptRule:
    """A new model is applied only if, on the held-out part, it beats the old one by ``improve_frac``
    (and by at least ``min_gain_deg``) and its RMS is within ``noise_factor`` x noise floor + ``abs_deg``."""

    improve_frac: float = 0.10
    min_gain_deg: float = 0.02
    noise_factor: float = 3.0
    abs_deg: float = 0.15


def excitation(t: np.ndarray, lo_deg: float, hi_deg: float, *, start_deg: float | None = None,
               cutoff_hz: float = 0.5, seed: int = 0) -> np.ndarray:
    """Warp setpoint (deg) of a calibration at times ``t`` (s from its start), within [lo, hi].

    From ``start_deg`` (default: mid-range) a raised-cosine sweep to hi, down to lo
    (``SWEEP_S`` in all), then a low-passed random signal over the whole range, ending
    at the start warp."""
    if not hi_deg > lo_deg:
        raise ValueError("calibration range: hi must exceed lo")
    t = np.asarray(t, dtype=np.float64)
    mid, half = 0.5 * (lo_deg + hi_deg), 0.5 * (hi_deg - lo_deg)
    w0 = mid if start_deg is None else float(np.clip(start_deg, lo_deg, hi_deg))
    out = np.empty_like(t)
    q = SWEEP_S / 4.0
    a = t < q
    s = 0.5 - 0.5 * np.cos(np.pi * np.clip(t / q, 0, 1))
    out[a] = (w0 + (hi_deg - w0) * s)[a]
    b = (t >= q) & (t < 3 * q)
    s = 0.5 - 0.5 * np.cos(np.pi * np.clip((t - q) / (2 * q), 0, 1))
    out[b] = (hi_deg + (lo_deg - hi_deg) * s)[b]
    c = t >= 3 * q
    if c.any():
        tr = t[c] - 3 * q
        r = X.filtered_random(tr, cutoff_hz=cutoff_hz, amplitude=0.95 * half, seed=seed)
        # join the sweep's end (lo) and the end state (w0) smoothly
        span = max(float(tr[-1]), 1e-9)
        ramp_in = 0.5 - 0.5 * np.cos(np.pi * np.clip(tr / q, 0, 1))
        ramp_out = 0.5 - 0.5 * np.cos(np.pi * np.clip((span - tr) / q, 0, 1))
        base = lo_deg + (w0 - lo_deg) * np.clip(tr / span, 0, 1)
        rnd = mid + r
        out[c] = base + ramp_in * ramp_out * (rnd - base)
    return np.clip(out, lo_deg, hi_deg)


@dataclass
class RefitResult:
    """A calibration's fit: the transform found, held-out RMS of the new and old model (deg)."""

    transform: Transform
    params: BoucWenParams  # the base folded with the transform (or the full re-identified model)
    lag_s: float
    train_rms: float
    heldout_rms: float
    old_heldout_rms: float
    noise: float
    n_train: int
    n_heldout: int
    full: bool = False
    accepted: bool = False
    reason: str = ""
    w_pred: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)

    def summary(self) -> dict:
        return {**self.transform.to_dict(), "lag_s": self.lag_s, "train_rms_deg": self.train_rms,
                "heldout_rms_deg": self.heldout_rms, "old_heldout_rms_deg": self.old_heldout_rms,
                "noise_deg": self.noise, "n_train": self.n_train, "n_heldout": self.n_heldout,
                "full": self.full, "accepted": self.accepted, "reason": self.reason}


def _split(t: np.ndarray, heldout_frac: float) -> tuple[np.ndarray, np.ndarray]:
    split = t[0] + (1.0 - heldout_frac) * (t[-1] - t[0])
    train = (t >= t[0] + WARMUP_S) & (t < split)
    held = t >= split
    return train, held


def predict(params: BoucWenParams, t: np.ndarray, u: np.ndarray, lag_s: float) -> np.ndarray:
    """Warp (deg) the model gives for command u through a first-order servo lag of ``lag_s``."""
    x = servo_follow(t, u, lag_s, math.inf, float(u[0])) if lag_s > 0 else u
    w, _, _ = forward(params, x)
    return w


def _rms(e: np.ndarray) -> float:
    e = e[np.isfinite(e)]
    return float(np.sqrt(np.mean(e * e))) if e.size else math.nan


def _check(t: np.ndarray, u: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t, u, w = (np.ascontiguousarray(a, dtype=np.float64) for a in (t, u, w))
    if not (t.shape == u.shape == w.shape) or t.size < 200:
        raise ValueError(f"calibration record too short ({t.size} samples, need 200)")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(u)) and np.all(np.isfinite(w))):
        raise ValueError("calibration record holds missing samples")
    if np.any(np.diff(t) <= 0):
        raise ValueError("calibration record: time must increase")
    if t[-1] - t[0] < 2 * SWEEP_S:
        raise ValueError("calibration record shorter than twice the opening sweep")
    return t, u, w


def refit(base: BoucWenParams, t, u, w, *, current: Transform = NO_CHANGE, heldout_frac: float = 0.3,
          fit_width: bool = True, bounds: FitBounds = FitBounds(), rule: AcceptRule = AcceptRule(),
          old: BoucWenParams | None = None) -> RefitResult:
    """Fit offset, gain (and hysteresis width) of the rigged wing relative to ``base``.

    ``t`` s, ``u`` the tendon commands sent (mm), ``w`` measured warp (deg). ``current`` is the
    transform in use (the start of the search); ``old`` the model flown now (default:
    ``current`` applied to ``base``), scored on the same held-out part. The result says
    whether ``accept`` passed it and why."""
    t, u, w = _check(t, u, w)
    train, held = _split(t, heldout_frac)
    old = old if old is not None else current.apply(base)
    lo = np.array([-bounds.max_offset_mm, bounds.gain[0], bounds.az_scale[0], bounds.lag_s[0]])
    hi = np.array([bounds.max_offset_mm, bounds.gain[1], bounds.az_scale[1], bounds.lag_s[1]])
    x0 = np.clip([current.offset, current.gain, current.az_scale if fit_width else 1.0, 0.02], lo, hi)
    free = np.array([True, True, fit_width, True])

    def full_x(xf: np.ndarray) -> np.ndarray:
        x = x0.copy()
        x[free] = xf
        return x

    def resid(xf: np.ndarray) -> np.ndarray:
        o, g, s, lag = full_x(xf)
        try:
            p = fold_pretension(base, o, g, s)
        except ValueError:
            return np.full(int(train.sum()), 1e3)
        e = predict(p, t, u, lag)[train] - w[train]
        e[~np.isfinite(e)] = 1e3
        return e

    eps = 1e-6
    sol = least_squares(resid, np.clip(x0[free], lo[free] + eps, hi[free] - eps), bounds=(lo[free], hi[free]),
                        x_scale=np.array([0.5, 0.1, 0.2, 0.02])[free], diff_step=1e-3, max_nfev=200)
    o, g, s, lag = full_x(sol.x)
    tf = Transform(float(o), float(g), float(s))
    params = tf.apply(base)
    w_new = predict(params, t, u, lag)
    w_old = predict(old, t, u, lag)
    res = RefitResult(transform=tf, params=params, lag_s=float(lag), train_rms=_rms(w_new[train] - w[train]),
                      heldout_rms=_rms(w_new[held] - w[held]), old_heldout_rms=_rms(w_old[held] - w[held]),
                      noise=noise_floor(w), n_train=int(train.sum()), n_heldout=int(held.sum()), w_pred=w_new)
    at_bound = [name for name, v, a, b in zip(("offset", "gain", "width"), (o, g, s), lo[:3], hi[:3], strict=True)
                if min(v - a, b - v) <= 1e-3 * max(1.0, abs(b - a))]
    res.accepted, res.reason = accept(res, rule, at_bound=at_bound)
    return res


def refit_full(base: BoucWenParams, t, u, w, *, lag_s: float = 0.02, heldout_frac: float = 0.3,
               rule: AcceptRule = AcceptRule(), old: BoucWenParams | None = None, seed: int = 0,
               progress=None, maxiter: int = 60) -> RefitResult:
    """Re-identify the whole Bouc-Wen model on the calibration (DE + Nelder-Mead), judged like ``refit``."""
    t, u, w = _check(t, u, w)
    train, held = _split(t, heldout_frac)
    old = old if old is not None else base
    x = servo_follow(t, u, lag_s, math.inf, float(u[0])) if lag_s > 0 else u
    n_fit = int(np.searchsorted(t, t[held][0])) if held.any() else t.size
    ident = identify(t[:n_fit], x[:n_fit], w[:n_fit], heldout_frac=0.2, seed=seed, maxiter=maxiter,
                     prior=base, max_delay_s=0.0, max_lag_s=0.0, progress=progress)  # the servo's lag is lag_s here
    p = ident.params
    w_new = predict(p, t, u, lag_s)
    w_old = predict(old, t, u, lag_s)
    res = RefitResult(transform=Transform(), params=p, lag_s=lag_s, train_rms=_rms(w_new[train] - w[train]),
                      heldout_rms=_rms(w_new[held] - w[held]), old_heldout_rms=_rms(w_old[held] - w[held]),
                      noise=noise_floor(w), n_train=int(train.sum()), n_heldout=int(held.sum()), full=True,
                      w_pred=w_new)
    res.accepted, res.reason = accept(res, rule)
    return res


def accept(res: RefitResult, rule: AcceptRule = AcceptRule(), *, at_bound: list[str] | None = None,
           ) -> tuple[bool, str]:
    """The held-out acceptance rule: (accepted, one-line reason fit for a STATUSTEXT)."""
    new, old, noise = res.heldout_rms, res.old_heldout_rms, res.noise
    if not math.isfinite(new) or res.n_heldout < 50:
        return False, "no usable held-out data"
    if at_bound:
        return False, f"fit at its bound ({', '.join(at_bound)}): rig or sensor problem?"
    limit = rule.noise_factor * (noise if math.isfinite(noise) else 0.0) + rule.abs_deg
    if new > limit:
        return False, f"held-out {new:.2f} deg above noise bound {limit:.2f}"
    if math.isfinite(old) and (new > (1.0 - rule.improve_frac) * old or old - new < rule.min_gain_deg):
        return False, f"old model still fits: held-out {new:.2f} vs old {old:.2f} deg"
    return True, f"held-out {new:.2f} deg (old {old:.2f}, bound {limit:.2f})"
