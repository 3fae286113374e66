"""Plant families for the blind diagnosis benchmark, built from the truth-side modules only.

A family is a hysteretic core (``truth_cores``; the physics-based sheath of
``sitl.sheath``) inside a signal path (``truth_chain``). Nothing on this side
imports ``warpbridge.model``: the effects are written again where they act.

| family               | core                        | effects                                | in the model's class |
|----------------------|-----------------------------|----------------------------------------|----------------------|
| ``bouc-wen``         | generalized Bouc-Wen        | the diagnosis's own forms (rewritten)  | yes                  |
| ``bouc-wen-phys``    | generalized Bouc-Wen        | physical: link, servo, linkage, sensor | core only            |
| ``prandtl-ishlinskii`` | sum of plays + spring     | physical                               | no                   |
| ``dahl``             | Dahl friction + spring      | physical                               | no                   |
| ``sheath``           | N-segment capstan sheath    | physical                               | no                   |
| ``lugre-sheath``     | N nodes of LuGre friction   | physical                               | no (rate dependent)  |

Physical effects (``Physical``): a transport delay is extra latency in the
link; a slew limit a slower servo (its own second-order position loop); a
backlash slack in the horn linkage (dead-zone contact model); friction and
pre-tension are properties of the core; a sensor lag is a slower two-stage
sensor filter; a drift a temperature-driven zero (curved); the aerodynamic
load a moment on the wing proportional to dynamic pressure that loads the
tendon. Every physical family also carries bench imperfections the nominal
model cannot express (link latency, servo dynamics, a little slack, the
sensor's filter, ADC quantisation); they stay the same between bench and field.

An effect spec is ``{name: (size, (a, b))}``; size 0 is no effect, ``(a, b)``
in [-1, 1] pick its sign and mix. ``magnitude_for`` finds the size that
changes the noise-free measured warp by a given RMS on a given log.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from truth_chain import (
    diagnosed_delay,
    diagnosed_lag,
    diagnosed_play,
    diagnosed_slew,
    dynamic_pressure_kpa,
    link,
    linkage,
    quantise,
    sensor_filter,
    servo,
    warming_drift,
)
from truth_cores import bw_run, bw_saturation, dahl_run, pi_run
from truth_lugre import V_REF, lugre_params, lugre_run

EFFECTS = ("delay", "rate_limit", "backlash", "friction", "pretension", "sensor_lag", "drift", "aero_load")
PRE_ROLL_S = 5.0  # every log starts after this much history: the tendon is already loaded

Spec = dict[str, tuple[float, tuple[float, float]]]


@dataclass
class Bench:
    """Imperfections of the physical signal path that bench and field share."""

    latency_s: float = 0.0
    jitter_s: float = 0.0
    servo_kp: float = 0.0  # 1/s; 0: no servo dynamics
    servo_vmax: float = math.inf  # mm/s
    servo_tau_s: float = 0.0
    slack_mm: float = 0.0
    link_k: float = 1000.0  # 1/s
    sensor_tau_s: float = 0.0
    quant_deg: float = 0.0

    @classmethod
    def draw(cls, rng: np.random.Generator, span: float) -> Bench:
        return cls(latency_s=rng.uniform(0.002, 0.010), jitter_s=rng.uniform(0.0, 0.004),
                   servo_kp=rng.uniform(40.0, 120.0), servo_vmax=span * rng.uniform(12.0, 30.0),
                   servo_tau_s=rng.uniform(0.003, 0.012), slack_mm=span * rng.uniform(0.0, 0.004),
                   link_k=rng.uniform(300.0, 1500.0), sensor_tau_s=rng.uniform(0.001, 0.005),
                   quant_deg=rng.uniform(0.015, 0.03))


class Family:
    """A plant: ``simulate(t, u, airspeed, spec, seed) -> (w_true, w_meas without noise)``."""

    family: str = ""
    in_class: bool = False
    u_lo: float = 0.0
    u_hi: float = 1.0
    bench: Bench
    name: str = ""

    @property
    def span(self) -> float:
        return self.u_hi - self.u_lo

    # the core with its friction factor, pre-tension (offset, stiffness factor) and aero stretch (c0, c1)
    def core(self, x: np.ndarray, q: np.ndarray, friction: float, pre: tuple[float, float],
             aero: tuple[float, float], t: np.ndarray | None = None) -> np.ndarray:
        raise NotImplementedError

    def simulate(self, t: np.ndarray, u: np.ndarray, airspeed: np.ndarray | None, spec: Spec,
                 seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
        return physical_path(self, t, u, airspeed, spec, seed)

    def quantum(self) -> float:
        return self.bench.quant_deg

    def aero_scale(self) -> float:
        """Aerodynamic load per kPa at full size: a tendon stretch (mm) for the phenomenological cores."""
        return 0.5 * self.span


def _size(spec: Spec, name: str) -> tuple[float, float, float]:
    s, (a, b) = spec.get(name, (0.0, (0.0, 0.0)))
    return float(s), float(a), float(b)


def pretension_of(spec: Spec, span: float) -> tuple[float, float]:
    """(offset, stiffness factor) of a pre-tension change: offset 0.2 span s cos(pi a), factor exp(0.5 s sin)."""
    s, a, _ = _size(spec, "pretension")
    th = math.pi * a
    return 0.2 * span * s * math.cos(th), math.exp(0.5 * s * math.sin(th))


def aero_of(fam: Family, size: float, mix: float) -> tuple[float, float]:
    """(c0, c1) of an aero load of ``size``: the load per kPa, and per kPa and deg of warp (``mix`` in [-1, 1]
    shares the size between them)."""
    m = 0.5 * (mix + 1.0)
    return fam.aero_scale() * size * (1.0 - m), 0.1 * fam.aero_scale() * size * m


def physical_path(fam: Family, t, u, airspeed, spec: Spec, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """link -> servo -> linkage -> core (friction, pre-tension, aero load) -> sensor filter -> drift."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    u = np.ascontiguousarray(u, dtype=np.float64)
    b = fam.bench
    span = fam.span
    rng = np.random.default_rng(seed)
    jit = rng.uniform(0.0, 1.0, t.size)
    s, _, _ = _size(spec, "delay")
    c = link(t, u, b.latency_s + 0.2 * s, jit, b.jitter_s)
    s, _, _ = _size(spec, "rate_limit")
    x = servo(t, c, b.servo_kp, b.servo_vmax * math.exp(-s), b.servo_tau_s, float(c[0]), 4) if b.servo_kp > 0 else c
    s, _, _ = _size(spec, "backlash")
    slack = b.slack_mm + 0.2 * span * s
    if slack > 0:
        x = linkage(t, x, slack, b.link_k, float(x[0]) - 0.5 * slack, 4)
    s, a, _ = _size(spec, "friction")
    friction = math.exp(math.copysign(s, a))
    q = dynamic_pressure_kpa(airspeed) if airspeed is not None else np.zeros(t.size)
    s, _, mix = _size(spec, "aero_load")
    w = fam.core(x, q, friction, pretension_of(spec, span), aero_of(fam, s, mix), t)
    s, kappa, _ = _size(spec, "sensor_lag")
    taus = (b.sensor_tau_s,)
    if s > 0:
        tau = 0.2 * s
        taus = taus + (tau, tau * (0.4 + 0.2 * kappa))
    wm = sensor_filter(t, w, taus)
    return w, wm


