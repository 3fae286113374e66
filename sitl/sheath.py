"""A tendon in a sheath warping a wing, from the mechanics: tendon travel (mm) -> warp (deg).

The truth side of the benchmarks, written from the physics and importing none of
the model's hysteresis operators. The sheath route, of total wrap angle
``bend_deg``, is ``n_segments`` friction nodes, each bending the tendon by
``bend_deg / n_segments``; the tendon runs from the servo end (travel ``u``,
positive = pull) over the nodes to the wing's trailing edge in
``n_segments + 1`` elastic pieces (together ``k_tendon`` N/mm, plus an optional
take-up ``slack_mm`` that a tendon lying loose in its sheath straightens out at
low tension: the compliance is high near zero tension, which gives the paper's
"hardening" branches: warp per mm of tendon grows along the pull). A node
sticks while the tensions on its two sides satisfy the capstan law,
``T_servo_side <= exp(mu theta) T_wing_side`` and the reverse; when it slips,
the ratio sits at that bound in the direction opposing the slip. The far end
pulls the trailing edge against the wing's stiffness ``k_wing`` (N per mm of
far-end travel, stiffening by ``hardening`` per 10 deg of warp) and an optional
external load ``load_n`` (an aerodynamic moment as the equivalent tendon force,
N, positive = pushing the trailing edge back). Warp is the far-end travel from
the wing's unloaded shape over ``mm_per_deg``; at rest (travel ``u0``, tension
``pretension_n`` all along, no load) the pre-tension holds the wing at the
small warp ``rest_warp``. The pre-tension thus sets the tendon's length: over
a travel range that goes slack it only shifts the loop in travel; over a range
that stays taut it also sets where the loop works (stiffer, with wider capstan
bands, at higher tension). A tendon only pulls: released far enough it goes
slack (zero tension everywhere, the wing at its unloaded shape less the load).
The motion is quasi-static and rate independent: each sample is solved exactly
(to 1e-12 mm) for the node positions, so the result depends only on the path
of (u, load), never on the sample rate. Usage::

    plant = SheathPlant(rigged_sheath(), u0=0.0)
    w = plant.simulate(u_mm_array, load_n=0.0)        # or plant.step(u, load) per sample
    u_lo, u_hi = plant.travel_range(10.0)                # tendon travel spanning warp 0..10 deg

Solver: a move of the servo end makes a slip zone grow from the servo end
(nodes 1..m slip, their tensions on the capstan exponential, node m+1 and
beyond stuck); the zone is the smallest m whose anchor node holds, and its
tension is a one-dimensional monotone root (Newton inside a bracket). A change
of load grows a zone from the far end the same way; when both change and the
zones meet, each stuck node between them and each split of an all-slipping
tendon is tried until one is consistent. Both move together within a sample,
so the result is exact for any path that is linear between samples; a plain
projected Gauss-Seidel solution agrees to 1e-8 deg (tests).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

# ---------------------------------------------------------------------------------------------------------------
# compiled kernel. Positions are displacements from rest, mm, positive towards the servo:
# pos[0] servo end (= u - u0), pos[1..N] tendon at the friction nodes, pos[N+1] far end (trailing edge).
# Segment j (1..N+1) joins pos[j-1] and pos[j]; its elongation is e_rest + pos[j-1] - pos[j].
# A trial configuration gives each moving segment j the tension t * mult[j] (t one unknown), from the capstan
# bound of the slipping nodes between it and the segment that carries t.
# ---------------------------------------------------------------------------------------------------------------

# layout of the kernel's parameter vector
K_N, K_KSEG, K_SSEG, K_TS, K_R, K_EREST, K_KW, K_AH, K_XWREST, K_MMDEG = range(10)
N_KPARAMS = 10
# layout of the kernel's small state vector (besides the positions)
S_LOAD, S_UHINT, S_UDIR, S_LHINT, S_LDIR, S_BAD, S_JHINT = range(7)  # S_JHINT..+3: per (servo, load) direction
N_SSTATE = 10

X_TOL = 1e-12  # mm, position tolerance of each solve
R_TOL = 1e-12  # relative tolerance of the stick test
DIR_TOL = 1e-9  # mm a slipping node may move the wrong way (solver noise) before a trial is rejected


@njit(cache=True, inline="always")
def _seg_e(t: float, p: np.ndarray) -> float:
    """Elongation (mm) of one segment at tension t >= 0: elastic plus take-up of slack."""
    return t / p[K_KSEG] + p[K_SSEG] * t / (t + p[K_TS])


@njit(cache=True, inline="always")
def _seg_de(t: float, p: np.ndarray) -> float:
    d = t + p[K_TS]
    return 1.0 / p[K_KSEG] + p[K_SSEG] * p[K_TS] / (d * d)


@njit(cache=True, inline="always")
def _seg_t(e: float, p: np.ndarray) -> float:
    """Tension of one segment at elongation e (0 when slack); the inverse of ``_seg_e``."""
    if e <= 0.0:
        return 0.0
    k = p[K_KSEG]
    ts = p[K_TS]
    b = ts / k + p[K_SSEG] - e
    disc = b * b + 4.0 * e * ts / k
    if b > 0.0:
        return 2.0 * e * ts / (b + math.sqrt(disc))
    return 0.5 * k * (math.sqrt(disc) - b)


@njit(cache=True, inline="always")
def _wing_x(f: float, p: np.ndarray) -> float:
    """Far-end travel from the unloaded wing (mm) at which the wing pushes back with force f (N)."""
    y = f / p[K_KW]
    ay = abs(y)
    x = 2.0 * ay / (1.0 + math.sqrt(1.0 + 4.0 * p[K_AH] * ay))
    return x if y >= 0.0 else -x


@njit(cache=True, inline="always")
def _wing_dx(x: float, p: np.ndarray) -> float:
    """d(travel)/d(force) of the wing at travel x."""
    return 1.0 / (p[K_KW] * (1.0 + 2.0 * p[K_AH] * abs(x)))


@njit(cache=True, inline="always")
def _tension(pos: np.ndarray, j: int, p: np.ndarray) -> float:
    return _seg_t(p[K_EREST] + pos[j - 1] - pos[j], p)


@njit(cache=True)
def _g(t, mult, j0, j1, wing, load, target, p):
    """Sum over segments j0..j1 of (elongation at t mult[j] - rest elongation), plus the far end's position
    when ``wing``, minus target; and its derivative in t (positive: the function increases)."""
    v = 0.0
    d = 0.0
    er = p[K_EREST]
    for j in range(j0, j1 + 1):
        tc = t * mult[j]
        v += _seg_e(tc, p) - er
        d += mult[j] * _seg_de(tc, p)
    if wing:
        x = _wing_x(t - load, p)
        v += x - p[K_XWREST]
        d += _wing_dx(x, p)
    return v - target, d


@njit(cache=True)
def _solve_t(mult, j0, j1, wing, load, target, guess, p) -> float:
    """t >= 0 with _g(t) = 0, or 0 when even zero tension overshoots (the tendon goes slack).

    Newton from the guess inside a bracket kept from the signs seen: _g increases and is concave wherever the
    far end is pulled (every term is), so after one step the iterates climb to the root from below."""
    lo = 0.0
    hi = math.inf
    zero_seen = False
    t = max(guess, 0.0)
    for _ in range(200):
        gv, dg = _g(t, mult, j0, j1, wing, load, target, p)
        if t == 0.0:
            zero_seen = True
            if gv >= 0.0:
                return 0.0
        if abs(gv) <= X_TOL:
            return t
        if gv > 0.0:
            hi = t
        else:
            lo = t
        tn = t - gv / dg
        if tn <= lo:
            tn = 0.0 if not zero_seen else 0.5 * (lo + hi)
        elif tn >= hi:
            tn = 0.5 * (lo + hi)
        if abs(tn - t) <= 1e-15 * (1.0 + t):
            return tn
        t = tn
    return t


@njit(cache=True, inline="always")
def _in_band(t_servo: float, t_wing: float, r: float) -> bool:
    """Capstan stick condition of a node between tensions t_servo and t_wing (with tolerance)."""
    return (t_servo <= r * t_wing * (1.0 + R_TOL) + 1e-14) and (t_wing <= r * t_servo * (1.0 + R_TOL) + 1e-14)


@njit(cache=True, inline="always")
def _holds(t_servo: float, t_wing: float, s: float, r: float) -> bool:
    """Does a node stay stuck against slipping in direction s?"""
    if s > 0.0:
        return t_servo <= r * t_wing * (1.0 + R_TOL) + 1e-14
    return t_wing <= r * t_servo * (1.0 + R_TOL) + 1e-14


@njit(cache=True)
def _moved_right(pos, tmp, j0, j1, s) -> bool:
    for j in range(j0, j1 + 1):
        if (tmp[j] - pos[j]) * s < -DIR_TOL:
            return False
    return True


@njit(cache=True)
def _servo_zone(pos, tmp, mult, x0, load, m, s, p):
    """Trial: nodes 1..m slip in direction s (servo end moved to x0); node m+1 stays, or the far end moves
    when m = N. Fills tmp[0..m] (and tmp[N+1] when m = N). Returns (moved the right way, tension of segment m+1)."""
    n = int(p[K_N])
    er = p[K_EREST]
    rs = p[K_R] if s > 0.0 else 1.0 / p[K_R]
    a = m + 1
    c = 1.0
    for j in range(a, 0, -1):
        mult[j] = c
        c *= rs
    wing = m == n
    guess = _tension(pos, a, p)
    if wing:
        t = _solve_t(mult, 1, a, True, load, x0, guess, p)
        tmp[a] = _wing_x(t - load, p) - p[K_XWREST]
    else:
        t = _solve_t(mult, 1, a, False, load, x0 - pos[a], guess, p)
        tmp[a] = pos[a]
    tmp[0] = x0
    if t > 0.0:
        for j in range(a, 1, -1):
            tmp[j - 1] = tmp[j] + _seg_e(t * mult[j], p) - er
    elif s > 0.0:  # slack tendon pulled: nodes dragged along only where a segment would stretch
        for j in range(1, m + 1):
            tmp[j] = max(pos[j], tmp[j - 1] + er)
    else:  # released until slack: nodes move towards the wing only as far as the tension reaches zero
        for j in range(a, 1, -1):
            tmp[j - 1] = min(pos[j - 1], tmp[j] - er)
    return _moved_right(pos, tmp, 1, m, s), t


@njit(cache=True)
def _load_zone(pos, tmp, mult, load, b, s, p):
    """Trial: nodes b+1..N slip in direction s and the far end moves under the new load; node b (or the servo
    end, b = 0) stays. Fills tmp[b..N+1]. Returns (moved the right way, tension of segment b+1)."""
    n = int(p[K_N])
    er = p[K_EREST]
    rs = p[K_R] if s > 0.0 else 1.0 / p[K_R]
    c = 1.0
    for j in range(n + 1, b, -1):
        mult[j] = c
        c *= rs
    t = _solve_t(mult, b + 1, n + 1, True, load, pos[b], _tension(pos, n + 1, p), p)
    tmp[b] = pos[b]
    tmp[n + 1] = _wing_x(t - load, p) - p[K_XWREST]
    if t > 0.0:
        for j in range(b + 1, n + 1):
            tmp[j] = tmp[j - 1] - (_seg_e(t * mult[j], p) - er)
    elif s > 0.0:  # wing springs towards the servo and slackens the tendon: nodes stay unless stretched
        for j in range(b + 1, n + 1):
            tmp[j] = max(pos[j], tmp[j - 1] + er)
    else:
        for j in range(n + 1, b + 1, -1):
            tmp[j - 1] = min(pos[j - 1], tmp[j] - er)
    return _moved_right(pos, tmp, b + 1, n, s), t * mult[b + 1]


@njit(cache=True)
def _all_slip(pos, tmp, mult, x0, load, k, su, sl, p):
    """Trial: nodes 1..k slip in direction su, nodes k+1..N in direction sl, the far end moves under the new
    load. Fills tmp[0..N+1]. Returns whether every node moved its way."""
    n = int(p[K_N])
    er = p[K_EREST]
    rl = p[K_R] if sl > 0.0 else 1.0 / p[K_R]
    ru = p[K_R] if su > 0.0 else 1.0 / p[K_R]
    c = 1.0
    for j in range(n + 1, 0, -1):
        mult[j] = c
        c *= ru if j <= k + 1 else rl
    t = _solve_t(mult, 1, n + 1, True, load, x0, _tension(pos, n + 1, p), p)
    tmp[0] = x0
    tmp[n + 1] = _wing_x(t - load, p) - p[K_XWREST]
    if t > 0.0:
        for j in range(n + 1, 1, -1):
            tmp[j - 1] = tmp[j] + _seg_e(t * mult[j], p) - er
    else:  # slack all along: nodes move only where a segment would otherwise stretch
        for j in range(1, n + 1):
            tmp[j] = pos[j]
            if su > 0.0:
                tmp[j] = max(tmp[j], tmp[j - 1] + er)
        for j in range(n + 1, 1, -1):
            tmp[j - 1] = min(tmp[j - 1], tmp[j] - er)
    return _moved_right(pos, tmp, 1, k, su) and _moved_right(pos, tmp, k + 1, n, sl)


@njit(cache=True)
def _search_servo(pos, tmp, mult, st, x0, load, s, p, use_hint, alone) -> int:
    """Smallest slip zone from the servo end whose anchor node holds (its far neighbour as it was); fills tmp."""
    n = int(p[K_N])
    r = p[K_R]
    m = int(st[S_UHINT]) if (use_hint and st[S_UDIR] == s) else 0
    from_zero = m == 0
    while True:
        ok, t = _servo_zone(pos, tmp, mult, x0, load, m, s, p)
        if not ok and not from_zero:
            m = 0
            from_zero = True
            continue
        if m < n and not _holds(t, _tension(pos, m + 2, p), s, r):
            m += 1
            continue
        if not ok and alone:
            st[S_BAD] += 1.0
        st[S_UHINT] = m
        st[S_UDIR] = s
        return m


@njit(cache=True)
def _search_load(pos, tmp, mult, st, load, s, p, use_hint, alone) -> int:
    """Smallest slip zone from the far end whose anchor node holds (its servo-side neighbour as it was)."""
    n = int(p[K_N])
    r = p[K_R]
    b = int(st[S_LHINT]) if (use_hint and st[S_LDIR] == s) else n
    from_end = b == n
    while True:
        ok, t = _load_zone(pos, tmp, mult, load, b, s, p)
        if not ok and not from_end:
            b = n
            from_end = True
            continue
        if b > 0 and not _holds(_tension(pos, b, p), t, s, r):
            b -= 1
            continue
        if not ok and alone:
            st[S_BAD] += 1.0
        st[S_LHINT] = b
        st[S_LDIR] = s
        return b


@njit(cache=True)
def _copy(src, dst, j0, j1):
    for j in range(j0, j1 + 1):
        dst[j] = src[j]


@njit(cache=True)
def _meeting_trial(pos, tmp, tmp2, mult, x0, load, su, sl, idx, p) -> bool:
    """Trial ``idx`` of two zones that meet: node idx stuck between them (1..N), or an all-slipping tendon split
    after node idx - N - 1 (N+1..2N+1). On success the state lands in tmp."""
    n = int(p[K_N])
    if idx <= n:
        c = idx
        ok, t_servo = _servo_zone(pos, tmp, mult, x0, load, c - 1, su, p)
        if not ok:
            return False
        ok, t_wing = _load_zone(pos, tmp2, mult, load, c, sl, p)
        if not ok or not _in_band(t_servo, t_wing, p[K_R]):
            return False
        _copy(tmp2, tmp, c, n + 1)
        return True
    k = idx - n - 1
    if su == sl and k != n:
        return False
    return _all_slip(pos, tmp, mult, x0, load, k, su, sl, p)


@njit(cache=True, inline="always")
def _jslot(su: float, sl: float) -> int:
    return S_JHINT + (2 if su > 0.0 else 0) + (1 if sl > 0.0 else 0)


@njit(cache=True, inline="always")
def _hint_node(h: float, n: int) -> int:
    """The node a stored meeting configuration is about (its stuck node, or the split)."""
    i = int(h)
    return i if i <= n else i - n - 1


@njit(cache=True)
def _meeting(pos, tmp, tmp2, mult, st, x0, load, su, sl, b, reach, p) -> bool:
    """Servo and load zones that meet: stuck nodes and splits outwards from node b, up to ``reach`` nodes away;
    the first consistent one lands in tmp."""
    n = int(p[K_N])
    slot = _jslot(su, sl)
    for d in range(min(reach, n + 1) + 1):
        for side in range(2):
            if d == 0 and side == 1:
                continue
            c = b + d if side == 0 else b - d
            if 1 <= c <= n and _meeting_trial(pos, tmp, tmp2, mult, x0, load, su, sl, c, p):
                st[slot] = c
                return True
            if 0 <= c <= n and _meeting_trial(pos, tmp, tmp2, mult, x0, load, su, sl, n + 1 + c, p):
                st[slot] = n + 1 + c
                return True
    return False


@njit(cache=True)
def _advance(pos, tmp, tmp2, mult, st, x0, load, p, use_hint):
    """One sample: the servo end to x0 and the load to ``load``, solved together (rate independent)."""
    n = int(p[K_N])
    su = 0.0 if x0 == pos[0] else (1.0 if x0 > pos[0] else -1.0)
    sl = 0.0 if load == st[S_LOAD] else (1.0 if load < st[S_LOAD] else -1.0)
    if su == 0.0 and sl == 0.0:
        return
    if sl == 0.0:
        m = _search_servo(pos, tmp, mult, st, x0, load, su, p, use_hint, True)
        _copy(tmp, pos, 0, n + 1 if m == n else m)
    elif su == 0.0:
        b = _search_load(pos, tmp, mult, st, load, sl, p, use_hint, True)
        _copy(tmp, pos, b, n + 1)
    elif use_hint and st[_jslot(su, sl)] > 0 and _meeting(pos, tmp, tmp2, mult, st, x0, load, su, sl,
                                                          _hint_node(st[_jslot(su, sl)], n), 1, p):
        _copy(tmp, pos, 0, n + 1)  # the zones met where they met last time (or a node away)
    else:
        m = _search_servo(pos, tmp, mult, st, x0, load, su, p, use_hint, False)
        b = _search_load(pos, tmp2, mult, st, load, sl, p, use_hint, False)
        if m + 1 < b:  # the two zones stay apart: each as found
            st[_jslot(su, sl)] = 0.0
            _copy(tmp, pos, 0, m)
            _copy(tmp2, pos, b + 1, n + 1)
        elif _meeting(pos, tmp, tmp2, mult, st, x0, load, su, sl, b, n + 1, p):
            _copy(tmp, pos, 0, n + 1)
        else:  # never seen; fall back to the servo move, then the load change
            st[S_BAD] += 1.0
            m = _search_servo(pos, tmp, mult, st, x0, st[S_LOAD], su, p, False, False)
            _copy(tmp, pos, 0, n + 1 if m == n else m)
            b = _search_load(pos, tmp, mult, st, load, sl, p, False, False)
            _copy(tmp, pos, b, n + 1)
    st[S_LOAD] = load


@njit(cache=True)
def _run1(pos, st, p, x0, load, use_hint) -> float:
    """One sample (the per-sample path, without array arguments); returns the warp (deg)."""
    tmp = np.empty_like(pos)
    tmp2 = np.empty_like(pos)
    mult = np.empty_like(pos)
    _advance(pos, tmp, tmp2, mult, st, x0, load, p, use_hint)
    return (pos[int(p[K_N]) + 1] + p[K_XWREST]) / p[K_MMDEG]


@njit(cache=True)
def _run(pos, st, p, x0, load, out, use_hint):
    """Advance the state through samples x0[i] (servo end from rest, mm) and load[i] (N); warp (deg) into out."""
    n = int(p[K_N])
    tmp = np.empty_like(pos)
    tmp2 = np.empty_like(pos)
    mult = np.empty_like(pos)
    for i in range(x0.shape[0]):
        _advance(pos, tmp, tmp2, mult, st, x0[i], load[i], p, use_hint)
        out[i] = (pos[n + 1] + p[K_XWREST]) / p[K_MMDEG]


# ---------------------------------------------------------------------------------------------------------------
# Python side
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SheathParams:
    """One tendon-sheath wing rig. Units: N, mm, deg."""

    bend_deg: float  # total wrap angle of the sheath route, deg
    mu: float  # tendon-sheath Coulomb friction coefficient
    n_segments: int  # friction nodes along the sheath
    k_tendon: float  # axial stiffness of the whole tendon, N/mm
    k_wing: float  # wing stiffness at the tendon's far end, N per mm of far-end travel
    pretension_n: float  # tension all along the tendon at rest, N
    mm_per_deg: float  # far-end tendon travel per degree of warp, mm/deg
    hardening: float = 0.0  # relative stiffening of the wing per 10 deg of warp (0 = linear)
    slack_mm: float = 0.0  # tendon travel taken up as a loose tendon straightens in its sheath, mm
    slack_n: float = 1.0  # tension at which half of slack_mm is taken up, N

    def __post_init__(self) -> None:
        finite = all(math.isfinite(float(v)) for v in dataclasses.astuple(self))
        if not finite:
            raise ValueError("sheath parameters must be finite")
        if int(self.n_segments) != self.n_segments or self.n_segments < 1:
            raise ValueError(f"n_segments must be a whole number >= 1, got {self.n_segments}")
        if self.bend_deg < 0 or self.mu < 0:
            raise ValueError("bend_deg and mu cannot be negative")
        if self.mu * math.radians(self.bend_deg) > 20.0:
            raise ValueError("mu * bend is beyond any real sheath (capstan ratio above exp(20))")
        if self.k_tendon <= 0 or self.k_wing <= 0 or self.mm_per_deg <= 0 or self.slack_n <= 0:
            raise ValueError("k_tendon, k_wing, mm_per_deg and slack_n must be positive")
        if self.pretension_n < 0 or self.hardening < 0 or self.slack_mm < 0:
            raise ValueError("pretension_n, hardening and slack_mm cannot be negative")

    def with_changes(self, **kw) -> SheathParams:
        """The same rig with some fields changed (e.g. friction or pre-tension changed in the field)."""
        return dataclasses.replace(self, **kw)

    @property
    def capstan_ratio(self) -> float:
        """Servo-end over far-end tension while the whole tendon slides in (exp(mu * bend))."""
        return math.exp(self.mu * math.radians(self.bend_deg))


def _kernel_params(p: SheathParams) -> np.ndarray:
    n = int(p.n_segments)
    k = np.zeros(N_KPARAMS)
    k[K_N] = n
    k[K_KSEG] = p.k_tendon * (n + 1)
    k[K_SSEG] = p.slack_mm / (n + 1)
    k[K_TS] = p.slack_n
    k[K_R] = math.exp(p.mu * math.radians(p.bend_deg) / n)
    k[K_KW] = p.k_wing
    k[K_AH] = p.hardening / (20.0 * p.mm_per_deg)  # tangent stiffness k_wing (1 + hardening * w / 10 deg)
    k[K_MMDEG] = p.mm_per_deg
    k[K_EREST] = float(_seg_e(p.pretension_n, k))
    k[K_XWREST] = float(_wing_x(p.pretension_n, k))
    return k


class SheathPlant:
    """A tendon-sheath wing: ``step(u_mm, load_n) -> warp_deg`` per sample, ``simulate`` for arrays."""

    def __init__(self, params: SheathParams, u0: float = 0.0) -> None:
        self.params = params
        self._p = _kernel_params(params)
        n = int(params.n_segments)
        self._pos = np.zeros(n + 2)
        self._st = np.zeros(N_SSTATE)
        self._out = np.zeros(1)
        self._use_hint = True
        self.u0 = 0.0
        self.reset(u0)

    def reset(self, u0: float = 0.0) -> None:
        """At rest at tendon travel u0: pre-tension all along, no load, no stress locked in by friction."""
        if not math.isfinite(u0):
            raise ValueError("u0 must be finite")
        self.u0 = float(u0)
        self._pos[:] = 0.0
        self._st[:] = 0.0
        self._warp = self.rest_warp

    def copy(self) -> SheathPlant:
        """An independent plant in the same state (to branch a simulation)."""
        other = SheathPlant(self.params, self.u0)
        other._pos[:] = self._pos
        other._st[:] = self._st
        other._warp = self._warp
        other._use_hint = self._use_hint
        return other

    @property
    def rest_warp(self) -> float:
        """Warp (deg) at rest: the pre-tension's own pull on the wing."""
        return float(self._p[K_XWREST] / self._p[K_MMDEG])

    @property
    def warp(self) -> float:
        """Warp (deg) after the last sample."""
        return self._warp

    @property
    def tensions(self) -> np.ndarray:
        """Tension (N) of the N + 1 tendon segments, servo end first."""
        er = self._p[K_EREST]
        return np.array([_seg_t(er + self._pos[j - 1] - self._pos[j], self._p) for j in range(1, len(self._pos))])

    @property
    def fallbacks(self) -> int:
        """Samples the exact solver could not place and solved as a servo move followed by the load change
        (none seen in testing; a count for tests and benchmarks to check)."""
        return int(self._st[S_BAD])

    @property
    def load(self) -> float:
        """The external load (N) of the last sample."""
        return float(self._st[S_LOAD])

    def step(self, u: float, load_n: float = 0.0) -> float:
        """One sample: tendon travel u (mm) and load (N) -> warp (deg)."""
        u, load_n = float(u), float(load_n)
        if not (math.isfinite(u) and math.isfinite(load_n)):
            raise ValueError("tendon travel and load must be finite")
        self._warp = float(_run1(self._pos, self._st, self._p, u - self.u0, load_n, self._use_hint))
        return self._warp

    def simulate(self, u, load_n=0.0) -> np.ndarray:
        """Warp (deg) for each sample of u (mm), with the load (N, scalar or array); continues from the state."""
        u = np.ascontiguousarray(u, dtype=np.float64).reshape(-1)
        load = np.ascontiguousarray(np.broadcast_to(np.asarray(load_n, dtype=np.float64), u.shape))
        if not (np.all(np.isfinite(u)) and np.all(np.isfinite(load))):
            raise ValueError("tendon travel and load must be finite")
        out = np.empty_like(u)
        if u.size:
            _run(self._pos, self._st, self._p, u - self.u0, load, out, self._use_hint)
            self._warp = float(out[-1])
        return out

    def travel_range(self, w_max_deg: float, step_mm: float = 0.002) -> tuple[float, float]:
        """(u_lo, u_hi), mm: pulling from a slack tendon reaches w_max_deg at u_hi, releasing from there returns
        the wing to zero warp at u_lo; sweeping u_lo..u_hi spans warp 0..w_max on both branches (no load)."""
        if not (math.isfinite(w_max_deg) and w_max_deg > 0):
            raise ValueError("w_max_deg must be positive")
        plant = SheathPlant(self.params, self.u0)
        span = w_max_deg * self.params.mm_per_deg
        # release from rest until the tendon is slack (the wing back at its unloaded shape)
        u = self.u0
        for _ in range(200):
            u -= span
            plant.step(u)
            if plant.tensions.max() < 1e-9:
                break
        else:
            raise RuntimeError("tendon never went slack")
        u_start = u
        u_hi = _crossing(plant, u_start, +1, w_max_deg, step_mm)
        u_lo = _crossing(plant, u_hi, -1, 0.0, step_mm)
        return u_lo, u_hi


