"""Unmodelled effects of a tendon-sheath wing, as small augmentations of the plant.

Each effect of the design brief's table is one operator with one or two
parameters, placed where it acts physically. The augmented plant is the chain::

    u_cmd -> delay -> servo_lag -> rate_limit -> slack (backlash + capstan stall) -> Bouc-Wen forward
          (pre-tension moves its backbone or the whole loop, friction scales the band of z) -> aero_load
          -> w_true
          -> sensor_lag -> drift -> w_meas

| name        | parameters                     | operator                                             |
|-------------|--------------------------------|------------------------------------------------------|
| delay       | delay_s                        | u(t - delay_s), linear interpolation                 |
| servo_lag   | servo_tau_s, servo_rate_mm_s,  | the servo's position loop: a first-order approach    |
|             | servo_deadband_mm              | capped at its rated speed to the edge of its dead    |
|             |                                | band, each row's command held                        |
| rate_limit  | rate_mm_s                      | slew-limited tendon travel                           |
| backlash    | backlash_mm                    | play operator of total width backlash_mm             |
| friction    | friction_scale, friction_pivot | the loop widens or narrows about a level inside it,  |
|             | capstan_pull_ratio, _release_  | or a stall at each reversal growing with the tension |
|             | ratio, capstan_zero_mm         |                                                      |
| pretension  | pretension_offset_mm, _gain    | backbone u = offset + (a1 w^2 + a2 w + a3) / gain,   |
|             | (pretension_loop: its form)    | or the whole loop, band az z included                |
| sensor_lag  | sensor_tau_s, _stage_ratio     | first-order lag of the warp measurement, or two in   |
|             |                                | cascade (the second ratio * tau)                     |
| drift       | drift_deg_s, drift_tau_s       | w_meas += drift_deg_s * tau (1 - exp(-(t - t0)/tau)) |
| aero_load   | aero_gain_per_kpa, aero_deg_per_kpa | w = w (1 - g q) - c q, q = rho V^2 / 2 in kPa   |

Friction scales the width of the hysteresis band as Coulomb friction in a
sheath does: the saturation levels of z scale by s (``b -> s^-n b``) while
its slope right after a reversal (``A``, the elastic stick stiffness) stays,
so a stronger friction needs proportionally more travel to break away. The
band is scaled about a level inside it that stays put: ``a3`` moves by
``az (1 - s) z_fix``, ``z_fix = z_mid + friction_pivot * z_half``, z_mid
halfway between the saturation levels of loading and unloading and z_half
half the distance between them. ``friction_pivot = 0`` (the default) keeps
the centre line (the elastic backbone) where it was; +-1 keeps the loading
or the unloading edge. A sheath's band does not always change symmetrically:
a Bouc-Wen band shrinks toward z = 0 rather than toward its middle, and a
capstan sheath's pull and release branches sit unequally about the
frictionless line, so a friction change that keeps the middle would leave an
offset that a pre-tension change would have to explain. A model-error
correction learned on the bench (``model.model_error``) scales its loop-shape
terms with the band too (``Effects.band_scale``), in height and in travel, as
the band itself scales: z(u) -> s z(u / s).

A sheath with capstan friction has a second form of a friction change: after
a reversal the far end stalls until the reversed slip has run along the whole
sheath, and the travel that takes grows in proportion to the tension. That is
a play (a dead band at every reversal) whose edges sit ``capstan_pull_ratio *
s`` below the travel while pulling and ``capstan_release_ratio * s`` above it
while releasing, s = max(x - capstan_zero_mm, 0), x the tendon travel and
``capstan_zero_mm`` the travel at which the tendon goes slack. By the capstan
law the two differ (the tension falls along the sheath one way when pulling and
the other way when releasing). Backlash is the same play with a fixed half-width
``backlash_mm / 2`` added to both edges. The diagnosis fits both forms of
``friction`` and keeps the one that explains the log better.

Pre-tension has two forms too. In the first it moves the elastic backbone and
nothing else: the rig's rest position shifts by ``offset`` in tendon travel and
its compliance scales by ``1 / gain`` (a stiffer or slacker rig), ``u = offset
+ (a1 w^2 + a2 w + a3) / gain + az z``; the friction band ``az z`` stays, as in
a rig whose friction does not depend on its tension. In a sheath it does: the
capstan law makes the friction force, so the travel it takes up, proportional
to the tension, and a rig pulled harder for the same warp (a stiffer wing) has
a band as much wider. The second form (``pretension_loop = 1``) scales the whole
loop, ``u = offset + (a1 w^2 + a2 w + a3 + az z) / gain``, the command-side
rigging ``fold_rigging`` that the online adapter and the pre-flight
recalibration estimate. Either way the offset and the gain are its two
parameters; the diagnosis fits both forms and keeps the one that explains the
log better.

The drift is a sensor zero warming up: it starts at ``drift_deg_s`` deg/s and
settles with time constant ``drift_tau_s``; ``drift_tau_s = inf`` (the default,
and what a file without the field means) is a steady ramp.

All operators are plain functions on arrays (compiled) plus a per-sample state
machine in ``model.plant`` that gives the same results.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from warpbridge.model._jit import njit
from warpbridge.model.effect_registry import EFFECT_FIELDS, FORM_FLAGS, added, added_field

RHO_AIR = 1.225  # kg/m^3, sea-level standard


@dataclass(frozen=True)
class Effects:
    """Magnitudes of every effect; the defaults are neutral (no effect)."""

    delay_s: float = 0.0
    servo_tau_s: float = 0.0  # the servo's position loop, a first-order lag (part of the rig, found by identify)
    servo_rate_mm_s: float = math.inf  # the servo's rated speed, capping that approach (mm/s of tendon)
    servo_deadband_mm: float = 0.0  # the servo's dead band: corrections within half of it are not made
    rate_mm_s: float = math.inf
    backlash_mm: float = 0.0
    friction_scale: float = 1.0
    capstan_pull_ratio: float = 0.0  # stall while pulling, per mm of tendon travel above capstan_zero_mm
    capstan_release_ratio: float = 0.0  # stall while releasing, per mm of the same travel
    capstan_zero_mm: float = 0.0  # tendon travel at which the tendon goes slack (meaningless at ratio 0)
    friction_pivot: float = 0.0  # the level of the band a friction scale keeps: 0 middle, +-1 its edges
    pretension_offset_mm: float = 0.0
    pretension_gain: float = 1.0
    pretension_loop: float = 0.0  # the form: 0 the backbone moves alone, 1 the whole loop (band included)
    sensor_tau_s: float = 0.0
    sensor_stage_ratio: float = 0.0  # a second lag in cascade, its time constant per sensor_tau_s (0: none)
    drift_deg_s: float = 0.0
    drift_tau_s: float = math.inf
    aero_gain_per_kpa: float = 0.0
    aero_deg_per_kpa: float = 0.0
    # the parameters of effects added at run time (``effect_registry.register``), those off neutral, by name;
    # read them as attributes like the others, set them with ``with_values``
    extra: tuple[tuple[str, float], ...] = ()

    def __post_init__(self) -> None:
        extra = {}
        for k, v in self.extra:
            par = added_field(k)
            if par is None:
                raise ValueError(f"unknown effect parameter {k!r}")
            if not isinstance(v, (int, float)) or math.isnan(v):
                raise ValueError(f"effect parameter {k} must be a number")
            if float(v) != par.neutral:
                extra[k] = float(v)
        object.__setattr__(self, "extra", tuple(sorted(extra.items())))
        for f in fields(self):
            if f.name == "extra":
                continue
            v = getattr(self, f.name)
            if not isinstance(v, (int, float)) or math.isnan(v):
                raise ValueError(f"effect parameter {f.name} must be a number")
            object.__setattr__(self, f.name, float(v))
        if (self.delay_s < 0 or self.backlash_mm < 0 or self.sensor_tau_s < 0 or self.servo_tau_s < 0
                or self.servo_deadband_mm < 0):
            raise ValueError("delay, servo lag, servo dead band, backlash and sensor lag cannot be negative")
        if not self.rate_mm_s > 0 or not self.servo_rate_mm_s > 0:
            raise ValueError("rate limit and servo speed must be positive")
        if not self.friction_scale > 0 or not self.pretension_gain > 0:
            raise ValueError("friction scale and pre-tension gain must be positive")
        if not self.drift_tau_s > 0:
            raise ValueError("drift time constant must be positive")
        if not (0.0 <= self.capstan_pull_ratio < 1.0 and 0.0 <= self.capstan_release_ratio < 1.0):
            raise ValueError("capstan ratios must be in [0, 1): the stall cannot outgrow the travel")
        if not math.isfinite(self.capstan_zero_mm):
            raise ValueError("capstan zero travel must be finite")
        if not self.has_capstan:  # where the tendon would go slack does not matter without a stall
            object.__setattr__(self, "capstan_zero_mm", 0.0)
        if not -1.0 <= self.friction_pivot <= 1.0:
            raise ValueError("friction pivot must be in [-1, 1]: a level inside the hysteresis band")
        if self.friction_scale == 1.0:  # an unchanged band has no level to keep
            object.__setattr__(self, "friction_pivot", 0.0)
        if self.pretension_loop not in (0.0, 1.0):
            raise ValueError("pretension_loop is a form: 0 (the backbone alone) or 1 (the whole loop)")
        if not 0.0 <= self.sensor_stage_ratio <= 1.0:
            raise ValueError("sensor stage ratio must be in [0, 1]: the second lag is the shorter one")
        if self.sensor_tau_s == 0.0:  # no lag, no second stage
            object.__setattr__(self, "sensor_stage_ratio", 0.0)

    def __getattr__(self, name: str) -> float:
        """A parameter of an effect added at run time (its neutral value when it is not set)."""
        par = added_field(name) if not name.startswith("_") and name != "extra" else None
        if par is None:
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        return dict(self.extra).get(name, par.neutral)

    def with_values(self, **kw: float) -> Effects:
        """A copy with these parameters changed, an added effect's too (``dataclasses.replace`` takes only the
        built-in ones)."""
        added_kw = {k: kw.pop(k) for k in list(kw) if k not in BUILT_IN_FIELDS}
        if not added_kw:
            return replace(self, **kw)
        unknown = [k for k in added_kw if added_field(k) is None]
        if unknown:
            raise TypeError(f"unknown effect parameter(s) {', '.join(unknown)}")
        return replace(self, **kw, extra=tuple((dict(self.extra) | added_kw).items()))

    @property
    def added_core_key(self) -> tuple[float, ...]:
        """The values of the added effects' parameters the core run depends on (a cache key's part)."""
        return tuple(v for k, v in self.extra if added_field(k).in_core)

    @property
    def sensor_taus(self) -> tuple[float, ...]:
        """Time constants of the sensor's lags in cascade (empty: no lag)."""
        return tuple(tau for tau in (self.sensor_tau_s, self.sensor_tau_s * self.sensor_stage_ratio) if tau > 0)

    @property
    def has_servo(self) -> bool:
        """True when the command passes through the servo's position loop (a lag, a rated speed, a dead band)."""
        return self.servo_tau_s > 0 or math.isfinite(self.servo_rate_mm_s) or self.servo_deadband_mm > 0

    @property
    def has_capstan(self) -> bool:
        """True when friction is in its capstan form (a stall pulling, releasing or both)."""
        return self.capstan_pull_ratio > 0 or self.capstan_release_ratio > 0

    @property
    def band_scale(self) -> float:
        """How much the hysteresis band is scaled (friction's band form; 1 in its capstan form, which adds a
        stall at each reversal instead): the model-error correction's loop-shape terms scale with it."""
        return 1.0 if self.has_capstan else self.friction_scale

    @property
    def has_slack(self) -> bool:
        """True when the input passes through a play (backlash, capstan stall or both)."""
        return self.backlash_mm > 0 or self.has_capstan

    @property
    def slack_args(self) -> tuple[float, float, float, float]:
        """(fixed half-width, pull ratio, release ratio, zero travel) of the play, for ``slack_play``."""
        return 0.5 * self.backlash_mm, self.capstan_pull_ratio, self.capstan_release_ratio, self.capstan_zero_mm

    def active(self) -> list[str]:
        """Names of the effects whose parameters differ from neutral."""
        out = []
        for name, (names, neutral, _) in EFFECT_FIELDS.items():  # a form flag alone changes nothing
            if any(getattr(self, f) != v for f, v in zip(names, neutral, strict=True) if f not in FORM_FLAGS):
                out.append(name)
        return out

    def only(self, names) -> Effects:
        """A copy keeping just the named effects (others neutral)."""
        keep = set(names)
        kw = {}
        for name, (fnames, neutral, _) in EFFECT_FIELDS.items():
            if name not in keep:
                kw.update(dict(zip(fnames, neutral, strict=True)))
        return self.with_values(**kw)

    def merged(self, other: Effects) -> Effects:
        """``other``'s active effects on top of these."""
        kw = {}
        for name in other.active():
            for f in EFFECT_FIELDS[name][0]:
                kw[f] = getattr(other, f)
        return self.with_values(**kw)

    def to_dict(self) -> dict[str, dict[str, float]]:
        """{effect name: {parameter: value}} for the active effects; an infinite value (no limit, a steady
        ramp) and a form flag at its first form are left out, which reads back as the same."""
        return {name: {f: getattr(self, f) for f in EFFECT_FIELDS[name][0]
                       if math.isfinite(getattr(self, f)) and not (f in FORM_FLAGS and getattr(self, f) == 0.0)}
                for name in self.active()}

    @classmethod
    def from_dict(cls, d: dict) -> Effects:
        if not isinstance(d, dict):
            raise ValueError("effects must be an object of {name: {parameter: value}}")
        kw: dict[str, float] = {}
        for name, params in d.items():
            if name not in EFFECT_FIELDS:
                raise ValueError(f"unknown effect {name!r} (known: {', '.join(EFFECT_FIELDS)})")
            if not isinstance(params, dict):
                raise ValueError(f"effect {name!r} needs an object of parameters")
            for f, v in params.items():
                if f not in EFFECT_FIELDS[name][0]:
                    raise ValueError(f"effect {name!r} has no parameter {f!r}")
                if v is None and math.isinf(EFFECT_FIELDS[name][1][EFFECT_FIELDS[name][0].index(f)]):
                    continue  # null: no limit / a steady ramp
                try:
                    kw[f] = float(v)
                except (TypeError, ValueError):
                    raise ValueError(f"effect parameter {f!r} must be a number") from None
        return cls().with_values(**kw)