def add_drift(fam: Family, t: np.ndarray, wm: np.ndarray, spec: Spec) -> np.ndarray:
    """The zero drift from the log's start (a warming sensor, or the diagnosis's ramp for in-class plants)."""
    s, a, b = _size(spec, "drift")
    if s == 0:
        return wm
    if fam.in_class:
        return wm + math.copysign(0.05 * s, a) * (t - t[0])
    tau_T = 30.0 * 10.0 ** (0.5 * (b + 1.0))  # 30..300 s
    return wm + warming_drift(t, math.copysign(3.0 * s, a), tau_T)


# ---- Bouc-Wen ----------------------------------------------------------------------------------

PAPER = np.array([-0.0205, 0.7120, 0.7958, 0.5369, 3.9953, 3.1179,
                  19.8351, -8.6135, 0.8325, -3.1266, 10.6984, -18.5])


def _canonical(p: np.ndarray) -> np.ndarray:
    """z -> az z (az = 1): A -> A az, b -> az^(1-n) b."""
    q = p.copy()
    c = p[3]
    q[3] = 1.0
    q[4] = p[4] * c
    q[6:12] = p[6:12] * c ** (1.0 - p[5])
    return q


@dataclass
class BoucWen(Family):
    p: np.ndarray = field(default_factory=lambda: _canonical(PAPER))
    u_lo: float = 0.0
    u_hi: float = 1.0
    bench: Bench = field(default_factory=Bench)
    in_class: bool = False
    family: str = "bouc-wen-phys"
    name: str = ""

    def core(self, x, q, friction, pre, aero, t=None):
        p = self.p.copy()
        off, stiff = pre
        if self.in_class:
            raise RuntimeError("in-class plants run the diagnosed path")
        # friction scales the saturation of z: b -> c^-n b
        p[6:12] *= friction ** (-p[5])
        p[1] *= stiff
        return bw_run(p, x - off, q, aero[0], aero[1], self.z0_rest(p), 0.002 * self.span)

    def z0_rest(self, p: np.ndarray) -> float:
        return 0.0

    def simulate(self, t, u, airspeed, spec, seed=0):
        if not self.in_class:
            return physical_path(self, t, u, airspeed, spec, seed)
        return self._diagnosed(t, u, airspeed, spec)

    def _diagnosed(self, t, u, airspeed, spec):
        """The diagnosis's effect forms: delay, slew, play, pretension g (x - o), saturation scale, aero, lag."""
        t = np.ascontiguousarray(t, dtype=np.float64)
        x = np.ascontiguousarray(u, dtype=np.float64)
        span = self.span
        s, _, _ = _size(spec, "delay")
        if s > 0:
            x = diagnosed_delay(t, x, 0.2 * s)
        s, _, _ = _size(spec, "rate_limit")
        if s > 0:
            x = diagnosed_slew(t, x, span * 4.0 / s)
        s, _, _ = _size(spec, "backlash")
        if s > 0:
            x = diagnosed_play(x, 0.2 * span * s)
        p = self.p.copy()
        s, a, _ = _size(spec, "pretension")
        if s > 0:  # the backbone shifted and its compliance scaled, the friction band kept
            th = math.pi * a
            p[0:3] /= math.exp(0.5 * s * math.sin(th))
            p[2] += 0.2 * span * s * math.cos(th)
        s, a, _ = _size(spec, "friction")
        if s > 0:  # the band's saturation scaled about its middle, the slope after a reversal kept
            c = math.exp(math.copysign(s, a))
            hi, lo = bw_saturation(p)
            p[2] += p[3] * (1.0 - c) * 0.5 * (hi + lo)
            p[6:12] *= c ** (-p[5])
        zero = np.zeros(t.size)
        w = bw_run(p, x, zero, 0.0, 0.0, 0.0, 0.002 * span)
        s, _, b = _size(spec, "aero_load")
        if s > 0 and airspeed is not None:
            q = dynamic_pressure_kpa(airspeed)
            mix = 0.5 * (b + 1.0)
            w = w * (1.0 - 4.0 * s * mix * q) - 40.0 * s * (1.0 - mix) * q
        wm = w
        s, _, _ = _size(spec, "sensor_lag")
        if s > 0:
            wm = diagnosed_lag(t, w, 0.2 * s)
        return w, wm

    def quantum(self) -> float:
        return 0.0 if self.in_class else self.bench.quant_deg


