"""Local benchmark (truth side only): how much a pre-tension change or an aerodynamic load widens the friction
band of the blind benchmark's capstan sheaths, beside what the diagnosis named for them.

    python benchmarks/bench_sheath_band.py [--seed 0,1,2] [--cache DIR]

In a tendon sheath the friction a stretch of sheath can hold grows with the
tension through it (capstan law), so an effect that changes the tension (a
re-tensioned rig, a load on the wing) changes the hysteresis band too. For
every single-effect case of ``bench_diagnose_blind.py`` on the ``sheath``
family with a pre-tension change or an aero load, this drives the case's truth
core (``plants.Sheath.core``, the N-segment sheath of ``sitl.sheath``; nothing
of the diagnosis) slowly over its travel range, three triangles, with and
without the effect (the load at the field log's 90th-percentile dynamic
pressure), and measures the band on the last cycle: its width in tendon travel
at common warp levels (what the diagnosis's ``friction`` scales) and in warp
at common travel, over the middle of the range. The baseline is the same rig
without the effect. The verdicts are the blind benchmark's cached results for
the case (run it first), under the sheath fold's decision (chosen on the
other families) and the shipped default.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import bench_diagnose_blind as blind  # noqa: E402
import blind_lofo  # noqa: E402
from _common import table  # noqa: E402
from plants import Family, _size, aero_of, draw_plants, dynamic_pressure_kpa, pretension_of  # noqa: E402

TENSION_EFFECTS = ("pretension", "aero_load")
CYCLE = 3000  # samples per leg of the slow triangle


def band_widths(plant: Family, pre: tuple[float, float], aero: tuple[float, float], q: float) -> tuple[float, float]:
    """(width in travel mm at common warp, width in warp deg at common travel) of the core's band on the last
    of three slow triangles over its travel range, averaged over the middle 60 %."""
    lo, hi = plant.u_lo, plant.u_hi
    g = np.linspace(lo, hi, CYCLE)
    tri = np.concatenate([g, g[::-1]])
    x = np.concatenate([np.full(200, lo), tri, tri, tri])
    w = plant.core(x, np.full(x.size, q), 1.0, pre, aero)
    k0 = 200 + 4 * CYCLE
    up, dn = w[k0:k0 + CYCLE], w[k0 + CYCLE:k0 + 2 * CYCLE][::-1]
    mid = (g > lo + 0.2 * (hi - lo)) & (g < hi - 0.2 * (hi - lo))
    in_warp = float(np.mean(np.abs(dn[mid] - up[mid])))
    levels = np.linspace(max(up.min(), dn.min()), min(up.max(), dn.max()), 500)[100:400]
    iu, idn = np.argsort(up), np.argsort(dn)
    in_travel = float(np.mean(np.abs(np.interp(levels, up[iu], g[iu]) - np.interp(levels, dn[idn], g[idn]))))
    return in_travel, in_warp


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", default="0,1,2", help="seeds of the blind benchmark (default 0,1,2)")
    ap.add_argument("--cache", type=Path, default=blind.default_cache(), help="the blind benchmark's cache")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seed.split(",")]
    res_dir = blind.results_dir(args.cache)
    results = [r for f in sorted(res_dir.glob("*.json")) if (r := blind.json.loads(f.read_text()))["seed"] in seeds]
    if not results:
        sys.exit(f"no blind-benchmark results for these sources in {res_dir}: run bench_diagnose_blind.py first")
    default = results[0]["default_decision"]
    fold_dk = blind_lofo.lofo(results, default)["sheath"][0]
    by_case = {(r["seed"], r["plant_index"], r["case"]): r for r in results if r["family"] == "sheath"}
    rows, grew = [], {n: [] for n in TENSION_EFFECTS}
    for seed in seeds:
        plants = draw_plants(seed, "sheath", 3)
        for idx, plant in enumerate(plants):
            for k, (names, case_seed) in enumerate(blind.draw_cases(seed, "sheath", idx, 2, 3)):
                if len(names) != 1 or names[0] not in TENSION_EFFECTS:
                    continue
                fc = blind.field_case(plant, case_seed, names, blind.FIELD_S, blind.RATE)
                q = float(np.percentile(dynamic_pressure_kpa(fc.airspeed), 90))
                base = band_widths(plant, (0.0, 1.0), (0.0, 0.0), q)
                s, _, mix = _size(fc.spec, "aero_load")
                eff = band_widths(plant, pretension_of(fc.spec, plant.span), aero_of(plant, s, mix), q)
                r = by_case.get((seed, idx, k))
                fold = "+".join(blind_lofo.verdict_at(r, fold_dk)) or "[]" if r else "(not run)"
                shipped = "+".join(r["verdict"]) or "[]" if r else "(not run)"
                ratio = eff[0] / base[0]
                grew[names[0]].append((ratio, fold))
                rows.append([plant.name, names[0], f"{r['magnitude_x_noise'][names[0]]:.1f}" if r else "-",
                             f"{base[0]:.3f}", f"x{ratio:.3f}", f"{base[1]:.3f}", f"x{eff[1] / base[1]:.3f}",
                             fold, shipped])
    print(f"capstan sheaths of the blind benchmark, seeds {', '.join(map(str, seeds))}: the friction band with and "
          f"without the case's effect (truth core, slow triangles; aero load at the field log's 90th-percentile "
          f"dynamic pressure); verdicts under the sheath fold's decision ({blind_lofo.describe_decision(fold_dk)}) "
          f"and the shipped default")
    print(table(rows, ["plant", "effect", "x noise", "band mm", "with effect", "band deg", "with effect",
                       "named (fold)", "named (default)"]))
    for n, v in grew.items():
        if not v:
            continue
        extra = [abs(x - 1) for x, named in v if n in named.split("+") and named != n]
        alone = [abs(x - 1) for x, named in v if named == n]
        print(f"{n}: band change in travel, |ratio - 1|, median {np.median([abs(x - 1) for x, _ in v]):.1%} over "
              f"{len(v)} cases; where another effect was named beside it (fold's decision): "
              + (f"median {np.median(extra):.1%} ({len(extra)} cases)" if extra else "none")
              + "; where it was named alone: " + (f"median {np.median(alone):.1%} ({len(alone)})" if alone else "none"))


if __name__ == "__main__":
    main()
