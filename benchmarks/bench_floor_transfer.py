"""Does the floor learned on the bench hold in the field? The nominal model's error on logs without any
effect, against the floor ``diagnose`` would judge them by.

    python benchmarks/bench_floor_transfer.py [--seed 0,1,2] [--family F,...] [--jobs N] [--cache DIR]

``diagnose`` names an effect by what the field log adds above a floor: the
noise (estimated from the log) and what the nominal model is known to get wrong
(from the bench log, cross-validated, after its model-error correction). That
floor is only right if the bench's error carries over to another log of the
same rig. For every plant of the blind benchmark (``bench_diagnose_blind.py``:
the same plants, bench logs and identified models, from its cache) and its
no-effect cases, this writes the field log (random input, varying airspeed:
what ``diagnose`` sees) and the check log (another excitation) without any
effect and measures the model's RMS on them after the first second, through
``warpbridge predict --correction``, against sqrt(noise^2 + known error^2).
Beside it, what a user would take instead: the bare model (``predict``) against
its bench misfit (identification's held-out RMS). A ratio of 1 means the floor
predicts the field; above 1 the field is worse than the bench said.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import bench_diagnose_blind as blind  # noqa: E402
from _common import table  # noqa: E402
from plants import FAMILIES, draw_plants, run_log  # noqa: E402

from warpbridge.bridge.commands.modelio import load_model  # noqa: E402
from warpbridge.model.diagnosis.start import known_error  # noqa: E402
from warpbridge.model.signals import noise_floor  # noqa: E402


def plant_ratios(family: str, seed: int, index: int, cache: Path) -> dict:
    """Per no-effect case of one plant: (field, check) RMS over the floor, corrected and bare."""
    plant = draw_plants(seed, family, index + 1)[index]
    args = argparse.Namespace(cache=cache, bench_duration=blind.BENCH_S, rate=blind.RATE)
    out: dict = {"plant": plant.name, "family": family, "field": [], "check": [], "field_bare": [],
                 "check_bare": []}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        model = blind.identified_model(plant, seed, index, args, work)
        mf = load_model(model)
        nones = [cs for names, cs in blind.draw_cases(seed, family, index, 2, 3) if not names]
        for k, cs in enumerate(nones):
            fc = blind.field_case(plant, cs, (), blind.FIELD_S, blind.RATE)
            tc, uc, vc, c_seed = blind.check_input(plant, fc, blind.FIELD_S, blind.RATE)
            logs = {"field": run_log(plant, fc.t, fc.u, fc.airspeed, {}, fc.noise, fc.f_seed),
                    "check": run_log(plant, tc, uc, vc, {}, fc.noise, c_seed)}
            for what, lg in logs.items():
                csv = work / f"{what}{k}.csv"
                blind.write_log(csv, lg)
                nz = noise_floor(lg.w)
                for suffix, corrected in (("", True), ("_bare", False)):
                    # the floor diagnose judges by: with the model-error model, or identification's misfit
                    err = known_error(mf, nz, corrected)
                    mse = blind.predict_mse(csv, model, lg.w, lg.t, work, f"{what}{k}{suffix}", corrected)
                    out[what + suffix].append(float(np.sqrt(mse / (nz ** 2 + err ** 2))))
    return out


def _span(v: list[float]) -> str:
    return f"{np.median(v):.2f} ({min(v):.2f}-{max(v):.2f})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", default="0,1,2", help="seeds of the blind benchmark (default 0,1,2)")
    ap.add_argument("--family", default=",".join(FAMILIES), help="families (default: all)")
    ap.add_argument("--jobs", type=int, default=0, help="parallel plants (default: the cores free now)")
    ap.add_argument("--cache", type=Path, default=blind.default_cache(), help="the blind benchmark's cache")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seed.split(",")]
    families = [f for f in args.family.split(",") if f]
    bad = [f for f in families if f not in FAMILIES]
    if bad:
        sys.exit(f"unknown family {', '.join(bad)} (known: {', '.join(FAMILIES)})")
    jobs = [(f, s, i) for s in seeds for f in families for i in range(3)]
    workers = args.jobs or blind.free_cores()
    res = []
    with ProcessPoolExecutor(workers) as pool:
        futs = [pool.submit(plant_ratios, *j, args.cache) for j in jobs]
        for i, f in enumerate(futs, 1):
            res.append(f.result())
            print(f"[{i}/{len(jobs)}] {res[-1]['plant']}", file=sys.stderr, flush=True)
    rows = []
    for fam in [*families, None]:
        rs = [r for r in res if fam is None or r["family"] == fam]
        per = {k: [float(np.median(r[k])) for r in rs] for k in ("field", "check", "field_bare", "check_bare")}
        worst = max(rs, key=lambda r: np.median(r["field"]))
        over = sum(x > 1.25 for r in rs for x in r["field"])
        n = sum(len(r["field"]) for r in rs)
        rows.append([fam or "all", str(len(rs)), _span(per["field"]), f"{over}/{n}",
                     f"{worst['plant']} {np.median(worst['field']):.2f} (bare {np.median(worst['field_bare']):.2f})",
                     _span(per["check"]), _span(per["field_bare"]), _span(per["check_bare"])])
    print(f"the nominal model on logs without effects against its floor, seeds {', '.join(map(str, seeds))}: "
          "RMS after the first 1 s / sqrt(noise^2 + known error^2), median per plant over its no-effect cases; "
          "median (range) over the plants")
    print(table(rows, ["family", "plants", "field log (corrected)", "field > 1.25x", "worst plant (field log)",
                       "check log (corrected)", "field log (bare)", "check log (bare)"]))


if __name__ == "__main__":
    main()
