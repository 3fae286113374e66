"""Gain and phase margins of the warp loop for the default gains and the paper's, on the default rig.

    python benchmarks/bench_margins.py [--no-measure] [--delay-ms 1] [--json OUT]

The loop: the PI in mm of tendon per deg (and per deg s), the SITL rig's servo (first-order lag
20 ms, 0.25 us steps, 2 us deadband, 0.1 s/60 deg on a 10 mm horn), the bridge's 100 Hz cycle, and
the plant's small-signal slope dw/du (deg/mm) where it is steepest: on the paper's Bouc-Wen wing
over the warp the random reference spans (2..10 deg), and on the sheath wing of the like-for-like
comparison (bench and re-rigged, 0..12 deg). Two figures per case (``sitl.margins``):

- linearised: the sampled-data loop at the 100 Hz ticks only, exactly discretised, with a
  sensor-read-to-servo-write delay of --delay-ms; the choice of the defaults rests on this one
  (kp sets a gain margin of at least 2.5 at the steepest slope; ki puts the PI's zero at about a
  quarter of the crossover);
- measured: a multisine frequency response of the lock-step simulation (the bridge's own cycle,
  ticks plus a cycle per servo message, sensor noise and ADC counts, the servo model) on a
  straight-line plant of the paper wing's steepest slope: L = -C/U at each tone.

Baseline: the paper's Kp = 7, Ki = 1, read as degrees of a 10 mm servo horn per degree (1.22,
0.175 mm/deg) and as mm/deg; and 0.7 / 20, the real-time demo's gains before this change.

``--json OUT`` also writes the slopes and the table, keyed by the sources the run imported (``stored.py``;
``results_page.py`` reads ``benchmarks/results/margins.json``).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import table  # noqa: E402
from stored import keyed, write_json  # noqa: E402

from warpbridge.sitl.like_for_like import bench_params, rigged  # noqa: E402
from warpbridge.sitl.margins import linear_margins, measure_loop, plant_slope  # noqa: E402
from warpbridge.sitl.scenarios import Rig  # noqa: E402
from warpbridge.sitl.sheath import SheathPlant  # noqa: E402
from warpbridge.sitl.wing import SheathWing, default_plant  # noqa: E402


def _fmt(m, top_gain: float = math.nan) -> tuple[str, str, str]:
    if not m.stable:
        return (f"{m.gain:.2f} UNSTABLE" if 0 < m.gain < math.inf else "UNSTABLE"), "-", "-"
    gm = f"> {top_gain:.2f} (no -180)" if not math.isfinite(m.gain) else f"{m.gain:.2f} ({m.gain_db:.1f} dB)"
    pm = "-" if not math.isfinite(m.phase_deg) else f"{m.phase_deg:.0f}"
    fc = "-" if not math.isfinite(m.crossover_hz) else f"{m.crossover_hz:.1f}"
    return gm, pm, fc


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--no-measure", action="store_true", help="linearised analysis only (seconds, not minutes)")
    ap.add_argument("--delay-ms", type=float, default=1.0, help="sensor read to servo write, ms (default 1)")
    ap.add_argument("--json", type=Path, default=None, help="also write the slopes and the table to this JSON file")
    args = ap.parse_args()
    rig = Rig()
    t0 = time.perf_counter()
    slopes = {"paper wing (Bouc-Wen), 2..10 deg": plant_slope(default_plant(), -0.5, 7.5, w_lo=2.0, w_hi=10.0)}
    for label, p in (("sheath wing, bench", bench_params()), ("sheath wing, re-rigged", rigged(bench_params()))):
        lo, hi = SheathPlant(p).travel_range(12.0)
        slopes[f"{label}, 0..12 deg"] = plant_slope(SheathWing(p), lo - 0.5, hi, w_lo=0.0, w_hi=12.0)
    print("steepest small-signal slope dw/du (slow tendon sweeps, no sensor):")
    for k, v in slopes.items():
        print(f"  {k}: {v:.2f} deg/mm")
    print()

    gain_sets = {"default": rig.gains("default"), "paper-horn": rig.gains("paper-horn"),
                 "paper-mm": rig.gains("paper-mm"), "0.7 / 20 (old demo)": (0.7, 20.0)}
    rows = []
    for name, (kp, ki) in gain_sets.items():
        for plant, k in slopes.items():
            m = linear_margins(kp, ki, k, loop_hz=100.0, tau_s=rig.servo.tau_s, delay_s=args.delay_ms * 1e-3)
            rows.append([name, f"{kp:.3g} / {ki:.3g}", plant, f"{k:.2f}", "linearised", *_fmt(m)])
    worst = next(iter(slopes.values()))
    if not args.no_measure:
        for name, (kp, ki) in gain_sets.items():
            print(f"measuring {name} on the lock-step simulation ...", file=sys.stderr, flush=True)
            meas = measure_loop(kp, ki, worst, rig=rig)
            gm, pm, fc = _fmt(meas.margins, 1.0 / abs(meas.L[-1]))
            rows.append([name, f"{kp:.3g} / {ki:.3g}", "straight line, paper wing's steepest", f"{worst:.2f}",
                         "measured" + (" (ran away)" if meas.diverged else ""), gm, pm, fc])
    header = ["gains", "kp mm/deg / ki mm/(deg s)", "plant", "deg/mm", "how", "gain margin", "phase margin deg",
              "crossover Hz"]
    print(table(rows, header))
    print(f"\nlinearised: 100 Hz ticks, servo lag {rig.servo.tau_s * 1e3:g} ms, input delay {args.delay_ms:g} ms, "
          "no deadband or slew limit. measured: lock-step, 100 Hz ticks + 100 Hz servo messages, tones 0.5-97 Hz, "
          "0.03 mm each; a gain margin '> x (no -180)': the phase never reached -180 deg below 97 Hz, where "
          f"1/|L| = x. {time.perf_counter() - t0:.0f} s.")
    if args.json:
        write_json(args.json, keyed({"benchmark": "bench_margins", "delay_ms": args.delay_ms,
                                     "measured": not args.no_measure, "loop_hz": 100.0,
                                     "servo_tau_ms": rig.servo.tau_s * 1e3, "slopes_deg_per_mm": slopes,
                                     "header": header, "rows": rows}))
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
