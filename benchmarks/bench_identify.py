"""Benchmark: full identification of a 60 s, 500 Hz log on this machine (issue 2 target: under 30 s).

Logs are simulated from the paper's parameters with 0.05 deg sensor noise; each
run uses a different excitation seed and starts the search from a deliberately
wrong prior. Reported: wall seconds (median), held-out RMS against the noise
floor, and in the same run the baseline of one forward pass and a straight-line fit.
Run: python benchmarks/bench_identify.py [runs]
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import table  # noqa: E402


def main(runs: int = 3) -> None:
    from warpbridge.model.boucwen import BoucWenParams, forward
    from warpbridge.model.excitation import filtered_random
    from warpbridge.model.identify import identify

    p = BoucWenParams.paper()
    wrong = BoucWenParams(a1=-0.005, a2=0.5, a3=1.5, az=0.3, A=8.0, n=2.0, b=(5, -2, 1, -1, 3, -5))
    t = np.arange(0, 60 * 500) / 500.0
    rows, walls = [], []
    for seed in range(runs):
        u = filtered_random(t, 1.0, 2.5, offset=4.5, seed=seed + 1)
        w, _, _ = forward(p, u)
        t0 = time.perf_counter()
        forward(p, u)
        one_pass = time.perf_counter() - t0
        wm = w + 0.05 * np.random.default_rng(seed).standard_normal(w.size)
        t0 = time.perf_counter()
        r = identify(t, u, wm, prior=wrong, seed=seed)
        wall = time.perf_counter() - t0
        walls.append(wall)
        rows.append([f"seed {seed}", wall, wall / one_pass, r.train_rms, r.heldout_rms, r.noise,
                     r.heldout_rms / r.noise, r.linear_heldout_rms])
    print(table(rows, ["log", "wall s", "x one pass", "train RMS", "held-out RMS", "noise", "held/noise",
                       "line held-out"]))
    print(f"median wall time {statistics.median(walls):.1f} s (target < 30 s); "
          f"median held-out/noise {statistics.median(r[6] for r in rows):.3f} (target <= 1.2)")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 3)