BUILT_IN_FIELDS = frozenset(f.name for f in fields(Effects) if f.name != "extra")
BAND_FIELDS = ("friction_scale", "friction_pivot")  # friction's first form: the band scaled about a level
CAPSTAN_FIELDS = ("capstan_pull_ratio", "capstan_release_ratio", "capstan_zero_mm")  # its second: the stall


def form_fields(name: str, eff: Effects) -> tuple[str, ...]:
    """The fields of effect ``name`` in the form ``eff`` uses: friction's capstan stall or its band scale;
    pre-tension's offset and gain, with its form flag when it moves the whole loop."""
    if name == "friction":
        return CAPSTAN_FIELDS if eff.has_capstan else BAND_FIELDS
    if name == "pretension" and not eff.pretension_loop:
        return tuple(f for f in EFFECT_FIELDS[name][0] if f not in FORM_FLAGS)
    return EFFECT_FIELDS[name][0]


def form_parameters(name: str, eff: Effects) -> int:
    """How many parameters effect ``name`` has in the form ``eff`` uses (its form flag is not one)."""
    return sum(f not in FORM_FLAGS for f in form_fields(name, eff))


def friction_core(params, scale: float, pivot: float = 0.0):
    """Bouc-Wen parameters (``model.boucwen.BoucWenParams``) with the friction effect folded in: the
    saturation of z scaled by ``scale`` (b by scale^-n, A kept) and a3 moved so that the level
    ``mid + pivot * half`` of the hysteresis band stays put (0: its middle, +-1: its edges; see the module
    docstring)."""
    if scale == 1.0:
        return params
    try:
        hi, lo = params.z_saturation(1.0)
    except (ValueError, ZeroDivisionError, OverflowError):
        hi = lo = math.nan
    if math.isfinite(hi) and math.isfinite(lo):
        z_fix = 0.5 * (hi + lo) + pivot * 0.5 * (hi - lo)
    else:
        z_fix = 0.0
    k = scale ** (-params.n)
    return replace(params, b=tuple(k * x for x in params.b), a3=params.a3 + params.az * (1.0 - scale) * z_fix)


