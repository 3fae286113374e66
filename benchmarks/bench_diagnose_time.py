"""What ``warpbridge diagnose`` costs on 60 s at 500 Hz, with the model-error correction's input terms reused
(as shipped) against recomputed at every evaluation (the code before they were cached), in the same run.

    python benchmarks/bench_diagnose_time.py [--seed 2] [--cases 10,12] [--repeats 1] [--cache DIR]

Cases are the blind benchmark's (``bench_diagnose_blind.py``: plant 0 of each family at ``--seed``, the case
numbers given; 10-12 are its pairs, the slowest), the bench models from its cache (identified there when
missing). Each case runs plain ``diagnose`` through ``bridge.cli.main`` once per variant and repeat, the
variants alternating in order, one process at a time. The report must be the same either way (checked:
the verdict and every fitted parameter); the table gives each case's times and their ratio, then the
median ratio and the slowest time per variant.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_diagnose_blind as blind  # noqa: E402
from plants import draw_plants  # noqa: E402

from warpbridge.model import model_error  # noqa: E402

FAMILIES = ("bouc-wen", "bouc-wen-phys", "dahl", "prandtl-ishlinskii", "sheath")


def _recomputed(self, x: np.ndarray) -> tuple:
    """The baseline: the input terms computed afresh at every call."""
    return model_error.input_terms(x, self.x_span, plays=len(self.sets) >= 6)


def _strip(report: dict) -> dict:
    return {k: v for k, v in report.items() if k not in ("seconds", "created")}


def timed_diagnose(field_csv: Path, model: Path, out: Path, reuse: bool) -> tuple[float, dict]:
    cached = model_error.ErrorModel._input_terms
    if not reuse:
        model_error.ErrorModel._input_terms = _recomputed
    try:
        t0 = time.perf_counter()
        code, text = blind.run_cli(["diagnose", str(field_csv), "--model", str(model), "--report", str(out),
                                    "--quiet"])
        seconds = time.perf_counter() - t0
    finally:
        model_error.ErrorModel._input_terms = cached
    if code != 0:
        raise RuntimeError(f"diagnose failed: {text}")
    return seconds, _strip(json.loads(out.read_text()))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--cases", default="10,12", help="case numbers of the blind benchmark (10-12: pairs)")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--cache", type=Path, default=blind.default_cache())
    a = ap.parse_args(argv)
    args = argparse.Namespace(cache=a.cache, bench_duration=blind.BENCH_S, rate=blind.RATE,
                              duration=blind.FIELD_S, timing_every=1)
    cases = [int(c) for c in a.cases.split(",")]
    rows = []
    print(f"diagnose, 60 s at 500 Hz: input terms reused (shipped) vs recomputed (baseline); seed {a.seed}, "
          f"plant 0 of each family, cases {a.cases}, {a.repeats} repeat(s)", flush=True)
    print(f"{'case':<28}{'truth':<26}{'baseline s':>11}{'reused s':>10}{'ratio':>7}  same report", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for n, family in enumerate(FAMILIES):
            plant = draw_plants(a.seed, family, 1)[0]
            model = blind.identified_model(plant, a.seed, 0, args, work)
            drawn = blind.draw_cases(a.seed, family, 0, 2, 3)
            for k in cases:
                names, case_seed = drawn[k]
                fc = blind.field_case(plant, case_seed, tuple(names), args.duration, args.rate)
                lg = blind.run_log(plant, fc.t, fc.u, fc.airspeed, fc.spec, fc.noise, fc.f_seed)
                field_csv = work / f"{plant.name}-c{k}.csv"
                blind.write_log(field_csv, lg)
                for r in range(a.repeats):
                    order = (False, True) if (n + k + r) % 2 == 0 else (True, False)
                    got = {reuse: timed_diagnose(field_csv, model, work / f"rep-{reuse}.json", reuse)
                           for reuse in order}
                    (tb, rb), (tr, rr) = got[False], got[True]
                    same = rb == rr
                    rows.append((tb, tr, same))
                    print(f"{plant.name + f'-c{k}':<28}{'+'.join(names):<26}{tb:>11.1f}{tr:>10.1f}{tr / tb:>7.2f}  "
                          f"{'yes' if same else 'NO'}", flush=True)
    ratios = [tr / tb for tb, tr, _ in rows]
    print(f"\n{len(rows)} runs: time ratio reused / recomputed median {statistics.median(ratios):.2f} "
          f"(range {min(ratios):.2f}-{max(ratios):.2f}); slowest: baseline {max(r[0] for r in rows):.1f} s, "
          f"reused {max(r[1] for r in rows):.1f} s; reports identical {sum(r[2] for r in rows)}/{len(rows)}")
    return 0 if all(r[2] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