def _bw_span(p: np.ndarray, w_lo: float, w_hi: float) -> tuple[float, float]:
    hi, lo = bw_saturation(p)
    a = lambda w: p[0] * w * w + p[1] * w + p[2]  # noqa: E731
    return a(w_lo) + p[3] * lo, a(w_hi) + p[3] * hi


def draw_bouc_wen(rng: np.random.Generator, in_class: bool) -> BoucWen:
    """Bouc-Wen parameters drawn around the paper's, kept only if well behaved on 2..12 deg."""
    base = _canonical(PAPER)
    hi0, _ = bw_saturation(base)
    for _ in range(500):
        p = base.copy()
        p[5] = rng.uniform(2.2, 4.0)
        p[6:12] = base[6:12] * rng.uniform(0.8, 1.25, 6)
        p[0] = base[0] * rng.uniform(0.3, 1.5)
        p[1] = base[1] * rng.uniform(0.75, 1.35)
        p[2] = base[2] + rng.uniform(-0.4, 0.4)
        p[4] = base[4] * rng.uniform(0.6, 1.6)
        hi, lo = bw_saturation(p)
        if not (math.isfinite(hi) and hi > 0 and math.isfinite(lo)):
            continue
        c = rng.uniform(0.5, 1.6)  # loop-width scale against the paper's
        p[6:12] *= (c * hi0 / hi) ** (-p[5])
        hi, lo = bw_saturation(p)
        width = hi - lo
        if not (math.isfinite(width) and 0.2 < width < 3.0):
            continue
        if p[0] < 0 and -p[1] / (2 * p[0]) < 18.0:  # monotone up to 18 deg at least
            continue
        u_lo, u_hi = _bw_span(p, 2.0, 12.0)
        if not u_hi > u_lo + 1.0:
            continue
        fam = BoucWen(p=p, u_lo=u_lo, u_hi=u_hi, in_class=in_class,
                      family="bouc-wen" if in_class else "bouc-wen-phys")
        if not in_class:
            fam.bench = Bench.draw(rng, u_hi - u_lo)
        t = np.linspace(0, 20, 4000)
        u = 0.5 * (u_lo + u_hi) + 0.55 * (u_hi - u_lo) * np.sin(2 * np.pi * 0.3 * t) * (0.4 + 0.6 * t / 20)
        _, w = fam.simulate(t, u, None, {})
        if np.all(np.isfinite(w)) and np.ptp(w) > 5.0 and np.max(w) < 16.0:
            return fam
    raise RuntimeError("could not draw a well-behaved Bouc-Wen plant")