def _crossing(plant: SheathPlant, u_from: float, s: int, w_target: float, step_mm: float) -> float:
    """Sweep u from u_from in direction s until the warp crosses w_target; the crossing by interpolation."""
    u_prev, w_prev = u_from, plant.step(u_from)
    for _ in range(100):
        seg = u_prev + s * step_mm * np.arange(1, 2001)
        w = plant.simulate(seg)
        hit = np.nonzero(w >= w_target)[0] if s > 0 else np.nonzero(w <= w_target + 1e-12)[0]
        if hit.size:
            i = int(hit[0])
            wa, ua = (w[i - 1], seg[i - 1]) if i else (w_prev, u_prev)
            wb, ub = w[i], seg[i]
            if wb == wa:
                return float(ub)
            return float(ua + (w_target - wa) * (ub - ua) / (wb - wa))
        u_prev, w_prev = float(seg[-1]), float(w[-1])
    raise RuntimeError(f"warp {w_target} deg not reached within {200000 * step_mm} mm of tendon")


def rigged_sheath() -> SheathParams:
    """The SITL's default rig: a small UAV membrane wing on the paper's 270 deg sheath route.

    A braided line in a plastic-lined sheath (mu 0.25, capstan ratio 3.3; 3 N/mm over the route including the
    sheath's own compression, 2 mm of take-up straightened by ~1 N), a wing needing ~3.6 N of pull for 10 deg
    (0.3 mm of trailing-edge travel per deg), 0.3 N of pre-tension (0.8 deg of warp at rest). Warp 0..10 deg
    spans about 7 mm of tendon; the loop is about 2 mm wide in tendon at 10 deg (1.2 mm at 5 deg)."""
    return SheathParams(bend_deg=270.0, mu=0.25, n_segments=20, k_tendon=3.0, k_wing=1.2, pretension_n=0.3,
                        mm_per_deg=0.3, hardening=0.1, slack_mm=2.0, slack_n=0.6)


