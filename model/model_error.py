"""The model's own error on the bench, learned from the bench residual (the model-error model).

A nominal model identified on a bench log rarely fits the wing exactly: the
hysteresis of a real sheath is not quite Bouc-Wen, the servo and the sensor
have dynamics of their own, the link a latency. That misfit has structure,
and the structure repeats in the field. ``ErrorModel`` describes it as a
linear combination of features of where the hysteresis is::

    r = w_meas - w_model ~ Phi(t, x, w_model) theta

- level: Legendre polynomials P0..P3 of the model's warp, normalised to the
  bench range (clipped a little beyond it);
- branch: the direction of the tendon travel s = +-1 times P0..P2 (a loop of
  the wrong width or a branch of the wrong curvature);
- transition: s exp(-d / l) for four lengths l, d the travel since the last
  reversal (the shape of the turn after a reversal);
- rate: the model's warp rate and its product with the level (latency, servo
  and sensor dynamics the rate-independent model cannot express);
- memory: the turn measured against the previous leg, s exp(-(d / a) / l) for
  three l, and s a, s a^2, a the travel of the previous leg over the span
  (minor loops that the model closes differently from the wing);
- play: the normalised states q_r = (x - p_r) / r of play operators on the
  tendon travel, thresholds r from 1 % to 30 % of the span, alone and times
  the level P1 (a Prandtl-Ishlinskii correction: the memory of friction spread
  along a sheath, which one Bouc-Wen state cannot hold, wipes out like a
  stack of plays);
- lag: the model's warp through first-order lags of 10, 30 and 100 ms, less
  the warp itself, over the time constant (a low-order linear dynamic model
  of the servo, link and sensor the bench shares with the field: the rate
  set is only its first-order Taylor term, and a latency of tens of ms over
  a fast bench input needs more).

What the rate and lag terms take from the sample times alone (each lag's
step factors, the rate's smoothing width, ``np.gradient``'s weights) is kept
per log (``TimeTerms``), and the plays and the lags each run in one compiled
pass, row by row: a diagnosis evaluates the correction on thousands of paths
of one log, and the results are bit for bit those of the plain operators.

Nested feature sets and a ridge penalty are chosen by blocked cross-validation
on the bench log, so noise is not learned as structure; the cross-validated
RMS after the correction is what the model is still known to get wrong.
``diagnose`` adds the correction to the model's core output, so that an
effect is named by what changed between bench and field, not by what the
model never captured. The loop-shape terms (branch, transition, memory,
play) describe a misfit of the hysteresis band, so they follow the band the
core runs with. A friction change that scales the band by s
(``Effects.band_scale``) scales the loop self-similarly, z(u) -> s z(u / s)
(``model.effects.friction_core``): the turn after a reversal is s times as
tall and takes s times the travel. The loop-shape terms do the same: their
amplitude is scaled by s and their travel lengths (transition lengths, the
previous leg, the play thresholds, the reversal dead band) by s, as a wing
whose friction halves also halves the part of its loop the model got wrong,
over half the travel. The level, rate and lag terms (the backbone and the
dynamics) stay. Units: t s, x mm (tendon travel into the core), w deg.
No I/O.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field

import numpy as np

from warpbridge.model._jit import njit
from warpbridge.model.boucwen import forward
from warpbridge.model.effects import apply_input_effects, apply_output_effects, core_params, slack_step
from warpbridge.model.initial_state import estimate_z0
from warpbridge.model.signals import noise_floor, warmup_end

_CACHE_LOCK = threading.Lock()  # guards every ErrorModel's input-terms cache

FORMAT = "warpbridge-model-error/1"
FEATURE_SETS = ("level", "branch", "transition", "rate", "memory", "play", "lag")  # nested: each adds to the previous
TRANSITION_LENGTHS = (0.01, 0.03, 0.1, 0.3)  # of the tendon span
MEMORY_LENGTHS = (0.05, 0.2, 0.6)  # of the previous leg
PLAY_THRESHOLDS = (0.01, 0.03, 0.06, 0.1, 0.15, 0.22, 0.3)  # of the tendon span
LAG_TIMES_S = (0.01, 0.03, 0.1)
SET_COLUMNS = {"level": 4, "branch": 3, "transition": 4, "rate": 2, "memory": 5, "play": 2 * len(PLAY_THRESHOLDS),
               "lag": len(LAG_TIMES_S)}
DEADBAND = 0.005  # of the tendon span: smaller wiggles are not reversals
RIDGES = (1e-6, 1e-4, 1e-2, 1.0)  # penalty relative to the mean diagonal of the normal equations
FOLDS = 5
LEVEL_CLIP = 1.25
RATE_SMOOTH_S = 0.01


@njit(cache=True)
def travel_since_reversal(x, eps):
    """(direction +-1, travel since the last reversal, travel of the leg before it) per sample;
    reversals need ``eps`` of travel back."""
    n = x.shape[0]
    s = np.empty(n)
    d = np.empty(n)
    a = np.empty(n)
    direction = 1.0
    ext = x[0]
    rev = x[0]
    prev = 0.0
    started = False
    for k in range(n):
        v = x[k]
        if not started:
            if abs(v - x[0]) > eps:
                direction = 1.0 if v > x[0] else -1.0
                started = True
                ext = v
        elif direction > 0:
            if v > ext:
                ext = v
            elif ext - v > eps:
                prev = ext - rev
                direction, rev, ext = -1.0, ext, v
        else:
            if v < ext:
                ext = v
            elif v - ext > eps:
                prev = rev - ext
                direction, rev, ext = 1.0, ext, v
        s[k] = direction
        d[k] = abs(v - rev)
        a[k] = prev
    return s, d, a


def play_states(x: np.ndarray, thresholds: np.ndarray) -> np.ndarray:
    """Normalised play-operator states (x - p_r) / r in [-1, 1] per sample (rows) and threshold r (columns);
    each play (``model.effects.play`` of total width 2 r) starts relaxed at the first sample."""
    return _play_states(np.ascontiguousarray(x, dtype=np.float64),
                        np.ascontiguousarray(thresholds, dtype=np.float64))


@njit(cache=True)
def _play_states(x, thresholds):
    """``play_states`` in one compiled pass over the samples, every play stepped at each (row by row, the
    order the array is stored in); the same arithmetic as ``play(x, 2 r, x[0])`` per threshold."""
    n = x.shape[0]
    m = thresholds.shape[0]
    out = np.empty((n, m))
    if n == 0:
        return out
    ys = np.full(m, x[0])
    for k in range(n):
        xk = x[k]
        for j in range(m):
            r = thresholds[j]
            y = slack_step(xk, ys[j], 0.5 * (2.0 * r), 0.0, 0.0, 0.0)
            ys[j] = y
            out[k, j] = (xk - y) / r
    return out


def _plays(x: np.ndarray, x_span: float) -> np.ndarray:
    return play_states(x, np.asarray(PLAY_THRESHOLDS, dtype=np.float64) * x_span)


@dataclass(frozen=True)
class TimeTerms:
    """What the rate and lag terms take from the sample times alone (the same for every path of a log):
    each lag's step factors exp(-dt / tau), the rate's smoothing width (a median of the steps) and the
    steps and weights of ``np.gradient`` along the times."""

    lag_factors: np.ndarray  # (len(LAG_TIMES_S), n)
    smooth: int
    steps: np.ndarray  # (n - 1,) np.diff(t)
    grad_weights: np.ndarray  # (3, n - 2) np.gradient's weights of w[k - 1], w[k], w[k + 1] at uneven steps
    uniform: bool  # every step the same: np.gradient's uniform branch


@njit(cache=True)
def _lag_factors(t, taus):
    """exp(-dt / tau) per lag and sample, dt from the sample before (0 at the first): ``lagged``'s factors."""
    n = t.shape[0]
    out = np.empty((taus.shape[0], n))
    for j in range(taus.shape[0]):
        tau = taus[j]
        tp = t[0] if n else 0.0
        for k in range(n):
            dt = t[k] - tp
            out[j, k] = math.exp(-dt / tau) if tau > 0 else 0.0
            tp = t[k]
    return out


