"""The effects' registry: one entry per effect, and every table of the effects derived from it.

An entry (``EffectSpec``) holds what the rest of the code needs to know of an effect: its parameters with
units and neutral values (``Param``), which of them the core run depends on and which enter the prediction
affinely, the boxes the diagnosis searches them in for each of its forms (scaled to the log: ``LogScale``),
the excitation that tells it apart from another effect, what an edge of its search means where the generic
reading does not hold, whether it adds latency, whether the tension an aero load adds changes it, and the
operator in ``model.effects`` that applies it. The order of ``REGISTRY`` is the order the diagnosis tries
the candidates in.

Pure data: ``model.effects`` derives its field tables from it (``EFFECT_FIELDS``, ``EFFECT_NAMES``), the
diagnosis its search boxes and readings (``model.diagnosis``). docs/effects.md says how to add an effect.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field, replace

import numpy as np

from warpbridge.model.signals import central_range


@dataclass(frozen=True)
class Param:
    """One parameter of an effect."""

    field: str  # its name in ``Effects`` and MODEL.json
    unit: str
    neutral: float  # the value that means "no effect"
    in_core: bool = False  # the core (Bouc-Wen) run depends on it: runs are cached by these
    linear: bool = False  # enters the prediction affinely: solved by least squares, not searched
    form_flag: bool = False  # chooses a form: written with it, not fitted, not counted


@dataclass(frozen=True)
class Box:
    """One nonlinear parameter's search: search variable s in [0, 1] -> physical value."""

    field: str
    lo: float
    hi: float
    log: bool = False
    neutral_at_hi: bool = False  # rate limit: the top of the box means "no limit"
    neutral_at_lo: bool = False  # capstan ratio, sensor stage ratio: the bottom of the box means "none" (0)
    grid_like: str | None = None  # on the starting grid, take the coordinate of this (earlier) box
    fixed: bool = False  # a form's flag: held at ``lo``, not searched (pre-tension's whole-loop form)
    wider_lo: float | None = None  # a fit ending at ``lo`` searches again down to this (``Box.widened``)
    wider_hi: float | None = None  # ... ending at ``hi``: up to this

    def widened(self, edge: str) -> Box | None:
        """This box reaching its wider limit at ``edge`` ("lower" or "upper"); None when that edge has none."""
        if edge == "lower" and self.wider_lo is not None:
            return replace(self, lo=self.wider_lo, wider_lo=None)
        if edge == "upper" and self.wider_hi is not None:
            return replace(self, hi=self.wider_hi, wider_hi=None)
        return None

    def value(self, s: float) -> float:
        s = min(max(float(s), 0.0), 1.0)
        if self.log:
            v = math.exp(math.log(self.lo) + s * (math.log(self.hi) - math.log(self.lo)))
        else:
            v = self.lo + s * (self.hi - self.lo)
        if self.neutral_at_hi and s >= 1.0:
            return math.inf
        if self.neutral_at_lo and s <= 0.0:
            return 0.0
        return v

    def coord(self, v: float) -> float:
        if self.neutral_at_hi and not math.isfinite(v):
            return 1.0
        if self.log:
            v = max(v, self.lo)
            s = (math.log(v) - math.log(self.lo)) / (math.log(self.hi) - math.log(self.lo))
        else:
            s = (v - self.lo) / (self.hi - self.lo)
        return min(max(s, 0.0), 1.0)


@dataclass(frozen=True)
class LogScale:
    """What a log's search boxes are scaled by: its length (s), sample rate (Hz), the central range of its
    input (mm) and that range's span, the shortest and longest latency searched (s) and the fastest the
    input moves between two samples (mm/s)."""

    duration: float
    fs: float
    lo: float
    hi: float
    span: float
    tmin: float
    tmax: float
    vmax: float

    @classmethod
    def of(cls, t: np.ndarray, u: np.ndarray) -> LogScale:
        dur = float(t[-1] - t[0])
        fs = (t.size - 1) / max(dur, 1e-12)
        lo_u, hi_u = central_range(u)
        span = max(float(hi_u - lo_u), 1e-9)
        tmax = min(0.5, 0.05 * dur)
        tmin = min(0.5 / fs, 0.1 * tmax)
        dt = np.diff(t)
        rate = np.abs(np.diff(u)) / np.where(dt > 0, dt, np.inf)
        vmax = max(float(np.max(rate)) if rate.size else 1.0, 1e-9)
        return cls(dur, fs, float(lo_u), float(hi_u), span, tmin, tmax, vmax)


def _no_search(_: LogScale) -> list[list[Box]]:
    """One form with nothing to search (an effect whose parameters are all linear, or not searched)."""
    return [[]]


