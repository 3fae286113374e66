"""How well the noise floor is estimated from a log: ``identify.noise_floor`` against the measurement error the
truth side added, and against the estimate it replaced.

    python benchmarks/bench_noise_floor.py [--seed 0,1] [--rate 500,100,50] [--family F,...]

``diagnose`` judges a field log against sqrt(noise^2 + known error^2), and ``identify`` takes the known error as
what its held-out RMS holds beyond the noise, so a noise estimate 10 % high hides a second effect of 20 % of the
floor, and one 10 % low on the bench adds that to the known error. The logs are the blind benchmark's
(``bench_diagnose_blind.py``: the same plants, their bench log and, per plant, its first no-effect, first
single-effect and first pair field log), simulated at each ``--rate``; the truth is the standard deviation of
what the measurement added to the plant's noise-free warp: the noise and the ADC's quantisation (a step of
0.015-0.03 deg on every family but the Bouc-Wen one, whose sensor is ideal). Beside it, the estimate of the code
before: the median absolute deviation of the second differences (the baseline, written out here). Each row
prints the ratio estimate / truth over the logs: median, the 5th and 95th percentiles, the extremes, and the
share of logs off by more than 5 %.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import table  # noqa: E402
from bench_diagnose_blind import (  # noqa: E402
    BENCH_S,
    FIELD_S,
    MAGNITUDE,
    NONES,
    PAIRS,
    PLANTS,
    bench_log,
    draw_cases,
    field_case,
)
from plants import FAMILIES, draw_plants, run_log  # noqa: E402

from warpbridge.model.signals import noise_floor  # noqa: E402


def mad_floor(w: np.ndarray) -> float:
    """The estimate before: 1.4826 x the median absolute deviation of the second differences / sqrt(6)."""
    d2 = np.diff(np.asarray(w, dtype=np.float64), 2)
    mad = float(np.median(np.abs(d2 - np.median(d2))))
    return 1.4826 * mad / math.sqrt(6.0) if mad > 0 else float(np.sqrt(np.mean(d2 ** 2) / 6.0))


def logs(seed: int, family: str, index: int, rate: float):
    """(what, measured warp, noise-free measured warp) of one plant's bench log and three of its field logs."""
    plant = draw_plants(seed, family, index + 1)[index]
    b = bench_log(plant, seed, index, BENCH_S, rate)
    yield "bench", b.w, b.w_clean
    cases = draw_cases(seed, family, index, NONES, PAIRS)
    firsts = {0: "field, no effect", NONES: "field, one effect", len(cases) - PAIRS: "field, a pair"}
    for k, what in firsts.items():
        names, case_seed = cases[k]
        fc = field_case(plant, case_seed, tuple(names), FIELD_S, rate, MAGNITUDE)
        lg = run_log(plant, fc.t, fc.u, fc.airspeed, fc.spec, fc.noise, fc.f_seed)
        yield what, lg.w, lg.w_clean


def spread(r: list[float]) -> list[str]:
    a = np.asarray(r)
    return [f"{np.median(a):.3f}", f"{np.percentile(a, 5):.3f}-{np.percentile(a, 95):.3f}",
            f"{a.min():.3f}-{a.max():.3f}", f"{np.mean(np.abs(a - 1) > 0.05):.0%}"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", default="0,1")
    ap.add_argument("--rate", default="500,100,50", help="samples per second the logs are simulated at")
    ap.add_argument("--family", default=",".join(FAMILIES))
    args = ap.parse_args()
    seeds = [int(s) for s in args.seed.split(",")]
    families = args.family.split(",")
    rows = []
    for rate in (float(r) for r in args.rate.split(",")):
        new: dict[str, list[float]] = {}
        old: dict[str, list[float]] = {}
        for seed in seeds:
            for fam in families:
                for index in range(PLANTS):
                    for what, w, clean in logs(seed, fam, index, rate):
                        truth = float(np.std(w - clean))
                        for d, est in ((new, noise_floor), (old, mad_floor)):
                            d.setdefault(what, []).append(est(w) / truth)
        new["all"] = [x for v in list(new.values()) for x in v]
        old["all"] = [x for v in list(old.values()) for x in v]
        for what in new:
            rows.append([f"{rate:g} Hz", what, len(new[what]), *spread(new[what]), *spread(old[what])])
        print(f"{rate:g} Hz done", file=sys.stderr)
    print(f"noise floor estimate / the standard deviation of the measurement error added, seeds {args.seed}, families "
          f"{', '.join(families)}: {PLANTS} plants each, their bench log ({BENCH_S:g} s) and three field logs "
          f"({FIELD_S:g} s)")
    head = ["rate", "logs", "n", "median", "p5-p95", "range", "off > 5%"]
    print(table(rows, head + ["before: median", "p5-p95", "range", "off > 5%"]))


if __name__ == "__main__":
    main()
