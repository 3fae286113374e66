"""How much one bench log decides: a blind-benchmark rig identified again on other draws of its bench input.

    python benchmarks/blind_bench_draws.py [--family sheath] [--seed 1] [--plant 1] [--draws 3] [--jobs 2]
                                           [--no-check] [--cache DIR] [--report-only]

The blind benchmark (``bench_diagnose_blind.py``) identifies each rig on one 40 s bench log, one realisation of a
random input. On a rig whose friction remembers many reversals, how well the identified model and its
model-error correction carry to the field depends on which realisation that was, and the bench log's own
cross-validation cannot tell (its folds share the realisation). This benchmark draws ``--draws`` more bench
logs of the same rig from the same process (the same plant, input generator and noise range, other random
draws), identifies each as the blind benchmark does (``identify --max-delay 0.16``, the model-error model
learned on the log), and diagnoses every field case of the rig (the blind benchmark's own logs: no effect,
each single effect, its random pairs) with each model, under the shipped default decision. Beside the other
draws it prints what the blind benchmark scores (the benchmark's own draw, "draw 0") and what docs/identify.md
advises for such rigs: the benchmark's model with draw 1 as ``identify --check`` (a second bench log of the
same kind of input), unless ``--no-check``.

Per model: the known error ``diagnose`` judges the field against, the corrected model's misfit on the rig's
no-effect field logs (``predict --correction``, after the first second), and how many verdicts are the truth.
Results are cached per model and case under ``--cache`` (keyed by the diagnosis sources), so a run can stop
and go on, and ``--report-only`` prints the tables from what is there.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import shutil
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_diagnose_blind as blind  # noqa: E402
from _common import table  # noqa: E402
from plants import FAMILIES, Family, draw_plants, run_log  # noqa: E402

from warpbridge.bridge.commands.logfile import read_log  # noqa: E402


def draw_bench_log(plant: Family, seed: int, index: int, draw: int, bench_s: float, rate: float):
    """The rig's bench log: the blind benchmark's own for ``draw`` 0, else another realisation of the same
    process (a random input of the same generator, a noise level from the same range)."""
    if draw == 0:
        return blind.bench_log(plant, seed, index, bench_s, rate)
    rng = np.random.default_rng([seed, sum(map(ord, plant.family)), index, 1, draw])
    t = blind.timebase(bench_s, rate)
    u = blind.excite(plant, t, "random", rng)
    noise = rng.uniform(0.03, 0.05)
    return run_log(plant, t, u, np.zeros(t.size), {}, noise, int(rng.integers(1 << 30)))


def draw_model(plant: Family, seed: int, index: int, draw: int, check_draw: int | None, args,
               work: Path) -> Path:
    """MODEL.json identified on bench draw ``draw`` as the blind benchmark identifies, its
    model-error model learned afresh; with ``check_draw``, that draw's bench log scored as ``identify --check``."""
    from warpbridge.bridge.commands.identify import bench_model_error, score_check_log
    from warpbridge.bridge.commands.modelio import load_model, save_model

    bench = work / f"{plant.name}-draw{draw}-bench.csv"
    lg = draw_bench_log(plant, seed, index, draw, args.bench_duration, args.rate)
    blind.write_log(bench, lg, with_airspeed=False)
    key = hashlib.sha256(bench.read_bytes() + blind.source_hash(blind.IDENT_SOURCES).encode()).hexdigest()[:16]
    cached = args.cache / "models" / f"{plant.name}-{key}.json"  # the blind benchmark's model cache and key
    if not cached.is_file():
        print(f"identify {plant.name} on bench draw {draw}", flush=True)
        cached.parent.mkdir(parents=True, exist_ok=True)
        tmp_model = work / f"{plant.name}-draw{draw}-ident.json"
        code, text = blind.run_cli(["identify", str(bench), "-o", str(tmp_model), "--quiet", "--max-delay", "0.16"])
        if code != 0:
            raise RuntimeError(f"identify failed on {plant.name} draw {draw}: {text}")
        shutil.copyfile(tmp_model, cached)
    mf = load_model(cached)
    mf.model_error = bench_model_error(mf, read_log(bench))
    if check_draw is not None:
        chk = work / f"{plant.name}-draw{check_draw}-bench.csv"
        blind.write_log(chk, draw_bench_log(plant, seed, index, check_draw, args.bench_duration, args.rate),
                        with_airspeed=False)
        mf.fit.extra["check"], _ = score_check_log(mf, read_log(chk), chk.name)
    out = work / f"{plant.name}-{label(draw, check_draw)}-model.json"
    save_model(out, mf)
    return out