def pretension_core(params, offset: float, gain: float, whole_loop: bool = False):
    """Bouc-Wen parameters with a pre-tension change folded in: the elastic backbone shifts by ``offset``
    in tendon travel and its compliance scales by ``1 / gain`` (u = offset + (a1 w^2 + a2 w + a3) / gain
    + az z); the friction band az z stays as it was, unless ``whole_loop``, when it scales with the
    backbone (u = offset + (a1 w^2 + a2 w + a3 + az z) / gain: friction in proportion to the tension)."""
    if whole_loop:
        return fold_rigging(params, offset, gain)
    if gain == 1.0 and offset == 0.0:
        return params
    return replace(params, a1=params.a1 / gain, a2=params.a2 / gain, a3=params.a3 / gain + offset)


def core_params(params, eff: Effects):
    """The Bouc-Wen parameters the augmented plant runs: pre-tension and friction folded in."""
    return friction_core(pretension_core(params, eff.pretension_offset_mm, eff.pretension_gain,
                                         bool(eff.pretension_loop)),
                         eff.friction_scale, eff.friction_pivot)


def fold_rigging(params, offset: float, gain: float, friction_scale: float = 1.0):
    """The Bouc-Wen parameters of the wing rigged on the command side, ``u = offset + f(w) / gain``, with
    the friction change folded in as the plant applies it (``friction_core``): the model the online
    adapter and the pre-flight recalibration estimate (their command transform ``u_cmd = offset +
    u_ff / gain`` inverts it exactly). Exact: u_eff = gain (u - offset) in front of u_eff = a1 w^2 + a2 w +
    a3 + az z is the model with a_i / gain, a3 / gain + offset and az / gain; z's dynamics do not depend
    on u. (The ``pretension`` effect in its whole-loop form, friction after it: ``core_params``.)"""
    if not (gain > 0 and friction_scale > 0 and math.isfinite(offset)):
        raise ValueError("gain and friction scale must be positive, offset finite")
    if gain == 1.0 and offset == 0.0 and friction_scale == 1.0:
        return params
    p = friction_core(params, friction_scale)
    return replace(p, a1=p.a1 / gain, a2=p.a2 / gain, a3=p.a3 / gain + offset, az=p.az / gain)


