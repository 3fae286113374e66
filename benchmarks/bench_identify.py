"""Benchmark: identification of 60 s, 500 Hz bench logs across excitation families and Bouc-Wen plants.

The truth side does not use the model's kernels: each plant is the generalized
Bouc-Wen model written again plainly (fixed-step RK4 in the tendon travel u,
where the system is not stiff: dw/du = 1/D, dz/du = f/D with D = du/dw > 0),
started 4 s before the log so that the log begins with the tendon loaded, with
0.05 deg of white sensor noise. Excitations (tendon input between the travel
that gives 2 and 12 deg on the loading branch): the paper's 1 Hz random,
a 3 Hz filtered random, a 1 Hz sine, a 0.1-3 Hz chirp, random steps and a
multisine. Each identification starts its search from a deliberately wrong
prior; it is scored on the log's held-out last quarter (what ``identify``
reports) and on a second log with another excitation that it never saw.

Per case: wall and CPU seconds (CPU counts both threads), the fit's held-out
RMS over the true noise (0.05 deg); the same with a previous revision of the
identification (``--baseline REV``, extracted from git into a temporary package
and run interleaved with the current code, so both see the same load); medians
and maxima; the load average before and after.
Run: python benchmarks/bench_identify.py [--baseline REV] [--plants a,b] [--families x,y] [--quick]
"""

from __future__ import annotations

import argparse
import importlib
import math
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit
from scipy import signal

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import table  # noqa: E402

from warpbridge.model import identification as current  # noqa: E402
from warpbridge.model.boucwen import BoucWenParams, forward  # noqa: E402
from warpbridge.model.initial_state import estimate_z0  # noqa: E402
from warpbridge.model.signals import reversal_indices  # noqa: E402

FS = 500.0
DURATION = 60.0
NOISE = 0.05
PREROLL_S = 4.0
REPO = Path(__file__).resolve().parents[1]


# ---- the truth: the generalized Bouc-Wen plant, written again -------------------------------

@dataclass(frozen=True)
class Plant:
    """u = a1 w^2 + a2 w + a3 + z (az = 1),  dz/dw = A - |z|^n psi(sgn w', sgn w, sgn z)."""

    name: str
    a1: float
    a2: float
    a3: float
    A: float
    n: float
    b: tuple[float, float, float, float, float, float]
    w_lo: float = 2.0
    w_hi: float = 12.0

    def array(self) -> np.ndarray:
        return np.array([self.a1, self.a2, self.a3, self.A, self.n, *self.b])


@njit(cache=True)
def _f(p, z, sdw, sw):
    sz = 1.0 if z > 0 else (-1.0 if z < 0 else 0.0)
    psi = p[5] * sdw * sz + p[6] * sw * sdw + p[7] * sw * sz + p[8] * sdw + p[9] * sz + p[10] * sw
    return p[3] - abs(z) ** p[4] * psi


@njit(cache=True)
def _rhs(p, w, z, sdw):
    sw = 1.0 if w > 0 else (-1.0 if w < 0 else sdw)
    f = _f(p, z, sdw, sw)
    d = 2.0 * p[0] * w + p[1] + f
    return 1.0 / d, f / d


@njit(cache=True)
def plain_forward(p, u, w0, z0, du_max):
    """Warp along tendon travel u: RK4 in u with steps of at most du_max (D = du/dw must stay > 0)."""
    w_out = np.empty(u.shape[0])
    w, z = w0, z0
    up = u[0]
    for k in range(u.shape[0]):
        delta = u[k] - up
        if delta != 0.0:
            sdw = 1.0 if delta > 0 else -1.0
            m = int(math.ceil(abs(delta) / du_max))
            h = delta / m
            for _ in range(m):
                a1, b1 = _rhs(p, w, z, sdw)
                a2, b2 = _rhs(p, w + 0.5 * h * a1, z + 0.5 * h * b1, sdw)
                a3, b3 = _rhs(p, w + 0.5 * h * a2, z + 0.5 * h * b2, sdw)
                a4, b4 = _rhs(p, w + h * a3, z + h * b3, sdw)
                w += h * (a1 + 2 * a2 + 2 * a3 + a4) / 6.0
                z += h * (b1 + 2 * b2 + 2 * b3 + b4) / 6.0
        up = u[k]
        w_out[k] = w
    return w_out