# ---- Prandtl-Ishlinskii --------------------------------------------------------------------------

@dataclass
class PrandtlIshlinskii(Family):
    radii: np.ndarray = field(default_factory=lambda: np.zeros(1))
    weights: np.ndarray = field(default_factory=lambda: np.ones(1))
    c: tuple[float, float, float] = (0.0, 1.0, 0.0)
    u_lo: float = 0.5
    u_hi: float = 8.0
    bench: Bench = field(default_factory=Bench)
    family: str = "prandtl-ishlinskii"
    name: str = ""

    def core(self, x, q, friction, pre, aero, t=None):
        off, stiff = pre
        c0, c1, c2 = self.c
        return pi_run(np.ascontiguousarray(x), self.radii * friction, self.weights, c0, c1 * stiff, c2, off, q,
                      aero[0], aero[1])


def draw_prandtl_ishlinskii(rng: np.random.Generator) -> PrandtlIshlinskii:
    """Ten to sixteen play operators with decaying weights and a hardening spring; u spans 0.5..8 mm."""
    m = int(rng.integers(10, 17))
    radii = np.linspace(0.0, rng.uniform(0.8, 1.8), m)
    weights = np.exp(-rng.uniform(0.5, 3.0) * np.linspace(0, 1, m))
    weights /= weights.sum()
    u_lo, u_hi = 0.5, 8.0
    y_lo, y_hi = u_lo - radii @ weights, u_hi - radii @ weights
    curv = rng.uniform(-0.25, 0.25)
    span = y_hi - y_lo
    c1 = 10.0 / span * (1 - curv)
    c2 = 10.0 / span ** 2 * curv
    c0 = 2.0 - c1 * y_lo - c2 * y_lo ** 2
    return PrandtlIshlinskii(radii, weights, (float(c0), float(c1), float(c2)), u_lo, u_hi,
                             Bench.draw(rng, u_hi - u_lo))


# ---- Dahl --------------------------------------------------------------------------------------

@dataclass
class Dahl(Family):
    hc: float = 0.5
    a: float = 1.0
    k: float = 1.0
    k2: float = 0.0
    c0: float = 0.0
    u_lo: float = 1.0
    u_hi: float = 9.0
    bench: Bench = field(default_factory=Bench)
    family: str = "dahl"
    name: str = ""

    def core(self, x, q, friction, pre, aero, t=None):
        off, stiff = pre
        hc = self.hc * friction
        return dahl_run(np.ascontiguousarray(x), hc, self.a, self.k * stiff, self.k2, self.c0, off, -hc, q,
                        aero[0], aero[1])


def draw_dahl(rng: np.random.Generator) -> Dahl:
    """A Dahl friction element (exponent 0.5..2) in series with a stiffening spring; u spans 1..9 mm."""
    hc = rng.uniform(0.3, 0.8)
    a = rng.uniform(0.5, 2.0)
    u_lo, u_hi = 1.0, 9.0
    k2 = rng.uniform(0.0, 0.08)
    e_lo, e_hi = u_lo + hc, u_hi - hc
    k = (10.0 - k2 * (e_hi ** 2 - e_lo ** 2)) / (e_hi - e_lo)
    c0 = 2.0 - k * e_lo - k2 * e_lo ** 2
    return Dahl(hc, a, float(k), float(k2), float(c0), u_lo, u_hi, Bench.draw(rng, u_hi - u_lo))