def dynamic_pressure_kpa(airspeed) -> np.ndarray:
    """q = rho V^2 / 2 in kPa for airspeed in m/s (NaN airspeed counts as 0)."""
    v = np.nan_to_num(np.asarray(airspeed, dtype=np.float64), nan=0.0)
    return 0.5 * RHO_AIR * v * v / 1000.0


# ---- input-side operators (on tendon travel u, mm) -------------------------------------------

@njit(cache=True)
def delayed(t, u, delay_s):
    """u(t - delay_s) by linear interpolation; before the log starts, u[0]."""
    n = t.shape[0]
    out = np.empty(n)
    j = 0
    for k in range(n):
        tk = t[k] - delay_s
        if tk <= t[0]:
            out[k] = u[0]
            continue
        while j + 1 < n and t[j + 1] < tk:
            j += 1
        if j + 1 >= n:
            out[k] = u[n - 1]
        else:
            dt = t[j + 1] - t[j]
            a = (tk - t[j]) / dt if dt > 0 else 1.0
            out[k] = u[j] + a * (u[j + 1] - u[j])
    return out


@njit(cache=True)
def rate_limited(t, u, rate, y0):
    """Tendon travel following u with at most ``rate`` mm/s of slew."""
    n = t.shape[0]
    out = np.empty(n)
    y = y0
    tp = t[0]
    for k in range(n):
        step = rate * (t[k] - tp)
        d = u[k] - y
        if d > step:
            d = step
        elif d < -step:
            d = -step
        y += d
        tp = t[k]
        out[k] = y
    return out


