"""Benchmark: one forward simulation (tendon -> warp) of 60 s at 500 Hz, compiled vs plain Python.

The baseline is what a competent engineer without numba would write: the same
algorithm (per sample, a safeguarded Newton solve of u(w) = u on the monotone
branch; z integrated over w in sub-steps sized by the local stiffness and an
error estimate, RK4 / Heun / Kutta-3 or an L-stable step at saturation) written
plainly below on Python floats, tuples and a list, with ``math``. It is checked
against the compiled kernel on the same input (the largest warp difference is
printed: it must be at rounding level, or the two do different work). For
reference only, the kernel's own code with numba's JIT disabled (a subprocess with
NUMBA_DISABLE_JIT=1, every operation on numpy scalars) is timed too; it is slower
than the plain baseline and is not the ratio we report. Medians of repeated runs.
Target: under 10 ms for the whole 60 s compiled.

Run: python benchmarks/bench_forward.py [--no-jit-off]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import median_time, table  # noqa: E402

FS, T = 500.0, 60.0

# ---------------------------------------------------------------- the plain-Python forward map

H_MAX = 0.25  # deg, longest sub-step in w
K_STIFF = 1.5  # longest sub-step in units of 1 / |df/dz|
TOL_Z = 1e-8  # local error allowed per sub-step (units of z)
NEWTON_ACCEPT = 1e-6


def sgn(x: float) -> float:
    return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)


def psi(b: tuple, sdw: float, sw: float, sz: float) -> float:
    return b[0] * sdw * sz + b[1] * sw * sdw + b[2] * sw * sz + b[3] * sdw + b[4] * sz + b[5] * sw


def dzdw(p: tuple, z: float, sdw: float, sw: float) -> float:
    A, n, b = p[4], p[5], p[6:]
    return A if z == 0.0 else A - abs(z) ** n * psi(b, sdw, sw, sgn(z))


def rk4_limit(jac: float, f: float, h: float) -> float:
    if h * jac > K_STIFF:
        h = K_STIFF / jac
    x = h * jac
    if f > 0.0 and x ** 5 * f > 120.0 * TOL_Z * jac:
        h = (120.0 * TOL_Z * jac / f) ** 0.2 / jac
    return h


def integrate_z(p: tuple, w0: float, z0: float, w1: float) -> float:
    """z after moving monotonically from (w0, z0) to w1, in controlled sub-steps."""
    if w1 == w0:
        return z0
    A, n, b = p[4], p[5], p[6:]
    sdw = 1.0 if w1 > w0 else -1.0
    w, z = w0, z0
    for _ in range(20_000):
        remaining = (w1 - w) * sdw
        if remaining <= 0.0:
            return z
        h, last = H_MAX, False
        if h >= remaining:
            h, last = remaining, True
        if w * sdw < 0.0 and h > -w * sdw:  # never step across w = 0
            h, last = -w * sdw, False
        sw = sgn(w + 0.5 * h * sdw)
        az = abs(z)
        implicit = False
        js = jac = inv_z = 0.0
        if az > 0.0:
            zn = az ** n
            ps = psi(b, sdw, sw, sgn(z))
            k1 = A - zn * ps
            inv_z = 1.0 / z
            js = -n * zn * inv_z * ps * sdw
            jac = abs(js)
            if jac > 0.0:
                f = abs(k1)
                h_rk = rk4_limit(jac, f, h)
                if js < 0.0 and h * f <= 0.05 * az:  # resting near saturation: L-stable step
                    h_be = h if h * h * jac * f <= 2.0 * TOL_Z else math.sqrt(2.0 * TOL_Z / (jac * f))
                    if h_be >= h_rk:
                        h, implicit = h_be, True
                if not implicit and h_rk < h:
                    h, last = h_rk, False
                elif implicit and h < remaining:
                    last = False
        else:
            k1 = A
        if not implicit:  # bound the step by the stiffness where an Euler step would land
            for _ in range(60):
                if h * abs(k1) <= 0.25 * az:
                    break
                ze = z + h * sdw * k1
                if ze == 0.0:
                    break
                zne = abs(ze) ** n
                pse = psi(b, sdw, sw, sgn(ze))
                je = n * zne / abs(ze) * abs(pse)
                if je == 0.0:
                    break
                h_lim = rk4_limit(je, max(abs(k1), abs(A - zne * pse)), h)
                if h <= h_lim:
                    break
                h, last = h_lim, False
        hs = h * sdw
        order = 4
        if not implicit and az > 0.0 and h * abs(k1) <= 0.05 * az:  # cheapest method within tolerance
            f = abs(k1)
            f2 = abs((n - 1.0) * inv_z * js)
            if h ** 3 * (jac * jac * f + f2 * f * f) <= 3.0 * TOL_Z:
                order = 2
            else:
                f3 = abs((n - 2.0) * inv_z) * f2
                if h ** 4 * (jac ** 3 * f + 4.0 * f2 * jac * f * f + f3 * f ** 3) <= 12.0 * TOL_Z:
                    order = 3
        if implicit:
            z = z + hs * k1 / (1.0 - h * js)
        elif order == 2:
            k2 = dzdw(p, z + hs * k1, sdw, sw)
            z = z + 0.5 * hs * (k1 + k2)
        elif order == 3:
            k2 = dzdw(p, z + 0.5 * hs * k1, sdw, sw)
            k3 = dzdw(p, z + hs * (2.0 * k2 - k1), sdw, sw)
            z = z + hs * (k1 + 4.0 * k2 + k3) / 6.0
        else:
            k2 = dzdw(p, z + 0.5 * hs * k1, sdw, sw)
            k3 = dzdw(p, z + 0.5 * hs * k2, sdw, sw)
            k4 = dzdw(p, z + hs * k3, sdw, sw)
            z = z + hs * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0
        if not abs(z) < 1e6:
            return math.nan
        if last:
            return z
        w += hs
        if (w1 - w) * sdw <= 0.0:
            return z
    return math.nan


def u_of(p: tuple, w: float, z: float) -> float:
    return p[0] * w * w + p[1] * w + p[2] + p[3] * z


def forward_step(p: tuple, w0: float, z0: float, u: float) -> tuple[float, float]:
    """Warp (and z) where the tendon reaches u, moving from (w0, z0): Newton inside a bracket."""
    du = u - u_of(p, w0, z0)
    if du == 0.0:
        return w0, z0
    a1, a2, az, A = p[0], p[1], p[3], p[4]
    sdw = 1.0 if du > 0.0 else -1.0
    scale = abs(a2) + abs(az * A) + 1e-12
    tol_u = 1e-13 * (abs(u) + scale)
    d0 = 2.0 * a1 * w0 + a2 + az * dzdw(p, z0, sdw, sgn(w0) if w0 != 0.0 else sdw)
    if d0 <= 1e-12 * scale:
        d0 = scale
    step = du / d0
    w = w0 + step
    if z0 != 0.0:  # second-order first guess
        zn0 = abs(z0) ** p[5]
        ps0 = psi(p[6:], sdw, sgn(w0) if w0 != 0.0 else sdw, sgn(z0))
        d1 = 2.0 * a1 + az * (-p[5] * zn0 / z0 * ps0) * (A - zn0 * ps0)
        corr = 1.0 - 0.5 * d1 * step / d0
        if 0.5 < corr < 1.5:
            w = w0 + step * corr
    lo, lo_z, hi = w0, z0, math.nan
    saturated = False
    for _ in range(100):
        z = integrate_z(p, w0, z0, w)
        if z != z:
            hi, w = w, 0.5 * (lo + w)
            continue
        g = u_of(p, w, z) - u
        if abs(g) <= tol_u:
            return w, z
        f_end = dzdw(p, z, sdw, sgn(w) if w != 0.0 else sdw)
        d = 2.0 * a1 * w + a2 + az * f_end
        if g * sdw < 0.0:
            if d <= 0.0:  # past the turning point of u(w)
                hi, saturated = w, True
            else:
                lo, lo_z = w, z
        else:
            hi = w
        if hi == hi and abs(hi - lo) <= 1e-13 * (abs(lo) + 1.0):
            break
        wn = w - g / d if d > 0.0 else math.nan
        inside_hi = hi != hi or ((wn - lo) * sdw > 0.0 and (hi - wn) * sdw > 0.0)
        if wn == wn and abs(wn - w) <= NEWTON_ACCEPT * (abs(w) + 1.0) and inside_hi:
            return wn, z + f_end * (wn - w)
        if hi == hi:
            if not (wn == wn and (wn - lo) * sdw > 0.0 and (hi - wn) * sdw > 0.0) or saturated:
                wn = 0.5 * (lo + hi)
        elif wn != wn or (wn - lo) * sdw <= 0.0:
            wn = lo + 2.0 * (lo - w0) + sdw * 1e-6 * (abs(lo) + 1.0)
        w = wn
        if saturated and hi == hi:  # the edge of the monotone range: bisect on the slope
            for _ in range(80):
                wm = 0.5 * (lo + hi)
                zm = integrate_z(p, w0, z0, wm)
                slope = 2.0 * a1 * wm + a2 + az * dzdw(p, zm, sdw, sgn(wm) if wm != 0.0 else sdw)
                if zm == zm and slope > 0.0 and (u_of(p, wm, zm) - u) * sdw < 0.0:
                    lo, lo_z = wm, zm
                else:
                    hi = wm
                if abs(hi - lo) <= 1e-13 * (abs(lo) + 1.0):
                    break
            return lo, lo_z
    return lo, lo_z


def forward_plain(p: tuple, u: list, w0: float, z0: float) -> list:
    """The forward map over a list of tendon positions (mm): a list of warps (deg)."""
    out = []
    w, z = w0, z0
    for uk in u:
        w, z = forward_step(p, w, z, uk)
        out.append(w)
    return out


# ---------------------------------------------------------------- the kernel with the JIT off (reference)

CHILD = r"""
import json, time
import numpy as np
from warpbridge.model.boucwen import BoucWenParams
from warpbridge.model import kernels as K
from warpbridge.model.excitation import filtered_random
t = np.arange(0, %(T)r * %(FS)r) / %(FS)r
u = filtered_random(t, 1.0, 2.5, offset=4.5, seed=1)
p = BoucWenParams.paper().to_array()
w = np.empty_like(u); z = np.empty_like(u)
times = []
for _ in range(3):
    t0 = time.perf_counter(); K.forward_run(p, u, 5.0, 0.0, w, z); times.append(time.perf_counter() - t0)
