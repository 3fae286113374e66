"""Print the field-tuning evidence: tracking RMS with a stale model, after self-calibration, with online
adaptation, and both, beside the model-matched wing; then sensor failures with adaptation on.

    python benchmarks/bench_field_tuning.py [--rigged-s 60] [--drift-s 300] [--seed 0] [--processes 2] [--json OUT]

Lock-step SITL with the whole bridge in-process (``sitl.field_tuning``). The simulated tendons are rigged
with pre-tension offset +0.8 mm, gain 1.10 and 15 % more friction than the bridge's (paper) model; in the
drift condition the offset moves by a further 10 % of the tendon range (the model's tendon travel over
0..max warp) during the flight. ff+pi runs with kp 0.7, ki 20 (``sitl.field_tuning.FFPI_GAINS``).
Target: calibrated and adapted within 1.5x of matched. ``--json OUT`` also writes both tables,
keyed by the sources the run imported (``stored.py``; ``results_page.py`` reads
``benchmarks/results/field-tuning.json``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from stored import keyed, write_json  # noqa: E402

from warpbridge.sitl.field_tuning import (  # noqa: E402
    FFPI_GAINS,
    METHODS,
    RIGGED,
    evidence_table,
    failure_rows,
    format_table,
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rigged-s", type=float, default=60.0, help="flight seconds without drift")
    ap.add_argument("--drift-s", type=float, default=300.0, help="flight seconds with drift")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--processes", type=int, default=2)
    ap.add_argument("--json", type=Path, default=None, help="also write both tables to this JSON file")
    args = ap.parse_args()
    t0 = time.perf_counter()
    rows, drift_mm = evidence_table(rigged_s=args.rigged_s, drift_s=args.drift_s, seed=args.seed,
                                    processes=args.processes)
    print("tracking RMS (deg, mean of both wings) and ratio to the model-matched wing")
    print(format_table(rows, drift_mm))
    print("\nsensor failures (ff+pi, calibrated, failure 60 s into a 120 s flight): RMS deg from 3 s after it")
    print(f"{'failure':<32} {'before':>7} {'adapt on':>9} {'adapt off':>10} {'offset est. moved':>18}")
    failures = failure_rows(seed=args.seed, processes=args.processes)
    for name, before, on, off, moved in failures:
        print(f"{name:<32} {before:7.3f} {on:9.3f} {off:10.3f} {moved:15.3f} mm")
    if args.json:
        write_json(args.json, keyed({
            "benchmark": "bench_field_tuning", "rigged_s": args.rigged_s, "drift_s": args.drift_s, "seed": args.seed,
            "drift_mm": drift_mm, "methods": list(METHODS), "rigged": RIGGED.to_dict(), "ffpi_gains": list(FFPI_GAINS),
            "rows": [{"condition": r.condition, "mode": r.mode, "rms_deg": r.rms} for r in rows],
            "failures": [{"failure": n, "rms_before_deg": b, "rms_adapt_on_deg": on, "rms_adapt_off_deg": off,
                          "offset_moved_mm": mv} for n, b, on, off, mv in failures]}))
        print(f"wrote {args.json}")
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