# ---- the physics-based sheath (``sitl.sheath``) ---------------------------------------------------

def _sheath_module():
    from warpbridge.sitl import sheath  # the lead merges it into main; the family is skipped until then

    return sheath


@dataclass
class Sheath(Family):
    """N friction nodes along the sheath (capstan law), an elastic tendon, a pre-tension; the aerodynamic
    moment is the sheath plant's own trailing-edge load. Friction scales mu, pre-tension scales the rig's
    tension at rest (and the stiffness factor the wing's)."""

    params: object = None
    u_lo: float = 0.0
    u_hi: float = 1.0
    bench: Bench = field(default_factory=Bench)
    family: str = "sheath"
    name: str = ""

    def aero_scale(self) -> float:
        """Trailing-edge load (N) per kPa at full size: a third of the rig's pull for the 12 deg range."""
        return 12.0 * self.params.mm_per_deg * self.params.k_wing / 3.0

    def core(self, x, q, friction, pre, aero, t=None):
        sh = _sheath_module()
        off, stiff = pre
        # pre-tension: a relative change of the rig's tension at rest (the offset part of the spec, over a
        # fifth of the span, maps to a factor e^(+-1) at full size), the stiffness part stiffens the wing
        rel = off / (0.2 * self.span)
        p = self.params.with_changes(mu=self.params.mu * friction,
                                     pretension_n=self.params.pretension_n * math.exp(rel),
                                     k_wing=self.params.k_wing * stiff)
        x = np.ascontiguousarray(x, dtype=np.float64)
        c0, c1 = aero
        w = sh.SheathPlant(p, u0=0.0).simulate(x, 0.0)  # the rig rests at travel 0, as in draw_sheath
        if c0 == 0.0 and c1 == 0.0 or not np.any(q):
            return w
        for _ in range(2):  # the load follows the warp it bends back: two fixed-point passes
            load = q * (c0 + c1 * w)
            w = sh.SheathPlant(p, u0=0.0).simulate(x, load)
        return w


def draw_sheath(rng: np.random.Generator) -> Sheath:
    """A rig from ``sitl.sheath.random_sheath`` (bend, mu, nodes, stiffnesses, pre-tension over a wide range);
    the tendon travel runs from where pulling reaches 2 deg to where it reaches 12 deg (the tendon never goes
    slack), kept when that is a sensible travel."""
    sh = _sheath_module()
    for _ in range(100):
        params = sh.random_sheath(rng)
        try:
            u_lo = sh.SheathPlant(params).travel_range(2.0)[1]
            u_hi = sh.SheathPlant(params).travel_range(12.0)[1]
        except RuntimeError:
            continue
        if 1.0 < u_hi - u_lo < 40.0:
            return Sheath(params, u_lo, u_hi, Bench.draw(rng, u_hi - u_lo))
    raise RuntimeError("could not draw a usable sheath rig")


# ---- a second sheath, in another form: LuGre friction at each node (``truth_lugre``) ------------------

@dataclass
class LugreSheath(Family):
    """N massless nodes along the sheath, each with LuGre friction (bristles, Stribeck, a lubricant's viscous
    drag) on the normal force of the tendon bent over it, an elastic tendon, a hardening wing: rate dependent,
    unlike every other family. Friction scales the friction coefficients; pre-tension is a turnbuckle that
    shortens the tendon (a travel offset) and stiffens the wing; the aerodynamic load pushes the trailing edge
    back (N per kPa, following the warp)."""

    bend_deg: float = 180.0
    n: int = 10
    k_tendon: float = 5.0
    t_rest: float = 0.5
    mu_c: float = 0.15
    mu_s: float = 0.18
    v_s: float = 1.0
    bristle_mm: float = 0.01
    bristle_tau_s: float = 0.001
    mu_v: float = 0.03
    k_wing: float = 1.0
    hardening: float = 0.2
    mm_per_deg: float = 0.5
    u_lo: float = 0.0
    u_hi: float = 1.0
    bench: Bench = field(default_factory=Bench)
    family: str = "lugre-sheath"
    name: str = ""

    def params(self, friction: float = 1.0, stiff: float = 1.0) -> np.ndarray:
        return lugre_params(self.bend_deg, self.n, self.k_tendon, self.t_rest, self.mu_c * friction,
                            self.mu_s * friction, self.v_s, self.bristle_mm, self.bristle_tau_s, self.mu_v * friction,
                            self.k_wing * stiff, self.hardening, self.mm_per_deg)

    def aero_scale(self) -> float:
        """Trailing-edge load (N) per kPa at full size: a third of the rig's pull for the 12 deg range."""
        return 12.0 * self.mm_per_deg * self.k_wing / 3.0

    def core(self, x, q, friction, pre, aero, t=None):
        if t is None:
            raise ValueError("the LuGre sheath is rate dependent: it needs the sample times")
        off, stiff = pre
        w, _, _ = lugre_run(np.ascontiguousarray(t, dtype=np.float64), np.ascontiguousarray(x, dtype=np.float64) + off,
                         np.ascontiguousarray(q, dtype=np.float64), float(aero[0]), float(aero[1]),
                         self.params(friction, stiff), self.n)
        return w

    @property
    def wrap(self) -> float:
        return self.mu_c * math.radians(self.bend_deg)