@njit(cache=True)
def play(u, width, y0):
    """Play (backlash) operator of total width ``width``: output moves only after the
    input has taken up the slack since the last reversal."""
    return slack_play(u, 0.5 * width, 0.0, 0.0, 0.0, y0)


@njit(cache=True)
def slack_step(x, y, r0, pull, release, zero):
    """One sample of ``slack_play``: the new output for input x and previous output y."""
    s = x - zero
    if s < 0.0:
        s = 0.0
    lo = x - r0 - pull * s
    if lo > y:
        return lo
    hi = x + r0 + release * s
    if hi < y:
        return hi
    return y


@njit(cache=True)
def slack_play(u, r0, pull, release, zero, y0):
    """Play operator whose edges move away from the input as the travel above ``zero`` grows: the output
    follows the input only at the edges u - r0 - pull s (pulling) and u + r0 + release s (releasing),
    s = max(u - zero, 0)."""
    n = u.shape[0]
    out = np.empty(n)
    y = y0
    for k in range(n):
        y = slack_step(u[k], y, r0, pull, release, zero)
        out[k] = y
    return out


# where the play (backlash, capstan stall) stands at a log's first sample: its slack taken up by the last pull
# (the tendon loaded, the default) or by the last release; a log that starts mid-flight may be either
PULLED, RELEASED = -1.0, 1.0