def plain_loading_span(plant: Plant, dw: float = 1e-3) -> tuple[float, float]:
    """Tendon travel giving w_lo and w_hi on the loading branch after a full unloading (Euler-free:
    RK4 over w on the inverse model, which is explicit)."""
    p = plant.array()

    def leg(w_from, w_to, z):
        sdw = 1.0 if w_to > w_from else -1.0
        ws = np.arange(w_from, w_to, sdw * dw)
        for w in ws:
            sw = 1.0 if w + 0.5 * sdw * dw > 0 else -1.0
            k1 = _f(p, z, sdw, sw)
            k2 = _f(p, z + 0.5 * sdw * dw * k1, sdw, sw)
            k3 = _f(p, z + 0.5 * sdw * dw * k2, sdw, sw)
            k4 = _f(p, z + sdw * dw * k3, sdw, sw)
            z += sdw * dw * (k1 + 2 * k2 + 2 * k3 + k4) / 6.0
        return z

    lo = min(0.0, plant.w_lo - 1.0)
    z = leg(plant.w_hi, lo, leg(lo, plant.w_hi, 0.0))  # settle on the unloading branch at the bottom
    z_at_lo = leg(lo, plant.w_lo, z)
    z_at_hi = leg(plant.w_lo, plant.w_hi, z_at_lo)
    u_of = lambda w, zz: plant.a1 * w * w + plant.a2 * w + plant.a3 + zz  # noqa: E731
    return u_of(plant.w_lo, z_at_lo), u_of(plant.w_hi, z_at_hi)


def paper_like(name: str, n: float, loop: float, A_scale: float = 1.0, a1_scale: float = 1.0,
               w_lo: float = 2.0, w_hi: float = 12.0) -> Plant:
    """The paper's model in the az = 1 gauge, with exponent n and the saturation of z scaled by ``loop``."""
    az, A, n0 = 0.5369, 3.9953, 3.1179
    b = np.array([19.8351, -8.6135, 0.8325, -3.1266, 10.6984, -18.5])
    # z -> az z: A -> az A, b -> az^(1-n) b (same output)
    A1, b1 = A * az, b * az ** (1 - n0)
    psi_load = b1[0] + b1[1] + b1[2] + b1[3] + b1[4] + b1[5]
    zsat = loop * (A1 / psi_load) ** (1 / n0)
    A2 = A1 * A_scale
    b2 = b1 / psi_load * A2 / zsat ** n  # same shape of psi, saturation zsat with exponent n
    return Plant(name, -0.0205 * a1_scale, 0.7120, 0.7958, A2, n, tuple(float(x) for x in b2), w_lo, w_hi)


PLANTS = {
    "paper": paper_like("paper", 3.1179, 1.0),
    "soft": paper_like("soft n=2, wide", 2.0, 1.4, A_scale=0.8),
    "stiff": paper_like("stiff n=4.5, narrow", 4.5, 0.6, A_scale=1.5),
    "lowwarp": paper_like("0.5-6 deg, flat", 2.6, 1.0, a1_scale=0.3, w_lo=0.5, w_hi=6.0),
}


# ---- excitations of the tendon ----------------------------------------------------------------

def _lowpass_random(t, cutoff, seed):
    rng = np.random.default_rng(seed)
    pad = int(FS / cutoff) * 4
    x = rng.standard_normal(t.size + 2 * pad)
    y = signal.sosfiltfilt(signal.butter(4, cutoff, fs=FS, output="sos"), x)[pad:pad + t.size]
    y -= y.mean()
    return y / np.max(np.abs(y))


def excitation(family: str, t: np.ndarray, seed: int) -> np.ndarray:
    """A signal in [-1, 1]."""
    rng = np.random.default_rng(seed)
    if family == "random1":  # the paper's: random, low-pass 1 Hz
        return _lowpass_random(t, 1.0, seed)
    if family == "random3":
        return _lowpass_random(t, 3.0, seed)
    if family == "sine":
        return np.sin(2 * np.pi * 1.0 * t - np.pi / 2)
    if family == "chirp":
        return signal.chirp(t - t[0], 0.1, t[-1] - t[0], 3.0, method="linear", phi=-90)
    if family == "steps":
        edges = np.cumsum(rng.uniform(0.5, 3.0, 200))
        levels = rng.uniform(-1, 1, edges.size + 1)
        return levels[np.searchsorted(edges, t - t[0])]
    if family == "multisine":
        y = 0.6 * np.sin(2 * np.pi * 0.4 * t) + 0.28 * np.sin(2 * np.pi * 1.1 * t + 1) + 0.12 * np.sin(
            2 * np.pi * 2.7 * t + 2)
        return y / np.max(np.abs(y))
    raise ValueError(family)