def random_sheath(rng: np.random.Generator) -> SheathParams:
    """A rig drawn over a wide physical range (uniform unless said; log-uniform for ratios of scale):

    bend 45..450 deg, mu 0.05..0.35 (log), so a capstan ratio of 1.04..16; 3..40 nodes; tendon 1..20 N/mm (log:
    a nylon line to a steel cable); wing 0.5..3 N/mm (log); pre-tension 0.1..2 N; 0.3..0.8 mm of far end per
    deg; wing hardening 0..0.6 per 10 deg; slack take-up 0..2 mm, half taken up at 0.3..2 N."""
    return SheathParams(
        bend_deg=float(rng.uniform(45.0, 450.0)),
        mu=float(np.exp(rng.uniform(math.log(0.05), math.log(0.35)))),
        n_segments=int(rng.integers(3, 41)),
        k_tendon=float(np.exp(rng.uniform(math.log(1.0), math.log(20.0)))),
        k_wing=float(np.exp(rng.uniform(math.log(0.5), math.log(3.0)))),
        pretension_n=float(rng.uniform(0.1, 2.0)),
        mm_per_deg=float(rng.uniform(0.3, 0.8)),
        hardening=float(rng.uniform(0.0, 0.6)),
        slack_mm=float(rng.uniform(0.0, 2.0)),
        slack_n=float(rng.uniform(0.3, 2.0)),
    )