@dataclass(frozen=True)
class EffectSpec:
    """One effect: its parameters, its search, the diagnosis's readings of it and its operator."""

    name: str
    meaning: str  # what it is, physically
    params: tuple[Param, ...]
    # the function of ``model.effects`` that applies it in the chain; an added effect has none, its ``apply``
    # instead
    operator: str
    # the boxes of its nonlinear parameters in each of its forms, scaled to a log; the fit keeps the best form
    forms: Callable[[LogScale], list[list[Box]]] = _no_search
    candidate: bool = True  # the diagnosis searches for it (False: the rig's own, which identify finds)
    separate: Mapping[str, str] = field(default_factory=dict)  # another effect -> the excitation telling them apart
    bound_hints: Mapping[tuple[str, str], str] = field(default_factory=dict)  # (parameter, edge) -> its meaning
    latency: str | None = None  # the field of the latency it adds (latency effects stand in for each other)
    band_rank: int | None = None  # a wider or narrower friction band is named as this (0 first)
    load_coupled: bool = False  # the tension an aero load adds changes it (a band, a compliance)
    tension_cause: tuple[str, str] | None = None  # it changes the tendon's tension: (what, how to tell apart)
    is_load: bool = False  # the load on the wing itself (what the load-coupled effects are read against)
    # an added effect's operator, (effects, t, signal) -> signal, called after the chain's own operators on its
    # ``side``: "input" (the tendon travel into the core) or "warp" (the wing's warp, before the aero load)
    apply: Callable | None = None
    side: str = ""

    @property
    def fields(self) -> tuple[str, ...]:
        return tuple(p.field for p in self.params)

    @property
    def neutral(self) -> tuple[float, ...]:
        return tuple(p.neutral for p in self.params)


def _friction_forms(s: LogScale) -> list[list[Box]]:
    """The band scaled about a level inside it, and the capstan stall, its zero below the log's travel."""
    return [[Box("friction_scale", 0.01, 10.0, log=True), Box("friction_pivot", -1.0, 1.0)],
            [Box("capstan_pull_ratio", 1e-4, 0.3, log=True, neutral_at_lo=True),
             Box("capstan_zero_mm", s.lo - 2.0 * s.span, s.lo),
             Box("capstan_release_ratio", 1e-4, 0.3, log=True, neutral_at_lo=True, grid_like="capstan_pull_ratio")]]


def _pretension_forms(s: LogScale) -> list[list[Box]]:
    """The backbone moved alone, and the whole loop: the same two parameters, the form a fixed flag."""
    own = [Box("pretension_offset_mm", -0.5 * s.span, 0.5 * s.span), Box("pretension_gain", 0.5, 2.0, log=True)]
    return [own + [Box("pretension_loop", float(loop), float(loop), fixed=True)] for loop in (0, 1)]