FAMILIES = ("random1", "random3", "sine", "chirp", "steps", "multisine")
CHECK_FAMILY = {"random1": "multisine", "random3": "sine", "sine": "random1", "chirp": "steps", "steps": "chirp",
                "multisine": "random1"}


def bench_log(plant: Plant, family: str, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t, u, w_meas, w_true) for 60 s at 500 Hz, after a pre-roll that leaves the tendon loaded."""
    u_lo, u_hi = plain_loading_span(plant)
    n_pre = int(PREROLL_S * FS)
    t_all = np.arange(n_pre + int(DURATION * FS)) / FS
    x = np.concatenate([_lowpass_random(t_all[:n_pre], 1.0, seed + 100), excitation(family, t_all[n_pre:], seed)])
    x[: n_pre // 4] = np.linspace(-1.0, x[n_pre // 4], n_pre // 4)  # from rest at the bottom of the span
    u = 0.5 * (u_lo + u_hi) + 0.5 * (u_hi - u_lo) * x
    p = plant.array()
    w_true = plain_forward(p, u, rest(plant, float(u[0])), 0.0, (u_hi - u_lo) / 4000.0)
    w_true = w_true[n_pre:]
    u = u[n_pre:]
    t = t_all[n_pre:] - t_all[n_pre]
    w_meas = w_true + NOISE * np.random.default_rng(seed + 7).standard_normal(t.size)
    return t, u, w_meas, w_true


def rest(plant: Plant, u0: float) -> float:
    """Warp at rest (z = 0) for tendon travel u0: the rising root of a1 w^2 + a2 w + a3 = u0."""
    a, b, c = plant.a1, plant.a2, plant.a3 - u0
    r = math.sqrt(b * b - 4 * a * c)
    return min(((-b + r) / (2 * a), (-b - r) / (2 * a)), key=lambda w: abs(w - plant.w_lo))


def truth_self_check(plant: Plant) -> float:
    """Largest change of the truth's warp when its step is quartered (its own integration error)."""
    u_lo, u_hi = plain_loading_span(plant)
    t = np.arange(int(10 * FS)) / FS
    x = excitation("random3", t, 1)
    x[:500] = np.linspace(-1.0, x[500], 500)
    u = 0.5 * (u_lo + u_hi) + 0.5 * (u_hi - u_lo) * x
    p = plant.array()
    w0 = rest(plant, float(u[0]))
    a = plain_forward(p, u, w0, 0.0, (u_hi - u_lo) / 4000.0)
    b = plain_forward(p, u, w0, 0.0, (u_hi - u_lo) / 16000.0)
    return float(np.max(np.abs(a - b)))


# ---- the code under test, current and previous ------------------------------------------------

def load_baseline(rev: str) -> object:
    """model/ at git revision ``rev`` (with its subpackages) as an importable package of its own (imports
    rewritten); its identification: the package ``model/identification/`` or, at older revisions, the module
    ``model/identify.py``."""
    root = Path(tempfile.mkdtemp(prefix="wb-baseline-"))
    pkg = root / "wb_baseline"
    (pkg / "model").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    files = subprocess.run(["git", "-C", str(REPO), "ls-tree", "-r", "--name-only", rev, "model/"], check=True,
                           capture_output=True, text=True).stdout.split()
    for f in files:
        if f.endswith(".py"):
            src = subprocess.run(["git", "-C", str(REPO), "show", f"{rev}:{f}"], check=True, capture_output=True,
                                 text=True).stdout
            (pkg / f).parent.mkdir(parents=True, exist_ok=True)
            (pkg / f).write_text(src.replace("warpbridge.model", "wb_baseline.model"))
    sys.path.insert(0, str(root))
    name = "identification" if "model/identification/__init__.py" in files else "identify"
    mod = importlib.import_module(f"wb_baseline.model.{name}")
    mod._bench_root = root
    return mod


@dataclass
class Run:
    wall: float
    cpu: float
    held_rms: float
    check_rms: float
    evaluations: int