def label(draw: int, check_draw: int | None) -> str:
    return f"draw{draw}" + (f"-check{check_draw}" if check_draw is not None else "")


def case_job(family: str, seed: int, index: int, k: int, names: tuple[str, ...], case_seed: int, model: str,
             tag: str, args) -> dict:
    """Diagnose the rig's case ``k`` (the blind benchmark's own field log) with ``model``."""
    plant = draw_plants(seed, family, index + 1)[index]
    fc = blind.field_case(plant, case_seed, names, args.duration, args.rate, blind.MAGNITUDE)
    fld = run_log(plant, fc.t, fc.u, fc.airspeed, fc.spec, fc.noise, fc.f_seed)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        field_csv, report = work / "field.csv", work / "report.json"
        blind.write_log(field_csv, fld)
        code, text = blind.run_cli(["diagnose", str(field_csv), "--model", model, "--report", str(report),
                                    "--quiet", "--jobs", "1"])
        if code != 0:
            raise RuntimeError(f"diagnose failed on {plant.name} case {k} ({tag}): {text}")
        rep = json.loads(report.read_text())
        misfit = math.sqrt(blind.predict_mse(field_csv, Path(model), fld.w, fld.t, work, "nom")) if not names else None
    return {"plant": plant.name, "model": tag, "case": k, "truth": sorted(names), "spec": blind.describe(fc.spec),
            "verdict": sorted(rep["verdict"]), "known_error_deg": rep["model_error_deg"],
            "field_misfit_deg": misfit, "sources": blind.source_hash(blind.DIAG_SOURCES)}


