"""Benchmark: one forward simulation (tendon -> warp) of 60 s at 500 Hz, compiled vs a plain-Python loop.

The plain-Python baseline is the very same kernel code run with numba's JIT
disabled (a subprocess with NUMBA_DISABLE_JIT=1) on the first 3 s of the same
input; per-sample costs are compared, so the ratio is like for like. Targets
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
PLAIN_SECONDS = 3.0

CHILD = r"""
import json, sys, time
import numpy as np
from model.boucwen import BoucWenParams
from model import kernels as K
from model.excitation import filtered_random
t = np.arange(0, %(T)r * %(FS)r) / %(FS)r
u = filtered_random(t, 1.0, 2.5, offset=4.5, seed=1)[: int(%(PS)r * %(FS)r)]
p = BoucWenParams.paper().to_array()
w = np.empty_like(u); z = np.empty_like(u)
times = []
for _ in range(3):
    t0 = time.perf_counter(); K.forward_run(p, u, 5.0, 0.0, w, z); times.append(time.perf_counter() - t0)
print(json.dumps({"per_sample": sorted(times)[1] / u.size}))
"""


def main() -> None:
    from model import kernels as K
    from model.boucwen import BoucWenParams, forward, inverse
    from model.excitation import filtered_random

    t = np.arange(0, T * FS) / FS
    u = filtered_random(t, 1.0, 2.5, offset=4.5, seed=1)
    p = BoucWenParams.paper()
    pa = p.to_array()
    w = np.empty_like(u)
    z = np.empty_like(u)
    fwd, _ = median_time(lambda: K.forward_run(pa, u, 5.0, 0.0, w, z), repeats=15)
    wf, _, _ = forward(p, u)
    inv, _ = median_time(lambda: inverse(p, wf), repeats=15)
    head = u[: int(PLAIN_SECONDS * FS)]
    fwd_head, _ = median_time(lambda: K.forward_run(pa, head, 5.0, 0.0, w[: head.size], z[: head.size]), repeats=15)
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    out = subprocess.run([sys.executable, "-c", CHILD % {"T": T, "FS": FS, "PS": PLAIN_SECONDS}], env=env,
                         capture_output=True, text=True, check=True)
    plain = json.loads(out.stdout.strip().splitlines()[-1])["per_sample"]
    compiled = fwd_head / head.size
    ratio = plain / compiled
    rows = [
        ["forward 60 s @ 500 Hz (compiled)", fwd * 1e3, "ms", "< 10 ms"],
        ["inverse 60 s @ 500 Hz (compiled)", inv * 1e3, "ms", ""],
        ["forward per sample, compiled", compiled * 1e9, "ns", ""],
        ["forward per sample, plain Python (same code, JIT off)", plain * 1e9, "ns", ""],
        ["speed ratio plain / compiled", ratio, "x", ">= 100x"],
    ]
    print(table(rows, ["what", "median", "unit", "target"]))


if __name__ == "__main__":
    main()