@njit(cache=True)
def _lag_columns(w, factors, denom):
    """(lag_tau(w) - w) / denom per sample and lag, each lag ``lagged`` with the given factors from w[0]."""
    n = w.shape[0]
    m = factors.shape[0]
    out = np.empty((n, m))
    if n == 0:
        return out
    ys = np.full(m, w[0])
    for k in range(n):  # row by row, the order the array is stored in
        for j in range(m):
            a = factors[j, k]
            y = a * ys[j] + (1.0 - a) * w[k]
            ys[j] = y
            out[k, j] = (y - w[k]) / denom[j]
    return out


@njit(cache=True)
def _gradient_weights(steps):
    """``np.gradient``'s weights of f[k - 1], f[k], f[k + 1] at each inner sample for uneven steps (its
    second-order central difference, the same operations)."""
    n = max(steps.shape[0] - 1, 0)
    out = np.empty((3, n))
    for k in range(n):
        dx1 = steps[k]
        dx2 = steps[k + 1]
        out[0, k] = -(dx2) / (dx1 * (dx1 + dx2))
        out[1, k] = (dx2 - dx1) / (dx1 * dx2)
        out[2, k] = dx1 / (dx2 * (dx1 + dx2))
    return out


@njit(cache=True)
def _gradient(f, steps, weights, uniform):
    """``np.gradient(f, t)`` (first-order at the ends) from t's steps and ``_gradient_weights``, bit for bit."""
    n = f.shape[0]
    out = np.empty(n)
    if uniform:
        h2 = 2.0 * steps[0]
        for k in range(1, n - 1):
            out[k] = (f[k + 1] - f[k - 1]) / h2
    else:
        for k in range(1, n - 1):
            out[k] = weights[0, k - 1] * f[k - 1] + weights[1, k - 1] * f[k] + weights[2, k - 1] * f[k + 1]
    out[0] = (f[1] - f[0]) / steps[0]
    out[n - 1] = (f[n - 1] - f[n - 2]) / steps[n - 2]
    return out