def slack_side_name(side: float) -> str:
    """``PULLED`` / ``RELEASED`` in words: what took the play's slack up last."""
    return "pull" if side < 0 else "release"


def slack_start(eff: Effects, x0: float, side: float = PULLED) -> float:
    """The play's output at the first sample: on its pulling edge (``PULLED``, the tendon loaded) or on its
    releasing edge (``RELEASED``)."""
    r0, pull, release, zero = eff.slack_args
    s = max(x0 - zero, 0.0)
    return x0 - r0 - pull * s if side < 0 else x0 + r0 + release * s


# ---- output-side operators (on warp, deg) ----------------------------------------------------

@njit(cache=True)
def lagged(t, w, tau, y0):
    """First-order lag with time constant tau (s), exact for input held over each step."""
    n = t.shape[0]
    out = np.empty(n)
    y = y0
    tp = t[0]
    for k in range(n):
        dt = t[k] - tp
        a = math.exp(-dt / tau) if tau > 0 else 0.0
        y = a * y + (1.0 - a) * w[k]
        tp = t[k]
        out[k] = y
    return out


@njit(cache=True)
def servo_move(y, c, dt, tau, rate, half=0.0):
    """Servo position after ``dt`` s holding command ``c`` from ``y``: a correction within its half dead band
    ``half`` is not made; otherwise it heads for the near edge of the band about c (c less half toward y) as a
    first-order lag of time constant ``tau``, its speed capped at ``rate`` (exactly: at the cap until within
    rate * tau of that edge, then the exponential). ``tau`` 0: at the rate straight there (at once without a
    cap)."""
    e = c - y
    if abs(e) <= half:
        return y
    c = c - math.copysign(half, e)
    e = c - y
    if tau <= 0.0:
        step = rate * dt
        return c if abs(e) <= step else y + math.copysign(step, e)
    if abs(e) > rate * tau:
        t_cap = (abs(e) - rate * tau) / rate
        if t_cap >= dt:
            return y + math.copysign(rate * dt, e)
        e = math.copysign(rate * tau, e)
        dt -= t_cap
    return c - e * math.exp(-dt / tau)


@njit(cache=True)
def servo_follow_sent(t, u, sent, tau, rate, y0, deadband=0.0):
    """The servo's travel at each row for commands u (``servo_move``, dead band ``deadband`` wide) that reach it
    ``sent[k]`` s after their row's time (the bridge's cycle log records it: the sensor is read, the command
    computed and written): until then the row before's command holds, and after it the row's own until the next
    row (any servo board holds a pulse until the next). ``sent`` is clipped to [0, the time to the next row]."""
    n = t.shape[0]
    out = np.empty(n)
    y = y0
    if n:
        out[0] = y
    half = 0.5 * deadband
    prev = u[0]
    for k in range(1, n):
        dt = t[k] - t[k - 1]
        d = sent[k - 1]
        d = 0.0 if not d > 0.0 else min(d, dt)
        if d > 0.0:
            y = servo_move(y, prev, d, tau, rate, half)
        y = servo_move(y, u[k - 1], dt - d, tau, rate, half)
        prev = u[k - 1]
        out[k] = y
    return out