REGISTRY: tuple[EffectSpec, ...] = (
    EffectSpec(
        "delay", "pure transport delay between command and tendon motion",
        (Param("delay_s", "s", 0.0, in_core=True),), "delayed",
        forms=lambda s: [[Box("delay_s", s.tmin, s.tmax, log=True)]],
        latency="delay_s",
        separate={
            "sensor_lag": "steps or a sharp doublet: a delay shifts the whole response, a sensor lag rounds its "
                          "onset; a sweep to several Hz shows the delay's phase growing linearly with frequency "
                          "while the lag's amplitude rolls off",
            "rate_limit": "the same excitation at two speeds or amplitudes: a slew limit only bites when the tendon "
                          "moves fast, a delay acts at every speed",
        }),
    EffectSpec(
        "servo_lag", "the servo's position loop: a first-order approach to each command, capped at its rated speed, "
        "to the edge of its dead band",
        (Param("servo_tau_s", "s", 0.0, in_core=True), Param("servo_rate_mm_s", "mm/s", math.inf, in_core=True),
         Param("servo_deadband_mm", "mm", 0.0, in_core=True)),
        "servo_follow", candidate=False),
    EffectSpec(
        "rate_limit", "servo slew-rate limit", (Param("rate_mm_s", "mm/s", math.inf, in_core=True),), "rate_limited",
        forms=lambda s: [[Box("rate_mm_s", 0.02 * s.vmax, 1.02 * s.vmax, log=True, neutral_at_hi=True,
                              wider_lo=0.002 * s.vmax)]]),
    EffectSpec(
        "backlash", "tendon slack: a dead band of fixed width at every reversal",
        (Param("backlash_mm", "mm", 0.0, in_core=True),), "slack_play",
        forms=lambda s: [[Box("backlash_mm", 1e-4 * s.span, 0.4 * s.span, log=True, wider_hi=s.span)]],
        band_rank=1, load_coupled=True,
        separate={
            "pretension": "small reversals at several positions: backlash acts at every reversal, a pre-tension "
                          "change shifts the curve everywhere",
            "delay": "reversals at several speeds: backlash is rate independent, a delay grows with speed",
            "sensor_lag": "reversals at several speeds: backlash is rate independent, a sensor lag grows with speed",
        }),
    EffectSpec(
        "friction", "sheath friction changed: the hysteresis widens or narrows, or a stall after each reversal "
                    "grows with the tension",
        (Param("friction_scale", "", 1.0, in_core=True), Param("capstan_pull_ratio", "mm/mm", 0.0, in_core=True),
         Param("capstan_release_ratio", "mm/mm", 0.0, in_core=True),
         Param("capstan_zero_mm", "mm", 0.0, in_core=True), Param("friction_pivot", "", 0.0, in_core=True)),
        "friction_core", forms=_friction_forms, band_rank=0, load_coupled=True,
        bound_hints={("capstan_zero_mm", "upper"): "the tendon would go slack within the log's travel"},
        separate={
            "backlash": "minor loops of several sizes at several mean tendon positions: backlash is a fixed dead "
                        "band at every reversal, friction scales the loop width with the excursion or grows the "
                        "dead band with the tension",
            "pretension": "several amplitudes around several mean tendon positions: pre-tension moves the curve "
                          "and changes its slope, friction only widens the loop",
        }),
    EffectSpec(
        "pretension", "pre-tension changed: the elastic backbone (or the whole loop) shifts in tendon travel and "
                      "its slope scales",
        (Param("pretension_offset_mm", "mm", 0.0, in_core=True), Param("pretension_gain", "", 1.0, in_core=True),
         Param("pretension_loop", "", 0.0, in_core=True, form_flag=True)),
        "core_params", forms=_pretension_forms, load_coupled=True,
        tension_cause=("a re-tensioned rig", "measure the tendon's tension at rest against the bench's: a band that "
                                             "changed in proportion to it is the tension's, one that changed more "
                                             "is the sheath's own (its bend, routing, wear or lubrication)"),
        separate={
            "aero_load": "runs at two or more distinct airspeeds (or one at rest): an aero load grows with dynamic "
                         "pressure, pre-tension does not",
            "drift": "return to the same tendon position at intervals over a long log: drift grows with time, a "
                     "pre-tension offset does not",
        }),
    EffectSpec(
        "sensor_lag", "the warp sensor's own dynamics: a first-order lag, or two lags in cascade",
        (Param("sensor_tau_s", "s", 0.0), Param("sensor_stage_ratio", "", 0.0)), "sensor_filtered",
        forms=lambda s: [[Box("sensor_tau_s", s.tmin, s.tmax, log=True),
                          Box("sensor_stage_ratio", 0.0, 1.0, neutral_at_lo=True)]],
        latency="sensor_tau_s",
        bound_hints={("sensor_stage_ratio", "upper"): "two equal lags: the sensor may have more stages, or a delay "
                                                      "as well"},
        separate={
            "rate_limit": "the same excitation at two speeds or amplitudes: a slew limit only bites on fast tendon "
                          "motion, a sensor lag at every speed",
        }),
    EffectSpec(
        "drift", "slow drift of the warp sensor's zero over the log",
        (Param("drift_deg_s", "deg/s", 0.0, linear=True), Param("drift_tau_s", "s", math.inf)), "drift_shape",
        # from a zero still settling at the log's end (not a static offset) to a steady ramp
        forms=lambda s: [[Box("drift_tau_s", 0.25 * s.duration, 20.0 * s.duration, log=True, neutral_at_hi=True)]],
        separate={
            "aero_load": "vary the airspeed up and down over the log rather than in one direction: drift follows "
                         "time, aero load follows dynamic pressure",
        }),
    EffectSpec(
        "aero_load", "airspeed-dependent load on the trailing edge: warp lost in proportion to dynamic pressure",
        (Param("aero_gain_per_kpa", "1/kPa", 0.0, linear=True), Param("aero_deg_per_kpa", "deg/kPa", 0.0, linear=True)),
        "dynamic_pressure_kpa", is_load=True,
        tension_cause=("a load on the wing", "compare stretches flown slow and fast: a band that grows with the "
                                             "airspeed is the load's")),
)


_ADDED: list[EffectSpec] = []  # effects added at run time (``register``), after the built-in ones


def spec(name: str) -> EffectSpec:
    """The registry's entry of effect ``name``."""
    for s in (*REGISTRY, *_ADDED):
        if s.name == name:
            return s
    raise KeyError(f"unknown effect {name!r} (known: {', '.join(s.name for s in (*REGISTRY, *_ADDED))})")


# ---- the tables derived from it ------------------------------------------------------------------

# effect name -> (field names, neutral values, physical meaning)
EFFECT_FIELDS: dict[str, tuple[tuple[str, ...], tuple[float, ...], str]] = {
    s.name: (s.fields, s.neutral, s.meaning) for s in REGISTRY}
