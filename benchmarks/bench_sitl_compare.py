"""Print the lock-step comparison table: every controller mode, calm and in 7 / 12 m/s gusts.

    python benchmarks/bench_sitl_compare.py [--duration 30] [--kp MM_PER_DEG --ki MM_PER_DEG_S] [--seed 0]

The same table as ``warpbridge sitl --lockstep``, beside the paper's bench figures
(open loop 1.727, PI only 2.04, feed-forward + PI 0.285 deg).
"""

from __future__ import annotations

import argparse
import time

from warpbridge.sitl.lockstep import compare
from warpbridge.sitl.report import comparison_table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--duration", type=float, default=30.0, help="seconds per run")
    ap.add_argument("--kp", type=float, default=None)
    ap.add_argument("--ki", type=float, default=None)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    t0 = time.perf_counter()
    rows = compare(("random", "gust7", "gust12"), duration_s=args.duration, kp=args.kp, ki=args.ki, seed=args.seed)
    print(comparison_table(rows))
    print(f"\n{len(rows)} lock-step runs of {args.duration:g} s in {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