def summary_rows(results: list[dict], tags: list[str], what: dict[str, str]) -> list[list[object]]:
    rows = []
    for tag in tags:
        rs = [r for r in results if r["model"] == tag]
        if not rs:
            continue
        singles = [r for r in rs if len(r["truth"]) == 1]
        pairs = [r for r in rs if len(r["truth"]) == 2]
        nones = [r for r in rs if not r["truth"]]
        ok = [r for r in rs if r["verdict"] == r["truth"]]
        known = rs[0]["known_error_deg"]
        misfit = [r["field_misfit_deg"] for r in nones if r["field_misfit_deg"] is not None]
        over = f" ({min(misfit) / known:.2f}-{max(misfit) / known:.2f}x)" if misfit and known > 0 else ""
        rows.append([what[tag], f"{known:.3f}", ", ".join(f"{m:.3f}" for m in misfit) + over if misfit else "-",
                     f"{sum(r['verdict'] == r['truth'] for r in singles)}/{len(singles)}",
                     f"{sum(r['verdict'] == r['truth'] for r in pairs)}/{len(pairs)}",
                     f"{sum(bool(r['verdict']) for r in nones)}/{len(nones)}", f"{len(ok)}/{len(rs)}"])
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--family", default="sheath", choices=FAMILIES, help="the rig's family (default sheath)")
    ap.add_argument("--seed", type=int, default=1, help="the rig's seed in the blind benchmark (default 1)")
    ap.add_argument("--plant", type=int, default=1, help="the rig's index in its family and seed (default 1: "
                    "with seed 1, the 424 deg capstan sheath)")
    ap.add_argument("--draws", type=int, default=3, help="other bench draws to identify on (default 3)")
    ap.add_argument("--no-check", action="store_true", help="leave out the benchmark's model with draw 1 as "
                    "identify --check")
    ap.add_argument("--jobs", type=int, default=2, help="cases diagnosed at a time (default 2)")
    ap.add_argument("--cache", type=Path, default=blind.default_cache(), help="cache folder (outside the "
                    "repository; the blind benchmark's by default, whose bench models draw 0 reuses)")
    ap.add_argument("--report-only", action="store_true", help="print the table from the cached results")
    args = ap.parse_args()
    if args.draws < 0:
        ap.error("--draws must be 0 or more")
    args.duration, args.rate, args.bench_duration = blind.FIELD_S, blind.RATE, blind.BENCH_S

    plant = draw_plants(args.seed, args.family, args.plant + 1)[args.plant]
    cases = blind.draw_cases(args.seed, args.family, args.plant, blind.NONES, blind.PAIRS)
    models = [(d, None) for d in range(args.draws + 1)]
    if args.draws >= 1 and not args.no_check:
        models.append((0, 1))
    tags = [label(d, c) for d, c in models]
    what = {label(d, c): ("draw 0 (the blind benchmark's)" if d == 0 and c is None else
                          f"draw 0, draw {c} as identify --check" if c is not None else f"draw {d}")
            for d, c in models}
    res_dir = args.cache / "bench_draws" / f"{plant.name}-{blind.source_hash(blind.DIAG_SOURCES)}"
    res_dir.mkdir(parents=True, exist_ok=True)
    print(f"{plant.name}: {len(cases)} field cases x {len(models)} models; results in {res_dir}", flush=True)

    def cached(tag: str, k: int) -> Path:
        return res_dir / f"{tag}-c{k}.json"

    if not args.report_only:
        with tempfile.TemporaryDirectory() as tmp:
            work = Path(tmp)
            todo = []
            for (d, c), tag in zip(models, tags, strict=True):
                missing = [k for k in range(len(cases)) if not cached(tag, k).is_file()]
                if missing:
                    model = draw_model(plant, args.seed, args.plant, d, c, args, work)
                    todo += [(tag, k, str(model)) for k in missing]
            with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
                futs = {pool.submit(case_job, args.family, args.seed, args.plant, k, cases[k][0], cases[k][1],
                                    model, tag, args): (tag, k) for tag, k, model in todo}
                for i, fut in enumerate(as_completed(futs), 1):
                    tag, k = futs[fut]
                    res = fut.result()
                    cached(tag, k).write_text(json.dumps(res))
                    mark = "ok" if res["verdict"] == res["truth"] else "WRONG"
                    print(f"[{i}/{len(todo)}] {what[tag]:<38} c{k:<3} {mark:<5} {res['spec']:<36} -> "
                          f"{res['verdict'] or '[]'}", flush=True)

    results = [json.loads(cached(t, k).read_text()) for t in tags for k in range(len(cases)) if cached(t, k).is_file()]
    note = blind.plant_notes([{"family": args.family, "seed": args.seed, "plant_index": args.plant}]).get(plant.name)
    print(f"\n{plant.name}{f' ({note})' if note else ''}: its {len(cases)} field cases of the blind benchmark, "
          "shipped default decision\n")
    print(table(summary_rows(results, tags, what),
                ["bench model", "known error deg", "no-effect field misfit deg (x known error)", "singles", "pairs",
                 "false alarms", "all right"]))
    print("\nverdicts (truth -> per model):")
    for k, (names, _) in enumerate(cases):
        by_tag = {r["model"]: r for r in results if r["case"] == k}
        if by_tag:
            print(f"  c{k:<3} {'+'.join(names) or 'none':<22} " + "  ".join(
                "..." if (r := by_tag.get(t)) is None else
                f"{','.join(r['verdict']) or '[]'}{'' if r['verdict'] == r['truth'] else '*'}" for t in tags))
    print("  (one column per bench model, in the table's order; * not the truth, ... not run yet)")


if __name__ == "__main__":
    main()