# the effects the diagnosis searches for (a change between the bench and the field)
EFFECT_NAMES: tuple[str, ...] = tuple(s.name for s in REGISTRY if s.candidate)
# effects of the rig itself that identification finds beside the model and the diagnosis keeps as they are
RIG_EFFECTS: tuple[str, ...] = tuple(s.name for s in REGISTRY if not s.candidate)
FORM_FLAGS: tuple[str, ...] = tuple(p.field for s in REGISTRY for p in s.params if p.form_flag)
CORE_FIELDS: tuple[str, ...] = tuple(p.field for s in REGISTRY for p in s.params if p.in_core)
UNITS: dict[str, str] = {p.field: p.unit for s in REGISTRY for p in s.params}
LATENCY_FIELDS: dict[str, str] = {s.name: s.latency for s in REGISTRY if s.latency}
SEPARATE: dict[frozenset, str] = {frozenset({s.name, other}): text for s in REGISTRY
                                  for other, text in s.separate.items()}
BOUND_HINTS: dict[tuple[str, str], str] = {k: v for s in REGISTRY for k, v in s.bound_hints.items()}
BAND_EFFECTS: tuple[str, ...] = tuple(s.name for s in sorted((s for s in REGISTRY if s.band_rank is not None),
                                                             key=lambda s: s.band_rank))
# what a load on the wing changes in a tendon sheath besides the warp it bends back: the friction band and the
# tendon's compliance (its take-up of slack stiffens with tension), all through the tension the load adds
LOAD_COUPLED: tuple[str, ...] = BAND_EFFECTS + tuple(s.name for s in REGISTRY
                                                     if s.load_coupled and s.name not in BAND_EFFECTS)
LOAD_EFFECT: str = next(s.name for s in REGISTRY if s.is_load)
# a change of the tension the sheath carries changes its friction too (capstan law): what changed it, and how to
# tell the two apart
TENSION_CHANGES: dict[str, tuple[str, str]] = {s.name: s.tension_cause for s in REGISTRY if s.tension_cause}


def forms_for(name: str, t: np.ndarray, u: np.ndarray) -> list[list[Box]]:
    """The search boxes of each form of effect ``name``, scaled to the log (t, u)."""
    return spec(name).forms(LogScale.of(t, u))


# ---- effects added at run time -------------------------------------------------------------------

def added(side: str = "") -> tuple[EffectSpec, ...]:
    """The effects added at run time (on ``side`` only, if given)."""
    return tuple(s for s in _ADDED if not side or s.side == side)


def added_field(name: str) -> Param | None:
    """The parameter ``name`` of an effect added at run time (None: no such parameter)."""
    return next((p for s in _ADDED for p in s.params if p.field == name), None)


def candidates() -> tuple[str, ...]:
    """Every effect the diagnosis searches for: the built-in candidates, then the added ones."""
    return EFFECT_NAMES + tuple(s.name for s in _ADDED if s.candidate)


def register(entry: EffectSpec) -> None:
    """Add an effect: its parameters are carried by ``Effects`` (``Effects.with_values``), its ``apply`` runs
    on its ``side`` of the chain, and the diagnosis searches for it (``candidates``) in its ``forms``."""
    if entry.apply is None or entry.side not in ("input", "warp"):
        raise ValueError(f"{entry.name}: an added effect needs its apply and a side, input or warp")
    if entry.name in EFFECT_FIELDS:
        raise ValueError(f"effect {entry.name!r} is registered already")
    taken = set(UNITS)
    clash = [p.field for p in entry.params if p.field in taken]
    if clash or any(p.linear or p.form_flag for p in entry.params):
        raise ValueError(f"{entry.name}: parameters must be new ({', '.join(clash)} taken) and searched")
    _ADDED.append(entry)
    EFFECT_FIELDS[entry.name] = (entry.fields, entry.neutral, entry.meaning)
    UNITS.update({p.field: p.unit for p in entry.params})
    SEPARATE.update({frozenset({entry.name, other}): text for other, text in entry.separate.items()})
    BOUND_HINTS.update(entry.bound_hints)


def unregister(name: str) -> None:
    """Take an effect added at run time out again."""
    entry = spec(name)
    if entry not in _ADDED:
        raise ValueError(f"effect {name!r} is built in")
    _ADDED.remove(entry)
    del EFFECT_FIELDS[name]
    for p in entry.params:
        UNITS.pop(p.field, None)
    for other in entry.separate:
        SEPARATE.pop(frozenset({name, other}), None)
    for k in entry.bound_hints:
        BOUND_HINTS.pop(k, None)


@contextmanager
def registered(entry: EffectSpec) -> Iterator[EffectSpec]:
    """``register`` for the duration of a block."""
    register(entry)
    try:
        yield entry
    finally:
        unregister(entry.name)