def time_terms(t: np.ndarray) -> TimeTerms:
    """``TimeTerms`` of the sample times t (s)."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    factors = _lag_factors(t, np.asarray(LAG_TIMES_S, dtype=np.float64))
    steps = np.diff(t)
    dt = float(np.median(steps)) if t.size > 1 else 1.0
    return TimeTerms(factors, max(1, int(round(RATE_SMOOTH_S / max(dt, 1e-9)))), steps,
                     _gradient_weights(steps), bool(steps.size and np.all(steps == steps[0])))


def lag_states(t: np.ndarray, w: np.ndarray, rate_scale: float, terms: TimeTerms | None = None) -> np.ndarray:
    """(lag_tau(w) - w) / (rate_scale tau) per sample (rows) and time constant tau of ``LAG_TIMES_S`` (columns);
    each lag starts settled on the first sample (about -w' / rate_scale for slow motion). ``terms``: the
    times' ``TimeTerms`` when already known."""
    tt = terms if terms is not None else time_terms(t)
    if tt.lag_factors.shape[1] != np.size(w):
        raise ValueError(f"{np.size(w)} warp samples for {tt.lag_factors.shape[1]} sample times")
    denom = np.array([rate_scale * tau for tau in LAG_TIMES_S])
    return _lag_columns(np.ascontiguousarray(w, dtype=np.float64), tt.lag_factors, denom)


@njit(cache=True)
def _travel_terms(x, x_span, trans_l, mem_l):
    """What the correction takes from the input alone, per sample: direction, the transition terms
    exp(-d / (l x_span)), the memory terms exp(-rel / l) and the previous leg's share of the span."""
    n = x.shape[0]
    eps = DEADBAND * x_span
    dirs, dists, prevs = travel_since_reversal(x, eps)
    et = np.empty((n, trans_l.shape[0]))
    em = np.empty((n, mem_l.shape[0]))
    legs = np.empty(n)
    for k in range(n):
        d = dists[k]
        prev = prevs[k]
        for i in range(trans_l.shape[0]):
            et[k, i] = math.exp(-d / (trans_l[i] * x_span))
        legs[k] = min(prev / x_span, 1.0)
        rel = min(d / max(prev, eps), 2.0)
        for i in range(mem_l.shape[0]):
            em[k, i] = math.exp(-rel / mem_l[i])
    return dirs, et, em, legs


@njit(cache=True)
def _correction(w, v, q, g, theta, w_center, w_scale, nsets, dirs, et, em, legs, band):
    n = w.shape[0]
    out = np.empty(n)
    for k in range(n):
        s = dirs[k] * band  # the loop-shape terms (branch, transition, memory, play) scale with the band
        h = (w[k] - w_center) / w_scale
        h = min(max(h, -LEVEL_CLIP), LEVEL_CLIP)
        p1 = h
        p2 = 1.5 * h * h - 0.5
        p3 = 2.5 * h * h * h - 1.5 * h
        acc = theta[0] + theta[1] * p1 + theta[2] * p2 + theta[3] * p3
        j = 4
        if nsets >= 2:
            acc += s * (theta[j] + theta[j + 1] * p1 + theta[j + 2] * p2)
            j += 3
        if nsets >= 3:
            for i in range(et.shape[1]):
                acc += theta[j] * s * et[k, i]
                j += 1
        if nsets >= 4:
            acc += theta[j] * v[k] + theta[j + 1] * v[k] * p1
            j += 2
        if nsets >= 5:
            leg = legs[k]
            for i in range(em.shape[1]):
                acc += theta[j] * s * em[k, i]
                j += 1
            acc += theta[j] * s * leg + theta[j + 1] * s * leg * leg
            j += 2
        if nsets >= 6:
            for i in range(q.shape[1]):
                acc += band * (theta[j] * q[k, i] + theta[j + 1] * q[k, i] * h)
                j += 2
        if nsets >= 7:
            for i in range(g.shape[1]):
                acc += theta[j] * g[k, i]
                j += 1
        out[k] = acc
    return out


def _smooth_rate(t: np.ndarray, w: np.ndarray, terms: TimeTerms | None = None) -> np.ndarray:
    """dw/dt (``np.gradient``, bit for bit) smoothed over ``RATE_SMOOTH_S``."""
    tt = terms if terms is not None else time_terms(t)
    if tt.lag_factors.shape[1] != np.size(w):
        raise ValueError(f"{np.size(w)} warp samples for {tt.lag_factors.shape[1]} sample times")
    w = np.ascontiguousarray(w, dtype=np.float64)
    r = _gradient(w, tt.steps, tt.grad_weights, tt.uniform) if w.size > 2 else np.zeros_like(w)
    k = tt.smooth
    if k > 1:
        r = np.convolve(r, np.ones(k) / k, mode="same")
    return r


def input_terms(x: np.ndarray, x_span: float, plays: bool) -> tuple:
    """What the correction takes from the input x alone: ``_travel_terms`` and, when the model has the play
    set, the play states (else an empty column block)."""
    terms = _travel_terms(x, x_span, np.array(TRANSITION_LENGTHS), np.array(MEMORY_LENGTHS))
    return terms + (_plays(x, x_span) if plays else np.zeros((x.size, 0)),)


@dataclass
class ErrorModel:
    """A fitted model-error model: feature normalisation, chosen feature sets, coefficients and what it
    measured on the bench (RMS in deg: cross-validated before and after the correction, noise)."""

    w_center: float
    w_scale: float
    x_span: float
    rate_scale: float
    sets: tuple[str, ...]
    theta: np.ndarray
    ridge: float = 0.0
    rms_before_deg: float = math.nan
    rms_after_deg: float = math.nan
    noise_deg: float = math.nan
    samples: int = 0
    extra: dict = field(default_factory=dict)
    _input_cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)
    _band_cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)
    _time_cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def known_error_deg(self) -> float:
        """What the corrected model still gets wrong beyond noise on the bench (cross-validated)."""
        if not (math.isfinite(self.rms_after_deg) and math.isfinite(self.noise_deg)):
            return math.nan
        return math.sqrt(max(self.rms_after_deg ** 2 - self.noise_deg ** 2, 0.0))

    def features(self, t, x, w) -> np.ndarray:
        return design(t, x, w, self.w_center, self.w_scale, self.x_span, self.rate_scale, self.sets)

    def correction(self, t, x, w, band: float = 1.0) -> np.ndarray:
        """Warp (deg) to add to the model's core output along input x and model warp w (one compiled pass,
        the same as ``features(t, x, w) @ theta`` at band 1). ``band`` is the scale of the hysteresis band
        the core runs with (``Effects.band_scale``): the loop-shape columns are taken ``band`` times as
        large, along a travel scale ``band`` times as long (the module docstring)."""
        if not (band > 0 and math.isfinite(band)):
            raise ValueError(f"band scale must be positive and finite, got {band}")
        w = np.ascontiguousarray(w, dtype=np.float64)
        if self.theta.size == 0:
            return np.zeros(w.size)
        nsets = len(self.sets)
        t = np.ascontiguousarray(t, dtype=np.float64)
        tt = self._time_terms(t) if nsets >= 4 else None
        v = _smooth_rate(t, w, tt) / self.rate_scale if nsets >= 4 else np.zeros(w.size)
        dirs, et, em, legs, q = self._input_terms(np.ascontiguousarray(x, dtype=np.float64), band)
        g = lag_states(t, w, self.rate_scale, tt) if nsets >= 7 else np.zeros((w.size, 0))
        return _correction(w, v, q, g, self.theta, self.w_center, self.w_scale, nsets, dirs, et, em, legs, band)

    def _input_terms(self, x: np.ndarray, band: float = 1.0) -> tuple:
        """``input_terms`` of x for this model's sets with the travel scale stretched by the band (a friction
        change scales the loop self-similarly: the turn after a reversal takes ``band`` times the travel).
        Those on the bench's travel scale (band 1) are kept for the last few paths: a fit that moves only the
        core runs the same x thousands of times. Those at another band are kept apart, for the last two: a
        friction fit tries a new band at nearly every run (kept with the others, those would push the reused
        paths out), but a fit that holds a band while it moves the rest asks for the same terms again."""
        pool, size = (self._input_cache, 4) if band == 1.0 else (self._band_cache, 2)
        key = (hash(x.tobytes()), band)
        with _CACHE_LOCK:  # diagnose's candidate fits may share this model from several threads
            hit = pool.get(key)
        if hit is not None and np.array_equal(hit[0], x):
            return hit[1]
        terms = input_terms(x, self.x_span * band, plays=len(self.sets) >= 6)
        with _CACHE_LOCK:
            if len(pool) >= size:
                pool.pop(next(iter(pool)))
            pool[key] = (x.copy(), terms)
        return terms

    def _time_terms(self, t: np.ndarray) -> TimeTerms:
        """``time_terms`` of t, kept for the last sample times seen (every path of a log shares them)."""
        with _CACHE_LOCK:
            hit = self._time_cache.get("t")
        if hit is not None and np.array_equal(hit[0], t):  # a copy: the caller's array may change later
            return hit[1]
        terms = time_terms(t)
        with _CACHE_LOCK:
            self._time_cache["t"] = (t.copy(), terms)
        return terms

    def corrected(self, t, x, w, band: float = 1.0) -> np.ndarray:
        """The model's warp w plus its correction (w unchanged where the model left its range: NaN stays NaN)."""
        if not np.all(np.isfinite(w)):
            return w
        return w + self.correction(t, x, w, band)

    def to_dict(self) -> dict:
        return {"format": FORMAT, "w_center": self.w_center, "w_scale": self.w_scale, "x_span": self.x_span,
                "rate_scale": self.rate_scale, "sets": list(self.sets), "theta": [float(v) for v in self.theta],
                "ridge": self.ridge, "bench_rms_before_deg": _num(self.rms_before_deg),
                "bench_rms_after_deg": _num(self.rms_after_deg), "noise_deg": _num(self.noise_deg),
                "samples": self.samples, **self.extra}

    @classmethod
    def from_dict(cls, d) -> ErrorModel:
        if not isinstance(d, dict):
            raise ValueError("model_error must be an object")
        if d.get("format") != FORMAT:
            raise ValueError(f"unsupported model_error format {d.get('format')!r} (this warpbridge reads {FORMAT!r})")
        try:
            sets = tuple(str(s) for s in d["sets"])
            bad = [s for s in sets if s not in FEATURE_SETS]
            if bad or list(sets) != list(FEATURE_SETS[:len(sets)]):
                raise ValueError(f"model_error feature sets must be a prefix of {', '.join(FEATURE_SETS)}")
            theta = np.asarray([float(v) for v in d["theta"]], dtype=np.float64)
            if theta.size != sum(SET_COLUMNS[s] for s in sets):
                raise ValueError("model_error theta does not match its feature sets")
            scales = [float(d[k]) for k in ("w_scale", "x_span", "rate_scale")]
            if not all(math.isfinite(v) and v > 0 for v in scales) or not np.all(np.isfinite(theta)):
                raise ValueError("model_error scales must be positive and its coefficients finite")
            known = {"format", "w_center", "w_scale", "x_span", "rate_scale", "sets", "theta", "ridge",
                     "bench_rms_before_deg", "bench_rms_after_deg", "noise_deg", "samples"}
            return cls(w_center=float(d["w_center"]), w_scale=scales[0], x_span=scales[1], rate_scale=scales[2],
                       sets=sets, theta=theta, ridge=float(d.get("ridge", 0.0)),
                       rms_before_deg=_opt(d.get("bench_rms_before_deg")),
                       rms_after_deg=_opt(d.get("bench_rms_after_deg")), noise_deg=_opt(d.get("noise_deg")),
                       samples=int(d.get("samples", 0)), extra={k: v for k, v in d.items() if k not in known})
        except KeyError as e:
            raise ValueError(f"model_error lacks {e.args[0]!r}") from None
        except (TypeError, ValueError) as e:
            if "model_error" in str(e):
                raise
            raise ValueError(f"bad model_error: {e}") from None