def _lugre_travel(fam: LugreSheath, w_target: float, speed: float) -> float | None:
    """Travel (mm) at which a steady pull at ``speed`` mm/s from rest reaches ``w_target`` deg (None if it does
    not within 45 mm)."""
    rate = 100.0
    t = np.arange(int(45.0 / speed * rate)) / rate
    x = speed * t
    w, _, _ = lugre_run(t, x, np.zeros(t.size), 0.0, 0.0, fam.params(), fam.n)
    hit = np.flatnonzero(w >= w_target)
    return float(x[hit[0]]) if hit.size else None


def draw_lugre_sheath(rng: np.random.Generator) -> LugreSheath:
    """A rig over a wide physical range (uniform unless said; log-uniform for ratios of scale): bend 45..450 deg;
    mu_c 0.05..0.3 (log), a static excess mu_s / mu_c 1..1.4 (capped where the steady friction would fall with
    speed), Stribeck speed 0.3..3 mm/s (log); a viscous drag
    adding 0..60 % of mu_c at 20 mm/s; bristles 0.003..0.03 mm (log) damped over 0.3..3 ms (log); 3..16 nodes;
    tendon 1..20 N/mm (log); wing 0.5..3 N/mm (log), hardening 0..0.6 per 10 deg, 0.3..0.8 mm per deg; a tension
    at rest holding the wing at 0.3..1.5 deg. The travel runs from where a slow pull reaches 2 deg to where it
    reaches 12 deg; kept when that is a sensible travel and a full cycle at speed never slackens the tendon."""
    for _ in range(100):
        mu_c = float(np.exp(rng.uniform(math.log(0.05), math.log(0.3))))
        k_wing = float(np.exp(rng.uniform(math.log(0.5), math.log(3.0))))
        mm_per_deg = float(rng.uniform(0.3, 0.8))
        hardening = float(rng.uniform(0.0, 0.6))
        w_rest = float(rng.uniform(0.3, 1.5))
        pa = w_rest * mm_per_deg
        fam = LugreSheath(
            bend_deg=float(rng.uniform(45.0, 450.0)), n=int(rng.integers(3, 17)),
            k_tendon=float(np.exp(rng.uniform(math.log(1.0), math.log(20.0)))),
            t_rest=k_wing * pa * (1.0 + hardening / (20.0 * mm_per_deg) * pa),
            mu_c=mu_c, mu_s=mu_c * float(rng.uniform(1.0, 1.4)),
            v_s=float(np.exp(rng.uniform(math.log(0.3), math.log(3.0)))),
            bristle_mm=float(np.exp(rng.uniform(math.log(0.003), math.log(0.03)))),
            bristle_tau_s=float(np.exp(rng.uniform(math.log(3e-4), math.log(3e-3)))),
            mu_v=mu_c * float(rng.uniform(0.0, 0.6)), k_wing=k_wing, hardening=hardening, mm_per_deg=mm_per_deg)
        # the steady friction must not fall with speed (truth_lugre): the Stribeck drop's steepest slope,
        # 0.858 (mu_s - mu_c) / v_s, stays under 90 % of the viscous slope mu_v / V_REF
        fam.mu_s = min(fam.mu_s, mu_c + 0.9 * fam.mu_v / V_REF * fam.v_s / 0.858)
        u_lo = _lugre_travel(fam, 2.0, 2.0)
        u_hi = _lugre_travel(fam, 12.0, 2.0)
        if u_lo is None or u_hi is None or not 1.0 < u_hi - u_lo < 40.0:
            continue
        # a full cycle at speed (1 Hz over the travel) must keep the tendon taut
        t = np.arange(4000) / 500.0
        x = 0.5 * (u_lo + u_hi) - 0.5 * (u_hi - u_lo) * np.cos(2 * np.pi * t)
        _, t_min, _ = lugre_run(t, x, np.zeros(t.size), 0.0, 0.0, fam.params(), fam.n)
        if t_min <= 0.05 * fam.t_rest:
            continue
        fam.u_lo, fam.u_hi, fam.bench = u_lo, u_hi, Bench.draw(rng, u_hi - u_lo)
        return fam
    raise RuntimeError("could not draw a usable LuGre sheath rig")