print(json.dumps({"run_s": sorted(times)[1]}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--no-jit-off", action="store_true", help="skip the JIT-off reference run")
    ap.add_argument("--repeats", type=int, default=5, help="plain-Python runs (median)")
    args = ap.parse_args()

    from warpbridge.model import kernels as K
    from warpbridge.model.boucwen import BoucWenParams, forward, inverse
    from warpbridge.model.excitation import filtered_random

    t = np.arange(0, T * FS) / FS
    u = filtered_random(t, 1.0, 2.5, offset=4.5, seed=1)
    p = BoucWenParams.paper()
    pa = p.to_array()
    w = np.empty_like(u)
    z = np.empty_like(u)
    fwd, _ = median_time(lambda: K.forward_run(pa, u, 5.0, 0.0, w, z), repeats=15)
    wf, _, _ = forward(p, u)
    inv, _ = median_time(lambda: inverse(p, wf), repeats=15)

    p_plain = tuple(float(x) for x in pa)
    u_list = [float(x) for x in u]
    print(f"running the plain-Python forward map ({args.repeats} runs of {u.size} samples) ...", file=sys.stderr)
    plain, _ = median_time(lambda: forward_plain(p_plain, u_list, 5.0, 0.0), repeats=args.repeats, warmup=0)
    K.forward_run(pa, u, 5.0, 0.0, w, z)
    agree = float(np.max(np.abs(np.asarray(forward_plain(p_plain, u_list, 5.0, 0.0)) - w)))

    rows = [
        ["forward 60 s @ 500 Hz (compiled)", fwd * 1e3, "ms", "< 10 ms"],
        ["forward 60 s @ 500 Hz (plain Python: floats, lists, math)", plain * 1e3, "ms", ""],
        ["plain Python vs compiled, largest warp difference", agree, "deg", "rounding"],
        ["inverse 60 s @ 500 Hz (compiled)", inv * 1e3, "ms", ""],
        ["forward per sample, compiled", fwd / u.size * 1e9, "ns", ""],
        ["speed ratio plain Python / compiled", plain / fwd, "x", ""],
    ]
    if not args.no_jit_off:
        env = dict(os.environ, NUMBA_DISABLE_JIT="1")
        print("running the kernel with the JIT off (reference, about a second per run) ...", file=sys.stderr)
        out = subprocess.run([sys.executable, "-c", CHILD % {"T": T, "FS": FS}], env=env,
                             capture_output=True, text=True, check=True)
        jit_off = json.loads(out.stdout.strip().splitlines()[-1])["run_s"]
        rows.append(["(reference) kernel code with the JIT off, numpy scalars", jit_off * 1e3, "ms", ""])
        rows.append(["(reference) JIT-off / compiled", jit_off / fwd, "x", ""])
    print(table(rows, ["what", "median", "unit", "target"]))
    print(f"\n{u.size} samples (60 s at 500 Hz, the paper's plant, filtered random tendon input); "
          "baseline: the plain-Python forward map above (same algorithm).")


if __name__ == "__main__":
    main()
