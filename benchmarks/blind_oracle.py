"""Why the blind benchmark's misses are missed: could any rule that names effects by held-out fit have named them?

    python benchmarks/blind_oracle.py [--seed 0,1] [--family F,...] [--sources SOURCES] [--jobs N] [--json FILE]

For every case of ``bench_diagnose_blind.py``'s cached results whose verdict under the shipped default decision
is not the truth, the case is drawn again (the same plant, bench model and field log), the diagnosis is set up
as ``warpbridge diagnose`` sets it up, and its own fits are asked for the true set of effects (every order of
entry, then the joint refit the verdict gets). The true set's held-out fit is then compared with the verdict's
on the same scored blocks, with the same paired test the diagnosis admits an effect by, and the miss is put in
one of three classes:

- ``search``: the true set fits the scored blocks significantly and materially better than the verdict and each
  of its effects passes the diagnosis's test against the fit of the others (the test of the round that would
  add it to them): the test would have named it, the search did not reach it (the order of entry, a joint
  fit's start);
- ``test``: the true set fits significantly better, but not by a material share of the floor, or an effect of
  it does not pass the test beside the others: a looser test would name it, at the price of false alarms;
- ``log``: the true set fits the scored blocks no better than the verdict: no rule that names effects by how
  well they fit held-out data could name it from this log (the effects imitate each other at this size, or
  the true effect is not in the operators' form and another one fits its trace as well).

The true set is fitted with the diagnosis's operators, not the truth's physics: ``log`` also covers a true
effect whose form the operators lack. Run the benchmark first; this reads its cache and needs its sizes.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import blind_compare  # noqa: E402
import blind_lofo  # noqa: E402
from bench_diagnose_blind import (  # noqa: E402
    BENCH_S,
    FAMILIES,
    FIELD_S,
    MAGNITUDE,
    NONES,
    PAIRS,
    PLANTS,
    RATE,
    cached_results,
    case_list,
    default_cache,
    draw_cases,
    field_case,
    identified_model,
    results_dir,
    run_log,
)
from plants import draw_plants  # noqa: E402

from warpbridge.bridge.commands.modelio import load_model  # noqa: E402
from warpbridge.model.diagnosis.options import DiagnoseOptions  # noqa: E402
from warpbridge.model.diagnosis.start import bench_known_error, set_up  # noqa: E402
from warpbridge.model.diagnosis.transfer import carry_check, decide_carried  # noqa: E402

CLASSES = ("search", "test", "log")


def true_fit(ex, truth: tuple[str, ...]):
    """The diagnosis's best fit of the effects ``truth``: each order of entry through its rounds, the best on
    the training blocks refitted jointly as a verdict is (the nominal for no effect)."""
    if not truth:
        return ex.nominal
    best = min((ex.fit_of(order) for order in itertools.permutations(truth)), key=lambda f: f.train_mse)
    return ex.final(tuple(best.names), best)


def classify(ex, d, verdict_fit, truth_fit, truth: tuple[str, ...]) -> dict:
    """The class of a miss (module docstring) and the figures it rests on. Each effect of the true set is tested
    against ``true_fit`` of the others, as the round that would add it last tests it."""
    level = d.alpha / max(len(ex.names), 1)
    g = ex.gain(verdict_fit, truth_fit)  # > 0: the true set fits the scored blocks better
    better = g.gain > 0 and g.p_value < level
    material = g.gain >= d.min_gain * ex.floor2
    passes = []
    for s in truth:
        rest = tuple(x for x in truth if x != s)
        without = true_fit(ex, rest)
        passes.append(bool(ex.admits(d, without, truth_fit)))
    kind = "search" if better and material and all(passes) else ("test" if better else "log")
    return {"class": kind, "heldout_rms_truth_deg": math.sqrt(truth_fit.score_mse),
            "heldout_rms_verdict_deg": math.sqrt(verdict_fit.score_mse),
            "heldout_rms_nominal_deg": math.sqrt(ex.nominal.score_mse), "floor_deg": math.sqrt(ex.floor2),
            "gain_ms": g.gain, "p_value": g.p_value, "material": bool(material),
            "each_passes": dict(zip(truth, passes, strict=True))}


def examine(res: dict, workers: int, cache: Path) -> dict:
    """Draw the case of a cached result again, diagnose it and classify its miss."""
    args = argparse.Namespace(cache=cache, bench_duration=BENCH_S, rate=RATE, duration=FIELD_S,
                              magnitude=MAGNITUDE)
    seed, index, k = res["seed"], res["plant_index"], res["case"]
    plant = draw_plants(seed, res["family"], index + 1)[index]
    names, case_seed = draw_cases(seed, res["family"], index, NONES, PAIRS)[k]
    with tempfile.TemporaryDirectory() as tmp:
        model = load_model(identified_model(plant, seed, index, args, Path(tmp)))
    fc = field_case(plant, case_seed, tuple(names), args.duration, args.rate, args.magnitude)
    lg = run_log(plant, fc.t, fc.u, fc.airspeed, fc.spec, fc.noise, fc.f_seed)
    opt = DiagnoseOptions(workers=workers)
    su = set_up(lg.t, lg.u, lg.w, lg.airspeed, model, opt)
    ex = su.ex
    # decided as diagnose decides: with the transfer check, and the miss classified on the floor it leaves
    measured = su.e_m ** 2 - bench_known_error(model, su.noise, opt.use_model_error) ** 2
    carry = carry_check(ex, su.error_model, su.slack_side, measured)
    with ex.workers():
        path, carried = decide_carried(ex, opt.decision, opt.max_effects, carry)
        judged = ex.at_floor(ex.floor2 + (carried.raised_by_ms if carried else 0.0))
        out = classify(judged, opt.decision, path.fit, true_fit(judged, tuple(names)), tuple(names))
    return {"plant": res["plant"], "family": res["family"], "case": k, "truth": sorted(names),
            "verdict": sorted(path.named), "cached_verdict": res["verdict"]} | out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", default="0,1", help="seeds (default 0,1)")
    ap.add_argument("--family", default=",".join(FAMILIES), help="families (default: all)")
    ap.add_argument("--sources", default="", help="the results to read: a source hash or a results folder "
                                                  "(default: this code's)")
    ap.add_argument("--jobs", type=int, default=max(1, len(os.sched_getaffinity(0))),
                    help="worker processes each diagnosis fits on (default: the cores)")
    ap.add_argument("--json", type=Path, help="also write the classified misses here")
    ap.add_argument("--cache", type=Path, default=default_cache(), help="the benchmark's cache folder")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seed.split(",")]
    families = args.family.split(",")
    res_dir = blind_compare.folder(args.sources, args.cache) if args.sources else results_dir(args.cache)
    cases = case_list(seeds, families, argparse.Namespace(plants=PLANTS, nones=NONES, pairs=PAIRS, singles_only=False))
    results, todo = cached_results(cases, res_dir)
    if todo:
        sys.exit(f"{len(todo)} of {len(cases)} cases are not in {res_dir.name}: run bench_diagnose_blind.py first")
    default = blind_lofo.key(json.loads(results[0]["default_decision"])) if results else ""
    misses = [r for r in results if sorted(r["verdict"]) != sorted(r["truth"])]
    print(f"{len(misses)} of {len(results)} cases missed under the shipped default decision {default} "
          f"(seeds {args.seed}; results {res_dir.name})", flush=True)
    rows = []
    for i, r in enumerate(misses, 1):
        t0 = time.perf_counter()
        row = examine(r, args.jobs, args.cache)
        rows.append(row)
        same = "" if row["verdict"] == sorted(r["verdict"]) else f"  (cached verdict {r['verdict']})"
        print(f"[{i}/{len(misses)}] {row['class']:<6} {row['plant']:<24} c{row['case']:<2} "
              f"{'+'.join(row['truth']) or '-':<22} -> {'+'.join(row['verdict']) or '-':<30} "
              f"held-out RMS truth {row['heldout_rms_truth_deg']:.4f} verdict {row['heldout_rms_verdict_deg']:.4f} "
              f"floor {row['floor_deg']:.4f} deg, p {row['p_value']:.1e}, "
              f"{time.perf_counter() - t0:.0f} s{same}", flush=True)
    print()
    print(f"{'family':<20} {'misses':>6} " + " ".join(f"{c:>6}" for c in CLASSES))
    for fam in [*families, "all"]:
        sub = [r for r in rows if fam in ("all", r["family"])]
        n = Counter(r["class"] for r in sub)
        print(f"{fam:<20} {len(sub):>6} " + " ".join(f"{n[c]:>6}" for c in CLASSES))
    moved = [r for r in rows if r["verdict"] != sorted(r["cached_verdict"])]
    if moved:
        print(f"\n{len(moved)} verdicts differ from the cached ones (other code computed them?)")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
