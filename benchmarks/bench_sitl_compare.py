"""The paper's controller comparison in lock-step SITL, like for like, beside the paper's bench figures.

    python benchmarks/bench_sitl_compare.py [--seeds 5] [--workers 2] [--model MODEL.json] [--out DIR] [--json OUT]

Like for like (``sitl.like_for_like``): the simulated wing is the physics-based tendon-sheath plant
(``sitl.sheath``: friction nodes along a 270 deg sheath, an elastic tendon, pre-tension), not the
Bouc-Wen model's class. A 90 s bench log of it (random tendon command, flex sensor with noise and
10-bit ADC, 200 Hz) is identified with ``warpbridge identify`` (skipped with --model); the wing then
flown is re-rigged (pre-tension x1.4, friction x1.15), and the bridge flies it with that model and its
default gains (kp 0.5 mm/deg, ki 10 mm/(deg s); PI only also with the paper's Kp = 7, Ki = 1 read as
degrees of a 10 mm servo horn). Scenario: the paper's 1 Hz, 4 deg random reference on the bench (calm),
and in gusts at 7 and 12 m/s. Each RMS is scored over two stretches of the same 60 s runs: from power-on
(1-20 s, the ramp-in excluded) and settled (15-60 s); gusts 5-30 s of 30 s runs. Mean over seeds (the
reference, gusts and sensor noise) and the range. Then, as an upper bound only, the same on the paper's
own plant with the paper's model in the controller (the controller knows the plant exactly).
``--json OUT`` also writes every row, keyed by the sources the run imported (``stored.py``;
``results_page.py`` reads ``benchmarks/results/sitl-compare.json``).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from stored import keyed, write_json  # noqa: E402

from warpbridge.bridge.controller import MODES  # noqa: E402
from warpbridge.sitl.like_for_like import (  # noqa: E402
    FRICTION_CHANGE,
    PRETENSION_CHANGE,
    bench_params,
    identify_bench,
    rigged,
    sheath_spec,
)
from warpbridge.sitl.lockstep import compare  # noqa: E402
from warpbridge.sitl.report import comparison_table  # noqa: E402
from warpbridge.sitl.scenarios import Rig  # noqa: E402
from warpbridge.sitl.wing import WingSpec  # noqa: E402

POWER_ON = (1.0, 20.0)
SETTLED = (15.0, 60.0)
GUSTS = (5.0, 30.0)

DIFFERS = ("What differs from the paper: its figures come from one real wing on a dSPACE bench, with a model "
           "identified on that wing and gains Kp = 7, Ki = 1 in units it does not give; these come from a simulated "
           "sheath wing identified on a simulated bench log, flown re-rigged, with gains chosen for margin "
           "(kp 0.5 mm/deg, ki 10 mm/(deg s)) and a servo and sensor whose lag and noise are ours, not the paper's.")


def _progress(what: str):
    t0 = time.perf_counter()

    def report(done: int, total: int) -> None:
        print(f"  {what}: {done}/{total} runs ({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)

    return report


def row_dict(r) -> dict:
    """A comparison row as JSON: the RMS per seed (deg), the paper's figure, the window (s; null: to the end)."""
    lo, hi = r.window
    return {"scenario": r.scenario, "mode": r.mode, "label": r.label, "rms_deg": list(r.rms), "paper_deg": r.paper,
            "window_s": [lo, hi if math.isfinite(hi) else None]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5, help="seeds of the calm like-for-like runs (default 5)")
    ap.add_argument("--few-seeds", type=int, default=3, help="seeds of the gust and upper-bound runs (default 3)")
    ap.add_argument("--workers", type=int, default=2, help="processes (default 2)")
    ap.add_argument("--model", type=Path, default=None, help="use this MODEL.json instead of identifying the bench log")
    ap.add_argument("--out", type=Path, default=None, help="keep the bench log and model here")
    ap.add_argument("--max-delay", type=float, default=0.0,
                    help="identify the bench log with this transport delay search (default 0: none, as the bridge's "
                         "model is identified)")
    ap.add_argument("--json", type=Path, default=None, help="also write every row to this JSON file")
    args = ap.parse_args()

    t_start = time.perf_counter()
    bench = bench_params()
    flown = rigged(bench)
    out = args.out or Path(tempfile.mkdtemp(prefix="bench-sitl-compare-"))
    if args.model is None:
        print(f"recording the bench log and identifying it in {out} ...", file=sys.stderr, flush=True)
        model = identify_bench(bench, out, max_delay=args.max_delay)
        # the folder is this machine's: the stored text names the files only
        ident = (out / "identify.txt").read_text(encoding="utf-8").strip().replace(f"{out}{os.sep}", "")
    else:
        model, ident = args.model, f"model given: {args.model}"
    print(f"bench wing: sheath {bench}\nflown wing: pre-tension x{PRETENSION_CHANGE:g} "
          f"({flown.pretension_n:g} N), friction x{FRICTION_CHANGE:g} (mu {flown.mu:g})")
    print("identification of the bench log:\n  " + ident.replace("\n", "\n  ") + "\n")

    seeds = tuple(range(args.seeds))
    few = tuple(range(args.few_seeds))
    spec = sheath_spec(flown)
    kw = dict(spec=spec, model_file=str(model), workers=args.workers)
    rows = compare(("random",), MODES, duration_s=SETTLED[1], windows=(POWER_ON, SETTLED), seeds=seeds,
                   progress=_progress("calm"), **kw)
    kp, ki = Rig().gains("paper-horn")
    rows += compare(("random",), ("pi",), duration_s=SETTLED[1], windows=(POWER_ON, SETTLED), seeds=seeds, kp=kp,
                    ki=ki, label="paper-horn gains", progress=_progress("calm, PI with the paper's gains"), **kw)
    rows = sorted(rows, key=lambda r: (r.window, MODES.index(r.mode), r.label))
    gusts = compare(("gust7", "gust12"), MODES, duration_s=GUSTS[1], windows=(GUSTS,), seeds=few,
                    progress=_progress("gusts"), **kw)
    print("LIKE FOR LIKE: sheath wing re-rigged after its bench identification; bridge defaults "
          "(kp 0.5 mm/deg, ki 10 mm/(deg s))")
    print(comparison_table(rows + gusts, note=DIFFERS))

    upper = compare(("random",), MODES, duration_s=SETTLED[1], windows=(POWER_ON, SETTLED), seeds=few,
                    spec=WingSpec(), model_file="paper", workers=args.workers, progress=_progress("upper bound"))
    print("\nUPPER BOUND, NOT LIKE FOR LIKE: the paper's Bouc-Wen plant with the paper's model in the controller "
          "(the controller knows the plant exactly)")
    print(comparison_table(upper))
    if args.json:
        write_json(args.json, keyed({
            "benchmark": "bench_sitl_compare", "seeds": args.seeds, "few_seeds": args.few_seeds,
            "max_delay_s": args.max_delay, "model": "identified" if args.model is None else "given",
            "identification": ident, "pretension_change": PRETENSION_CHANGE, "friction_change": FRICTION_CHANGE,
            "like_for_like": [row_dict(r) for r in rows + gusts], "upper_bound": [row_dict(r) for r in upper]},
            also=("warpbridge.bridge.cli", "warpbridge.bridge.commands.identify")))  # identify_bench's subprocess
        print(f"wrote {args.json}")
    print(f"\n{time.perf_counter() - t_start:.0f} s in all; bench log and model in {out}")


if __name__ == "__main__":
    main()