def _num(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def _opt(v) -> float:
    return math.nan if v is None else float(v)


def design(t, x, w, w_center: float, w_scale: float, x_span: float, rate_scale: float,
           sets: tuple[str, ...]) -> np.ndarray:
    """Feature matrix (n x columns of ``sets``) along input x (mm) and model warp w (deg) at times t (s)."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    x = np.ascontiguousarray(x, dtype=np.float64)
    w = np.ascontiguousarray(w, dtype=np.float64)
    h = np.clip((w - w_center) / w_scale, -LEVEL_CLIP, LEVEL_CLIP)
    p1, p2, p3 = h, 1.5 * h * h - 0.5, 2.5 * h ** 3 - 1.5 * h
    cols: list[np.ndarray] = []
    s, d, a = travel_since_reversal(x, DEADBAND * x_span) if len(sets) > 1 else (None, None, None)
    for name in sets:
        if name == "level":
            cols += [np.ones_like(h), p1, p2, p3]
        elif name == "branch":
            cols += [s, s * p1, s * p2]
        elif name == "transition":
            cols += [s * np.exp(-d / (lam * x_span)) for lam in TRANSITION_LENGTHS]
        elif name == "rate":
            v = _smooth_rate(t, w) / rate_scale
            cols += [v, v * p1]
        elif name == "memory":
            leg = np.minimum(a / x_span, 1.0)
            rel = np.minimum(d / np.maximum(a, DEADBAND * x_span), 2.0)
            cols += [s * np.exp(-rel / lam) for lam in MEMORY_LENGTHS] + [s * leg, s * leg * leg]
        elif name == "play":
            q = _plays(x, x_span)
            for i in range(q.shape[1]):
                cols += [q[:, i], q[:, i] * h]
        elif name == "lag":
            g = lag_states(t, w, rate_scale)
            cols += [g[:, i] for i in range(g.shape[1])]
    if not cols:
        return np.zeros((t.size, 0))
    return np.column_stack(cols)


def _ridge_solve(A: np.ndarray, y: np.ndarray, ridge: float) -> np.ndarray:
    G = A.T @ A
    scale = float(np.trace(G)) / max(G.shape[0], 1)
    G = G + ridge * max(scale, 1e-300) * np.eye(G.shape[0])
    try:
        return np.linalg.solve(G, A.T @ y)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(A, y, rcond=None)[0]


def fit_error_model(t, x, w_model, w_meas, noise: float, start: int = 0,
                    sets: tuple[str, ...] = FEATURE_SETS) -> ErrorModel:
    """Learn the model-error model from a bench log: residual w_meas - w_model along input x.

    Samples before ``start`` (the warm-up, where the initial state is uncertain) are not used. The feature
    sets (nested prefixes of ``sets``, itself a prefix of ``FEATURE_SETS``) and the ridge penalty minimise
    the error on ``FOLDS`` contiguous held-out folds; the empty model (no correction) competes too."""
    if tuple(sets) != FEATURE_SETS[:len(sets)]:
        raise ValueError(f"feature sets must be a prefix of {', '.join(FEATURE_SETS)}")
    t = np.ascontiguousarray(t, dtype=np.float64)
    x = np.ascontiguousarray(x, dtype=np.float64)
    w_model = np.ascontiguousarray(w_model, dtype=np.float64)
    r = np.ascontiguousarray(w_meas, dtype=np.float64) - w_model
    n = t.size
    use = np.zeros(n, bool)
    use[start:] = True
    use &= np.isfinite(r) & np.isfinite(w_model)
    wl, wh = np.percentile(w_model[use], [1, 99]) if use.any() else (0.0, 1.0)
    w_center, w_scale = 0.5 * (wl + wh), max(0.5 * (wh - wl), 1e-6)
    xl, xh = np.percentile(x[use], [0.5, 99.5]) if use.any() else (0.0, 1.0)
    x_span = max(float(xh - xl), 1e-9)
    rate = _smooth_rate(t, w_model)
    rate_scale = max(float(np.sqrt(np.mean(rate[use] ** 2))) if use.any() else 1.0, 1e-9)
    full = design(t, x, w_model, w_center, w_scale, x_span, rate_scale, tuple(sets))
    idx = np.flatnonzero(use)
    folds = np.array_split(idx, FOLDS)
    before = float(np.mean(r[idx] ** 2)) if idx.size else math.nan
    best = ((), 0.0, before)  # (sets, ridge, cv mse)
    for k in range(1, len(sets) + 1):
        ncol = sum(SET_COLUMNS[s] for s in FEATURE_SETS[:k])
        if idx.size < 20 * ncol:
            break  # too few samples for this many columns (and the larger sets after it)
        A = full[:, :ncol]
        for ridge in RIDGES:
            sse = 0.0
            for f in folds:
                train = np.setdiff1d(idx, _guarded(f, n, t))
                th = _ridge_solve(A[train], r[train], ridge)
                e = r[f] - A[f] @ th
                sse += float(np.dot(e, e))
            cv = sse / idx.size
            if cv < best[2]:
                best = (FEATURE_SETS[:k], ridge, cv)
    sets, ridge, cv = best
    ncol = sum(SET_COLUMNS[s] for s in sets)
    theta = _ridge_solve(full[idx, :ncol], r[idx], ridge) if ncol else np.zeros(0)
    return ErrorModel(w_center=float(w_center), w_scale=float(w_scale), x_span=x_span, rate_scale=rate_scale,
                      sets=tuple(sets), theta=np.asarray(theta, dtype=np.float64), ridge=float(ridge),
                      rms_before_deg=math.sqrt(before) if math.isfinite(before) else math.nan,
                      rms_after_deg=math.sqrt(cv) if math.isfinite(cv) else math.nan,
                      noise_deg=float(noise), samples=int(idx.size))


def _guarded(fold: np.ndarray, n: int, t: np.ndarray, guard_s: float = 0.5) -> np.ndarray:
    """A fold's samples plus a guard band on either side (left out of training: the residual is correlated)."""
    if fold.size == 0:
        return fold
    lo = int(np.searchsorted(t, t[fold[0]] - guard_s))
    hi = int(np.searchsorted(t, t[fold[-1]] + guard_s, side="right"))
    return np.arange(lo, min(hi, n))


def bench_error_model(params, effects, t, u, w, sent=None) -> ErrorModel:
    """The model-error model of a nominal model (Bouc-Wen ``params`` with ``effects``) on its bench log.

    The model is free-run on the logged input from the initial state its opening stretch gives; samples up
    to the first reversal (capped at a tenth of the log) are left out, as in identification. ``sent``: when
    each command reached the servo, s after its row (``effects.servo_travel``)."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    u = np.ascontiguousarray(u, dtype=np.float64)
    w = np.ascontiguousarray(w, dtype=np.float64)
    p = core_params(params, effects)
    x = apply_input_effects(effects, t, u, sent=sent)
    z0 = estimate_z0(p, x, w)
    w_core = forward(p, x, z0=z0)[0]
    _, w_pred = apply_output_effects(effects, t, w_core)
    # fitted on the core's trajectory: the correction is added there, before any output effect
    return fit_error_model(t, x, w_core, w_meas=w - (w_pred - w_core), noise=noise_floor(w),
                           start=warmup_end(u))

