"""Truth side of the diagnosis benchmark: a tendon in a sheath with LuGre friction at each node (rate dependent).

Nothing here imports ``warpbridge.model`` nor ``sitl.sheath``: this is a second
sheath written from the mechanics in another form. The sheath route of wrap
``bend`` is ``n`` friction nodes, each bending the tendon by theta = bend / n;
the tendon runs from the servo end (travel x, positive = pull) over the nodes to
the wing's trailing edge in n + 1 elastic pieces (together ``k_tendon`` N/mm).
The nodes are massless: at each node the tension difference across it is the
friction of the sheath on the tendon there,

    T_servo_side - T_wing_side = theta (T_servo_side + T_wing_side) / 2 * phi,

the normal force of a belt bent by theta times a friction coefficient phi that
follows the LuGre law along the node's velocity v (mm/s): a bristle deflection z
with dz/dt = v - sigma0 |v| z / g(v), g(v) = mu_c + (mu_s - mu_c) exp(-(v / v_s)^2)
(Stribeck), and phi = sigma0 z + sigma1 exp(-(v / v_s)^2) dz/dt + mu_v v / V_REF
(bristle damping that fades with sliding, which keeps the law passive; a
lubricated sheath's viscous drag, per unit normal force). The Stribeck drop is
kept under what the viscous drag makes up, so that the steady friction grows
with speed: a massless node has no unique motion on a falling friction curve
(a real one stick-slips through its inertia). At slow steady slip phi -> mu_c and
the tension ratio across the sheath is the capstan law's exp(mu_c bend); at
speed the band widens with mu_v, and at a reversal the bristles give a smooth
pre-sliding turn. The far end pulls the trailing edge against the wing's
hardening stiffness (force k_wing p (1 + a_h p) at far-end travel p from the
wing's unloaded shape) and an aerodynamic load (N, positive = pushing the
trailing edge back) that follows the warp it bends; warp is p / mm_per_deg.

Each sample is integrated in ``SUBSTEPS`` semi-implicit Euler substeps (the
input interpolated linearly): each node's normal force and the bristles'
sliding rate are taken from the substep before, the motion implicitly, so the
n + 1 node equations are a tridiagonal linear system (the far end's hardening
spring linearised and solved again until it settles); no iteration can fail.
Positions are displacements from rest (tension ``t_rest`` all along, no
bristle deflection).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

V_REF = 20.0  # mm/s: the speed at which the viscous share mu_v is added to the friction coefficient
SUBSTEPS = 4
EPS_V = 1e-3  # mm/s: |v| is smoothed below this
PRE_RAMP_S = 1.0  # the rig is pulled from rest to the first sample's travel over this long before the log


@njit(cache=True)
def _substep(p, z, vel, x, h, load0, load1, prm, work) -> None:
    """Advance the node positions p, bristles z and node speeds vel over a substep h to servo travel x.

    Semi-implicit: each node's normal force, the bristles' sliding rate |v| / g(v) and the damping's fade
    come from the speed of the substep before; the rest is implicit, so each node's equation is linear in
    its own travel and the system is tridiagonal (the wing's hardening spring and the warp-following load
    are linearised and the solve repeated until the far end settles)."""
    n = p.size - 1
    k, theta, t_rest = prm[0], prm[1], prm[2]
    mu_c, mu_s, v_s, s0, s1, mu_v = prm[3], prm[4], prm[5], prm[6], prm[7], prm[8]
    kw, ah, p_rest, mmdeg = prm[9], prm[10], prm[11], prm[12]
    lo, di, up, rhs, alpha, beta, nrm, p_old, dd = (work[0], work[1], work[2], work[3], work[4], work[5], work[6],
                                                    work[7], work[8])
    for i in range(n + 1):
        p_old[i] = p[i]
    for i in range(n):
        left = x if i == 0 else p[i - 1]
        tl = t_rest + k * (left - p[i])
        tr = t_rest + k * (p[i] - p[i + 1])
        nrm[i] = 0.5 * theta * max(tl + tr, 0.0)  # a slack tendon presses on nothing
        v = vel[i]
        a = math.sqrt(v * v + EPS_V * EPS_V)
        e = math.exp(-(v / v_s) ** 2)
        g = mu_c + (mu_s - mu_c) * e
        d = 1.0 + h * s0 * a / g if g > 0.0 else 1.0
        dd[i] = d
        damp = s1 * e
        # phi = alpha + beta * (p_i - p_old_i): z1 = (z0 + dp) / d
        alpha[i] = s0 * z[i] / d + damp * z[i] * (1.0 / d - 1.0) / h
        beta[i] = s0 / d + damp / (d * h) + mu_v / (h * V_REF)
    for _ in range(20):
        for i in range(n):
            lo[i] = k
            di[i] = -2.0 * k - nrm[i] * beta[i]
            up[i] = k
            rhs[i] = nrm[i] * (alpha[i] - beta[i] * p_old[i])
        rhs[0] -= k * x  # the servo end is given
        # far end: t_rest + k (p[n-1] - p[n]) = kw pa (1 + ah pa) + load0 + load1 pa / mmdeg, linearised at p[n]
        pa = p_rest + p[n]
        f = kw * pa * (1.0 + ah * pa) + load0 + load1 * pa / mmdeg
        df = kw * (1.0 + 2.0 * ah * pa) + load1 / mmdeg
        lo[n] = k
        di[n] = -k - df
        up[n] = 0.0
        rhs[n] = -t_rest + f - df * p[n]
        if n == 0:
            rhs[n] -= k * x
        # Thomas algorithm
        for i in range(1, n + 1):
            m = lo[i] / di[i - 1]
            di[i] -= m * up[i - 1]
            rhs[i] -= m * rhs[i - 1]
        last = p[n]
        p[n] = rhs[n] / di[n]
        for i in range(n - 1, -1, -1):
            p[i] = (rhs[i] - up[i] * p[i + 1]) / di[i]
        if abs(p[n] - last) < 1e-12:
            break
    for i in range(n):
        dp = p[i] - p_old[i]
        z[i] = (z[i] + dp) / dd[i]
        vel[i] = dp / h


@njit(cache=True)
def lugre_run(t, x, q, c0, c1, prm, n):
    """Warp (deg) per sample of tendon travel x (mm, from rest) at times t (s), dynamic pressure q (kPa) with
    an aero load q (c0 + c1 w) N; also the lowest tendon tension met (N) and the tension of each tendon piece
    at the end (servo end first, N). ``prm`` as ``lugre_params``."""
    m = x.size
    out = np.empty(m)
    p = np.zeros(n + 1)
    z = np.zeros(n)
    vel = np.zeros(n)
    work = np.zeros((9, n + 1))
    k, t_rest, p_rest, mmdeg = prm[0], prm[2], prm[11], prm[12]
    t_min = t_rest
    # from rest to the first sample's travel, slowly
    ramp = 200 * SUBSTEPS
    hr = PRE_RAMP_S / ramp
    for j in range(1, ramp + 1):
        _substep(p, z, vel, x[0] * j / ramp, hr, 0.0, 0.0, prm, work)
    for s in range(m):
        if s > 0:
            h = (t[s] - t[s - 1]) / SUBSTEPS
            l0 = q[s] * c0
            l1 = q[s] * c1
            for j in range(1, SUBSTEPS + 1):
                _substep(p, z, vel, x[s - 1] + (x[s] - x[s - 1]) * j / SUBSTEPS, h, l0, l1, prm, work)
        out[s] = (p_rest + p[n]) / mmdeg
        for i in range(n + 1):
            left = x[s] if i == 0 else p[i - 1]
            tt = t_rest + k * (left - p[i])
            if tt < t_min:
                t_min = tt
    tensions = np.empty(n + 1)
    for i in range(n + 1):
        tensions[i] = t_rest + k * ((x[m - 1] if i == 0 else p[i - 1]) - p[i])
    return out, t_min, tensions


def wing_rest(t_rest: float, k_wing: float, a_h: float) -> float:
    """Far-end travel from the wing's unloaded shape at which the wing holds the tension at rest (mm)."""
    if a_h <= 0.0:
        return t_rest / k_wing
    return (-1.0 + math.sqrt(1.0 + 4.0 * a_h * t_rest / k_wing)) / (2.0 * a_h)


def lugre_params(bend_deg: float, n: int, k_tendon: float, t_rest: float, mu_c: float, mu_s: float, v_s: float,
                 bristle_mm: float, bristle_tau_s: float, mu_v: float, k_wing: float, hardening: float,
                 mm_per_deg: float) -> np.ndarray:
    """The kernel's parameter vector. ``bristle_mm``: the bristle deflection at which sliding starts
    (mu_c / sigma0); ``bristle_tau_s``: its damping time (sigma1 = sigma0 tau); ``hardening``: the wing's
    relative stiffening per 10 deg of warp."""
    s0 = mu_c / bristle_mm
    a_h = hardening / (20.0 * mm_per_deg)
    return np.array([k_tendon * (n + 1), math.radians(bend_deg) / n, t_rest, mu_c, mu_s, v_s, s0,
                     s0 * bristle_tau_s, mu_v, k_wing, a_h, wing_rest(t_rest, k_wing, a_h), mm_per_deg])