@njit(cache=True)
def servo_follow(t, u, tau, rate, y0, deadband=0.0):
    """``servo_follow_sent`` with every command sent at its row's time: a row's measurement sees only the commands
    before it (the bridge reads the sensor, then sets the servo)."""
    return servo_follow_sent(t, u, np.zeros(t.shape[0]), tau, rate, y0, deadband)


def servo_travel(t, u, tau, rate, y0, deadband=0.0, sent=None):
    """The servo's travel at each row (``servo_follow``; ``servo_follow_sent`` when the log says when each
    command was sent)."""
    if sent is None:
        return servo_follow(t, u, tau, rate, y0, deadband)
    return servo_follow_sent(t, u, np.ascontiguousarray(sent, dtype=np.float64), tau, rate, y0, deadband)


def sensor_filtered(eff: Effects, t: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The warp sensor's lag (one or two first-order stages in cascade), each starting settled on w[0]."""
    y = np.ascontiguousarray(w, dtype=np.float64)
    for tau in eff.sensor_taus:
        y = lagged(t, y, tau, float(y[0]))
    return y


def apply_input_effects(eff: Effects, t: np.ndarray, u: np.ndarray, slack_side: float = PULLED,
                        sent: np.ndarray | None = None) -> np.ndarray:
    """Tendon travel the sheath actually sees for command u (delay, servo lag, rate limit, backlash and capstan
    stall), the play starting on the edge ``slack_side`` names (``slack_start``); ``sent``: when each command
    reached the servo, s after its row (``servo_travel``; None: at the row's time)."""
    x = np.ascontiguousarray(u, dtype=np.float64)
    if eff.delay_s > 0:
        x = delayed(t, x, eff.delay_s)
    if eff.has_servo:
        x = servo_travel(t, x, eff.servo_tau_s, eff.servo_rate_mm_s, float(x[0]), eff.servo_deadband_mm, sent)
    if math.isfinite(eff.rate_mm_s):
        x = rate_limited(t, x, eff.rate_mm_s, float(x[0]))
    if eff.has_slack:
        x = slack_play(x, *eff.slack_args, slack_start(eff, float(x[0]), slack_side))
    for entry in added("input"):  # effects added at run time, after the chain's own
        x = np.ascontiguousarray(entry.apply(eff, t, x), dtype=np.float64)
    return x


def added_on_warp(eff: Effects, t: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The warp through the effects added at run time on its side (itself when there are none)."""
    for entry in added("warp"):
        w = np.asarray(entry.apply(eff, t, w), dtype=np.float64)
    return w


def apply_output_effects(eff: Effects, t: np.ndarray, w_model: np.ndarray, airspeed=None,
                         ) -> tuple[np.ndarray, np.ndarray]:
    """(w_true, w_meas): aero load on the warp, then sensor lag and drift on its measurement."""
    w = added_on_warp(eff, t, np.asarray(w_model, dtype=np.float64))
    if (eff.aero_gain_per_kpa != 0.0 or eff.aero_deg_per_kpa != 0.0) and airspeed is not None:
        q = dynamic_pressure_kpa(airspeed)
        w = w * (1.0 - eff.aero_gain_per_kpa * q) - eff.aero_deg_per_kpa * q
    w_meas = w
    w_meas = sensor_filtered(eff, t, w_meas)
    if eff.drift_deg_s != 0.0:
        w_meas = w_meas + eff.drift_deg_s * drift_shape(t - t[0], eff.drift_tau_s)
    return w, w_meas


def drift_shape(dt, tau: float):
    """Zero drift per deg/s of initial rate after dt s: tau (1 - exp(-dt / tau)), or dt for tau = inf."""
    if not math.isfinite(tau):
        return dt
    return -tau * np.expm1(-np.asarray(dt, dtype=np.float64) / tau)