# ---- drawing ------------------------------------------------------------------------------------

FAMILIES = ("bouc-wen", "bouc-wen-phys", "prandtl-ishlinskii", "dahl", "sheath", "lugre-sheath")


def draw_family(family: str, rng: np.random.Generator) -> Family:
    if family == "bouc-wen":
        return draw_bouc_wen(rng, in_class=True)
    if family == "bouc-wen-phys":
        return draw_bouc_wen(rng, in_class=False)
    if family == "prandtl-ishlinskii":
        return draw_prandtl_ishlinskii(rng)
    if family == "dahl":
        return draw_dahl(rng)
    if family == "sheath":
        return draw_sheath(rng)
    if family == "lugre-sheath":
        return draw_lugre_sheath(rng)
    raise ValueError(f"unknown family {family!r} (known: {', '.join(FAMILIES)})")


def draw_plants(seed: int, family: str, count: int) -> list[Family]:
    """``count`` plants of one family; seed and family fix them."""
    rng = np.random.default_rng([seed, sum(map(ord, family))])
    out = []
    for i in range(count):
        p = draw_family(family, rng)
        p.name = f"{family}-s{seed}-{i}"
        out.append(p)
    return out


# ---- logs and magnitudes -------------------------------------------------------------------------

@dataclass
class Log:
    t: np.ndarray
    u: np.ndarray
    airspeed: np.ndarray
    w_true: np.ndarray
    w_clean: np.ndarray  # measured warp without noise and quantisation
    w: np.ndarray  # what the sensor logs


def run_log(fam: Family, t: np.ndarray, u: np.ndarray, airspeed: np.ndarray, spec: Spec, noise: float,
            seed: int) -> Log:
    """Simulate a log whose first ``PRE_ROLL_S`` of input (already in t, u) are history and are cut off."""
    w_true, wm = fam.simulate(t, u, airspeed, spec, seed)
    keep = t >= t[0] + PRE_ROLL_S
    tk = t[keep] - t[keep][0]
    wm = add_drift(fam, tk, wm[keep], spec)
    rng = np.random.default_rng([seed, 7])
    w = quantise(wm + noise * rng.standard_normal(tk.size), fam.quantum())
    return Log(tk, u[keep], airspeed[keep], w_true[keep], wm, w)


def magnitude_for(fam: Family, name: str, target_rms: float, shape, t, u, airspeed, seed: int) -> float:
    """Size of effect ``name`` whose RMS change of the noise-free measured warp on this log is ``target_rms``."""
    base = run_log(fam, t, u, airspeed, {}, 0.0, seed).w_clean

    def rms(s: float) -> float:
        w1 = run_log(fam, t, u, airspeed, {name: (s, shape)}, 0.0, seed).w_clean
        v = float(np.sqrt(np.mean((w1 - base) ** 2)))
        return v if math.isfinite(v) else math.inf

    lo, hi = 0.0, 0.02
    while rms(hi) < target_rms and hi < 50:
        lo, hi = hi, hi * 2
    for _ in range(18):
        mid = math.sqrt(lo * hi) if lo > 0 else 0.5 * hi
        if rms(mid) < target_rms:
            lo = mid
        else:
            hi = mid
    return math.sqrt(lo * hi) if lo > 0 else hi


def describe(spec: Spec) -> str:
    return ",".join(f"{n}={s:.3g}" for n, (s, _) in spec.items() if s > 0) or "none"