def run_identify(ident, t, u, w, check, wrong, seed) -> Run:
    t0, c0 = time.perf_counter(), time.process_time()
    r = ident.identify(t, u, w, prior=wrong, seed=seed)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    tc, uc, wc, _ = check
    params = r.params
    z0 = estimate_z0(params, uc, wc)
    pred = forward(params, uc, z0=z0)[0]
    return Run(wall, cpu, r.heldout_rms, float(np.sqrt(np.mean((pred - wc) ** 2))), r.evaluations)


def loadavg() -> str:
    try:
        return open("/proc/loadavg").read().split()[0]
    except OSError:
        return "?"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", help="git revision whose identification runs beside the current one")
    ap.add_argument("--plants", default=",".join(PLANTS), help=f"comma-separated of {', '.join(PLANTS)}")
    ap.add_argument("--families", default=",".join(FAMILIES), help=f"comma-separated of {', '.join(FAMILIES)}")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    wrong = BoucWenParams(a1=-0.005, a2=0.5, a3=1.5, az=0.3, A=8.0, n=2.0, b=(5, -2, 1, -1, 3, -5))
    versions = {"new": current}
    if args.baseline:
        versions["old"] = load_baseline(args.baseline)
    # compile everything before timing
    t = np.arange(2000) / FS
    u = 4.5 + 2 * np.sin(2 * np.pi * t)
    for v in versions.values():
        v.identify(t, u, 5 + 2.5 * np.sin(2 * np.pi * t - 0.3), maxiter=2, polish_evals=20)
    print(f"{os.cpu_count()} CPUs, numba threads {os.environ.get('NUMBA_NUM_THREADS', 'default')}; "
          f"load average at start {loadavg()}")
    for name in args.plants.split(","):
        print(f"truth '{PLANTS[name].name}': integration error {truth_self_check(PLANTS[name]):.1e} deg "
              "(step vs quarter step)")
    rows, res = [], {k: [] for k in versions}
    for pi, name in enumerate(args.plants.split(",")):
        plant = PLANTS[name]
        for fi, fam in enumerate(args.families.split(",")):
            seed = args.seed + 10 * pi + fi
            t, u, w, _ = bench_log(plant, fam, seed)
            check = bench_log(plant, CHECK_FAMILY[fam], seed + 1000)
            rev = reversal_indices(u[: int(0.75 * u.size)]).size
            row = [plant.name, fam, rev]
            for key, ident in versions.items():
                r = run_identify(ident, t, u, w, check, wrong, seed)
                res[key].append(r)
                row += [r.wall, r.cpu, r.held_rms / NOISE, r.check_rms / NOISE]
            rows.append(row + [loadavg()])
            print("  ".join(str(x) if isinstance(x, (str, int)) else f"{x:.3g}" for x in row), flush=True)
    head = ["plant", "excitation", "reversals (train)"]
    for key in versions:
        head += [f"{key} wall s", f"{key} CPU s", f"{key} held/noise", f"{key} check/noise"]
    print()
    print("Held out: the log's last 15 s (what identify reports); check: a second 60 s log with another "
          "excitation, predicted whole with z0 estimated from its first samples. noise = 0.05 deg (true).")
    print(table(rows, head + ["load"]))
    print()
    for key, rs in res.items():
        walls = [r.wall for r in rs]
        cpus = [r.cpu for r in rs]
        held = [r.held_rms / NOISE for r in rs]
        chk = [r.check_rms / NOISE for r in rs]
        print(f"{key}: wall median {statistics.median(walls):.1f} s, max {max(walls):.1f} s, max/min "
              f"{max(walls) / min(walls):.2f}; CPU median {statistics.median(cpus):.1f} s, max {max(cpus):.1f} s, "
              f"max/min {max(cpus) / min(cpus):.2f}; held-out/noise median {statistics.median(held):.3f}, "
              f"max {max(held):.3f}; check/noise median {statistics.median(chk):.3f}, max {max(chk):.3f}")
    if "old" in res:
        ratio = [o.cpu / n.cpu for o, n in zip(res["old"], res["new"], strict=True)]
        print(f"CPU old/new per case: median {statistics.median(ratio):.2f}x, min {min(ratio):.2f}x, "
              f"max {max(ratio):.2f}x")
        shutil.rmtree(versions["old"]._bench_root, ignore_errors=True)
    print(f"load average at end {loadavg()} (2 cores shared; wall times scale with it, CPU times much less)")


if __name__ == "__main__":
    main()
