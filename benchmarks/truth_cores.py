"""Truth side of the diagnosis benchmark: hysteretic cores (tendon travel -> warp), with their own friction
and pre-tension parameters, and an aerodynamic load acting through them.

Nothing here imports ``warpbridge.model``. Each core maps the tendon travel
reaching the sheath, x (mm), to the true warp (deg). An aerodynamic moment on
the wing loads the tendon: it stretches it by ``q (c0 + c1 w)`` mm (q the
dynamic pressure in kPa, w the warp one sample earlier), so the load passes
through the friction like any other tendon motion. Friction and pre-tension
are properties of each core:

- ``bw_run``: the generalized Bouc-Wen law integrated over the tendon travel
  (dw/dx = 1 / g, dz/dx = f / g with g = du/dw along the branch; classical
  RK4 in x), not the project's forward map, which integrates over w and
  solves each sample with Newton steps. Its friction scales the saturation of
  z (the loop width, not the initial slope); pre-tension shifts the travel and
  stiffens the elastic part (a2).
- ``pi_run``: a Prandtl-Ishlinskii sum of play operators (the radii are the
  friction thresholds) through a hardening spring w = c0 + c1 (y + e0) +
  c2 (y + e0)^2; pre-tension moves the spring's operating point e0 and its
  stiffness c1.
- ``dahl_run``: a rate-independent Dahl friction element (friction level hc)
  in series with a hardening spring, pre-tension again the spring's operating
  point and stiffness.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def _sgn(x):
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return 0.0


@njit(cache=True)
def _bw_deriv(p, w, z, s):
    a1, a2, az, A, n = p[0], p[1], p[3], p[4], p[5]
    sw, sz = _sgn(w), _sgn(z)
    psi = p[6] * _sgn(s * z) + p[7] * sw * s + p[8] * sw * sz + p[9] * s + p[10] * sz + p[11] * sw
    az_ = abs(z)
    zn = math.exp(n * math.log(az_)) if az_ > 0 else 0.0
    f = A - zn * psi
    g = 2.0 * a1 * w + a2 + az * f
    g_min = 0.02 * a2  # beyond the model's monotone range the warp creeps on instead of exploding
    if g < g_min:
        g = g_min
    return 1.0 / g, f / g


@njit(cache=True)
def bw_rest_warp(p, x0, z0):
    """Warp at which u = a1 w^2 + a2 w + a3 + az z0 equals x0 on the rising branch."""
    a1, a2 = p[0], p[1]
    c = p[2] + p[3] * z0 - x0
    if abs(a1) < 1e-15:
        return -c / a2
    disc = a2 * a2 - 4.0 * a1 * c
    if disc < 0:
        return -a2 / (2.0 * a1)
    r = math.sqrt(disc)
    w1 = (-a2 + r) / (2.0 * a1)
    if 2.0 * a1 * w1 + a2 > 0:
        return w1
    return (-a2 - r) / (2.0 * a1)


@njit(cache=True)
def bw_run(p, x, q, c0, c1, z0, h_max):
    """Warp along tendon travel x: p = [a1, a2, a3, az, A, n, b1..b6]; aero stretch q (c0 + c1 w) mm."""
    n = x.shape[0]
    w_out = np.empty(n)
    xe = x[0] - q[0] * c0
    w = bw_rest_warp(p, xe, z0)
    z = z0
    xp = xe
    for k in range(n):
        xe = x[k] - q[k] * (c0 + c1 * w)
        dx = xe - xp
        m = int(abs(dx) / h_max) + 1
        h = dx / m
        s = _sgn(dx)
        if s != 0.0:
            for _ in range(m):
                k1w, k1z = _bw_deriv(p, w, z, s)
                k2w, k2z = _bw_deriv(p, w + 0.5 * h * k1w, z + 0.5 * h * k1z, s)
                k3w, k3z = _bw_deriv(p, w + 0.5 * h * k2w, z + 0.5 * h * k2z, s)
                k4w, k4z = _bw_deriv(p, w + h * k3w, z + h * k3z, s)
                w += h * (k1w + 2 * k2w + 2 * k3w + k4w) / 6.0
                z += h * (k1z + 2 * k2z + 2 * k3z + k4z) / 6.0
        xp = xe
        w_out[k] = w
    return w_out


def bw_saturation(p: np.ndarray) -> tuple[float, float]:
    """(z on a long loading run, z on a long unloading run) at positive warp; inf if z does not saturate."""
    b = p[6:12]
    psi_load = b[0] + b[1] + b[2] + b[3] + b[4] + b[5]  # w' > 0, z > 0, w > 0
    psi_unload = b[0] - b[1] - b[2] - b[3] - b[4] + b[5]  # w' < 0, z < 0, w > 0
    A, n = p[4], p[5]
    hi = (A / psi_load) ** (1 / n) if psi_load > 0 else math.inf
    lo = -(A / psi_unload) ** (1 / n) if psi_unload > 0 else -math.inf
    return hi, lo


@njit(cache=True)
def pi_run(x, radii, weights, c0, c1, c2, e0, q, a0, a1):
    """Prandtl-Ishlinskii core: plays start centred (as after a long rest at x[0])."""
    n = x.shape[0]
    m = radii.shape[0]
    out = np.empty(n)
    ys = np.empty(m)
    for i in range(m):
        ys[i] = x[0] - q[0] * a0
    w = 0.0
    for k in range(n):
        xe = x[k] - q[k] * (a0 + a1 * w) if k > 0 else x[0] - q[0] * a0
        y = 0.0
        for i in range(m):
            r = radii[i]
            if xe - r > ys[i]:
                ys[i] = xe - r
            elif xe + r < ys[i]:
                ys[i] = xe + r
            y += weights[i] * ys[i]
        e = y + e0
        w = c0 + c1 * e + c2 * e * e
        out[k] = w
    return out


@njit(cache=True)
def dahl_run(x, hc, a, k1, k2, c0, e0, h0, q, a0, a1):
    """Dahl friction element (rate independent, dh/dx = (1 - h/hc sgn dx)^a) in series with a spring."""
    n = x.shape[0]
    out = np.empty(n)
    h = h0
    xp = x[0] - q[0] * a0
    w = 0.0
    for k in range(n):
        xe = x[k] - q[k] * (a0 + a1 * w) if k > 0 else xp
        du = xe - xp
        mf = abs(du) / (0.01 * hc)
        m = 0
        if mf >= 10000.0:  # a step of more than 100 hc (friction scaled towards 0): the element saturates
            h = hc if du > 0 else -hc
        elif mf == mf:  # not NaN
            m = int(mf) + 1
        d = du / max(m, 1)
        for _ in range(m):
            s = 1.0 if d > 0 else -1.0
            g = 1.0 - h / hc * s
            if g < 0.0:
                g = 0.0
            h += d * g ** a
        xp = xe
        e = xe - h + e0
        w = c0 + k1 * e + k2 * e * e
        out[k] = w
    return out
