"""Benchmark: one forward simulation (tendon -> warp) of 60 s at 500 Hz, compiled vs a plain-Python loop.

The plain-Python baseline is the very same kernel code run with numba's JIT
disabled (a subprocess with NUMBA_DISABLE_JIT=1) on the same 60 s input, so the
ratio is like for like (medians of repeated runs on both sides). Targets
(issue 2): at least 100x, and under 10 ms for the whole 60 s.
Run: python benchmarks/bench_forward.py
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import median_time, table  # noqa: E402

FS, T = 500.0, 60.0

CHILD = r"""
import json, sys, time
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
print(json.dumps({"run_s": sorted(times)[1], "per_sample": sorted(times)[1] / u.size}))
"""


def main() -> None:
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
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    print("running the plain-Python loop (about a second per run) ...", file=sys.stderr)
    out = subprocess.run([sys.executable, "-c", CHILD % {"T": T, "FS": FS}], env=env,
                         capture_output=True, text=True, check=True)
    plain_run = json.loads(out.stdout.strip().splitlines()[-1])["run_s"]
    ratio = plain_run / fwd
    rows = [
        ["forward 60 s @ 500 Hz (compiled)", fwd * 1e3, "ms", "< 10 ms"],
        ["forward 60 s @ 500 Hz (plain Python: same code, JIT off)", plain_run * 1e3, "ms", ""],
        ["inverse 60 s @ 500 Hz (compiled)", inv * 1e3, "ms", ""],
        ["forward per sample, compiled", fwd / u.size * 1e9, "ns", ""],
        ["speed ratio plain / compiled", ratio, "x", ">= 100x"],
    ]
    print(table(rows, ["what", "median", "unit", "target"]))


if __name__ == "__main__":
    main()
