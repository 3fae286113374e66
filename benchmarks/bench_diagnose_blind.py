"""Blind check of ``warpbridge diagnose``, blind in form: plants and effects written from the physics, scored
leave-one-family-out on logs the diagnosis never saw.

    python benchmarks/bench_diagnose_blind.py [--family F,...] [--seed 0,1] [--plants 3] [--pairs 3]
                                              [--nones 2] [--quick] [--jobs N] [--cache DIR] [--report-only]
                                              [--choose-on-seed 0,1,2]

Plants (``benchmarks/plants.py``; truth side in ``truth_chain.py``,
``truth_cores.py``, ``truth_lugre.py`` and the sheath of ``sitl/sheath.py``,
none of which imports the diagnosis's operators): Bouc-Wen with the diagnosis's
own effect forms (the only family in the model's class), Bouc-Wen,
Prandtl-Ishlinskii, Dahl, N-segment capstan sheaths and sheaths of N LuGre
friction nodes (bristles, a lubricant's viscous drag: the only rate-dependent
family) with physical effects and bench imperfections (link latency, servo
dynamics, linkage slack, sensor filter, ADC quantisation).

Per plant: a 40 s bench log (random input, no airflow, the tendon already
loaded at the first sample) and ``warpbridge identify`` on it, which also
learns the model-error model. Per case (no effect, each single effect, random
pairs) at a random magnitude (RMS change of the warp 2.5-15x the sensor noise; ``--magnitude`` other sizes,
log-uniform), a 60 s field log (random input, varying airspeed) that
``warpbridge diagnose --sensitivity`` sees, and a 30 s check log it never sees
(another excitation and airspeed range), written twice: with the effects and
without them (same input and noise). The check-log gap is what the effects add
to the nominal model's error there: (MSE_nominal - MSE_augmented) /
(MSE_nominal - MSE_nominal without the effects), scored after the first 1 s,
``warpbridge predict --correction`` making both predictions (the nominal with
the model-error correction it carries, which ``diagnose`` judges the field
against); the same ratio with the bare model (``predict`` without the flag) is
reported beside it. All through ``bridge.cli.main``
on real files.

Leave-one-family-out: ``diagnose --sensitivity`` reports the verdict under
each decision of a small grid (significance level, share of the remaining gap,
material gain); for each held-out family the decision is chosen on the other
families and the held-out family is scored with it (``blind_lofo.py``). With
``--choose-on-seed``, on the other families of those seeds: the seeds scored
(a fresh one) are then held out as well as the family.

The expensive parts are cached under ``--cache`` (default: the user's cache
folder, outside the repository): the identified bench model per plant (keyed
by the plant and the identification sources) and each case's result (keyed by
the case and the diagnosis sources), so a re-run after a change to the
diagnosis re-diagnoses without re-identifying, and ``--report-only`` prints
the tables from what is there.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import itertools
import json
import math
import os
import shutil
import sys
import tempfile
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

import blind_lofo  # noqa: E402
from plants import (  # noqa: E402
    EFFECTS,
    FAMILIES,
    PRE_ROLL_S,
    Family,
    describe,
    draw_plants,
    magnitude_for,
    run_log,
)

from warpbridge.bridge.cli import main as cli  # noqa: E402
from warpbridge.bridge.commands.diagnose import free_cores  # noqa: E402
from warpbridge.bridge.commands.logfile import read_log, write_csv_atomic  # noqa: E402
from warpbridge.model import excitation  # noqa: E402

IDENT_SOURCES = [*sorted(str(p.relative_to(ROOT)) for p in (ROOT / "model" / "identification").glob("*.py")),
                 "model/signals.py", "model/kernels.py", "model/boucwen.py", "model/initial_state.py",
                 "model/monotone.py", "model/effects.py", "model/_jit.py", "bridge/commands/logfile.py",
                 "bridge/commands/identify.py"]
DIAG_SOURCES = IDENT_SOURCES + ["benchmarks/plants.py", "benchmarks/truth_chain.py", "benchmarks/truth_cores.py",
                                "sitl/sheath.py", *sorted(str(p.relative_to(ROOT)) for p in
                                                          (ROOT / "model" / "diagnosis").glob("*.py")),
                                "model/model_error.py", "model/effect_registry.py", "model/plant.py",
                                "benchmarks/truth_lugre.py", "bridge/commands/diagnose.py",
                                "bridge/commands/predict.py", "benchmarks/bench_diagnose_blind.py"]
BENCH_S, FIELD_S, CHECK_S, RATE = 40.0, 60.0, 30.0, 500.0
CHECK_SKIP_S = 1.0
PLANTS, NONES, PAIRS = 3, 2, 3  # per family and seed: plants; per plant: no-effect cases, random pairs


def source_hash(paths: list[str]) -> str:
    h = hashlib.sha256()
    for p in paths:
        f = ROOT / p
        h.update(p.encode())
        h.update(f.read_bytes() if f.is_file() else b"absent")
    return h.hexdigest()[:12]


def default_cache() -> Path:
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "warpbridge" / "bench_diagnose_blind"


def run_cli(argv: list[str]) -> tuple[int, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli(argv)
    return code, out.getvalue() + err.getvalue()


def airspeed_profile(t: np.ndarray, lo: float, hi: float, seed: int) -> np.ndarray:
    return excitation.filtered_random(t, 0.08, 0.5 * (hi - lo), 0.5 * (hi + lo), seed=seed)


def excite(plant: Family, t: np.ndarray, kind: str, rng: np.random.Generator) -> np.ndarray:
    off, amp = 0.5 * (plant.u_lo + plant.u_hi), 0.5 * plant.span
    seed = int(rng.integers(1 << 30))
    if kind == "random":
        return excitation.filtered_random(t, rng.uniform(0.8, 2.0), amp, off, seed=seed)
    if kind == "multisine":
        return excitation.multisine_reversals(t, (0.6 * amp, 0.28 * amp, 0.12 * amp),
                                              tuple(rng.uniform([0.25, 0.9, 2.2], [0.5, 1.4, 3.2])), off)
    if kind == "sweep":
        return excitation.sweep(t, 0.2, rng.uniform(1.5, 3.0), amp, off)
    raise ValueError(kind)


def timebase(seconds: float, rate: float) -> np.ndarray:
    return np.arange(int(round((seconds + PRE_ROLL_S) * rate))) / rate


def write_log(path: Path, lg, with_airspeed: bool = True) -> None:
    cols = {"t": lg.t, "u": lg.u, "warp": lg.w}
    if with_airspeed:
        cols["airspeed"] = lg.airspeed
    write_csv_atomic(path, cols)


# ---- plants and their bench models ----------------------------------------------------------------

def plant_rng(seed: int, family: str, index: int) -> np.random.Generator:
    return np.random.default_rng([seed, sum(map(ord, family)), index, 1])


def bench_log(plant: Family, seed: int, index: int, bench_s: float, rate: float):
    rng = plant_rng(seed, plant.family, index)
    t = timebase(bench_s, rate)
    u = excite(plant, t, "random", rng)
    noise = rng.uniform(0.03, 0.05)
    return run_log(plant, t, u, np.zeros(t.size), {}, noise, int(rng.integers(1 << 30)))


def check_bench_log(plant: Family, seed: int, index: int, bench_s: float, rate: float):
    """A second bench log of the plant, another input than the bench's random one (a multisine or a sweep,
    drawn from the plant's own generator), for ``identify --check``."""
    rng = np.random.default_rng([seed, sum(map(ord, plant.family)), index, 3])
    t = timebase(bench_s, rate)
    u = excite(plant, t, str(rng.choice(["multisine", "sweep"])), rng)
    noise = rng.uniform(0.03, 0.05)
    return run_log(plant, t, u, np.zeros(t.size), {}, noise, int(rng.integers(1 << 30)))


def identified_model(plant: Family, seed: int, index: int, args, work: Path) -> Path:
    """The plant's identified bench model (cached), with its model-error model learned afresh."""
    lg = bench_log(plant, seed, index, args.bench_duration, args.rate)
    bench = work / f"{plant.name}-bench.csv"
    write_log(bench, lg, with_airspeed=False)
    # keyed by the bench log itself and the identification sources: a change of the truth side re-identifies
    # exactly the plants whose bench log it changed
    key = hashlib.sha256(bench.read_bytes() + source_hash(IDENT_SOURCES).encode()).hexdigest()[:16]
    cached = args.cache / "models" / f"{plant.name}-{key}.json"
    if not cached.is_file():
        cached.parent.mkdir(parents=True, exist_ok=True)
        tmp_model = work / f"{plant.name}-ident.json"
        # with the transport delay search, as a model to diagnose with should be identified
        code, text = run_cli(["identify", str(bench), "-o", str(tmp_model), "--quiet", "--max-delay", "0.16"])
        if code != 0:
            raise RuntimeError(f"identify failed on {plant.name}: {text}")
        shutil.copyfile(tmp_model, cached)
    # the model-error model is refreshed on every run (cheap), with the same call ``identify`` makes
    from warpbridge.bridge.commands.identify import bench_model_error
    from warpbridge.bridge.commands.modelio import load_model, save_model

    mf = load_model(cached)
    mf.model_error = bench_model_error(mf, read_log(bench))
    if getattr(args, "bench_check", False):  # identify --check: a second bench log of another input scores the model
        from warpbridge.bridge.commands.identify import score_check_log

        chk = check_bench_log(plant, seed, index, args.bench_duration, args.rate)
        check_csv = work / f"{plant.name}-bench-check.csv"
        write_log(check_csv, chk, with_airspeed=False)
        mf.fit.extra["check"], _ = score_check_log(mf, read_log(check_csv), check_csv.name)
    out = work / f"{plant.name}-model.json"
    save_model(out, mf)
    return out


# ---- cases ----------------------------------------------------------------------------------------

def draw_cases(seed: int, family: str, index: int, nones: int, pairs: int) -> list[tuple[tuple[str, ...], int]]:
    """(effects, case seed) per case: ``nones`` without effect, every single effect, ``pairs`` random pairs."""
    rng = np.random.default_rng([seed, sum(map(ord, family)), index, 2])
    cases: list[tuple[str, ...]] = [()] * nones + [(n,) for n in EFFECTS]
    combos = list(itertools.combinations(EFFECTS, 2))
    for k in rng.choice(len(combos), size=min(pairs, len(combos)), replace=False):
        cases.append(combos[int(k)])
    return [(c, int(rng.integers(1 << 30))) for c in cases]


def predict_mse(log_csv: Path, model: Path, w: np.ndarray, t: np.ndarray, work: Path, tag: str,
                corrected: bool = True) -> float:
    """MSE of ``warpbridge predict`` on a check log after its first second (``--correction`` unless told not)."""
    pred = work / f"{tag}-pred.csv"
    code, text = run_cli(["predict", str(log_csv), "--model", str(model), "-o", str(pred)]
                         + (["--correction"] if corrected else []))
    if code != 0:
        raise RuntimeError(f"predict failed: {text}")
    wp = np.loadtxt(pred, delimiter=",", skiprows=1)[:, 1]
    keep = t >= t[0] + CHECK_SKIP_S
    return float(np.mean((w[keep] - wp[keep]) ** 2))


@dataclass
class FieldCase:
    """What a case's field log is drawn from; ``rng`` goes on to draw its check log."""

    rng: np.random.Generator
    noise: float
    t: np.ndarray
    u: np.ndarray
    airspeed: np.ndarray
    f_seed: int
    spec: dict
    mags: dict


MAGNITUDE = (2.5, 15.0)  # the effects' RMS change of the warp, in multiples of the sensor noise (log-uniform)


def field_case(plant: Family, case_seed: int, names: tuple[str, ...], duration: float, rate: float,
               magnitude: tuple[float, float] = MAGNITUDE) -> FieldCase:
    """The case's noise, input, airspeed and effect sizes (RMS change of the warp ``magnitude`` x the noise,
    2.5-15 unless told)."""
    rng = np.random.default_rng(case_seed)
    noise = float(rng.uniform(0.03, 0.05))
    t = timebase(duration, rate)
    u = excite(plant, t, "random", rng)
    v = airspeed_profile(t, rng.uniform(5, 9), rng.uniform(16, 22), int(rng.integers(1 << 30)))
    f_seed = int(rng.integers(1 << 30))
    spec, mags = {}, {}
    for n in names:
        m = float(math.exp(rng.uniform(math.log(magnitude[0]), math.log(magnitude[1]))))
        shape = (float(rng.uniform(-1, 1)), float(rng.uniform(-1, 1)))
        spec[n] = (magnitude_for(plant, n, m * noise, shape, t, u, v, f_seed), shape)
        mags[n] = m
    return FieldCase(rng, noise, t, u, v, f_seed, spec, mags)


def check_input(plant: Family, fc: FieldCase, duration: float, rate: float):
    """(t, input, airspeed, plant seed) of the case's check log: half the field log's length, another
    excitation (multisine, sweep or random) and airspeed range, drawn from the case's generator after the
    field log."""
    rng = fc.rng
    tc = timebase(0.5 * duration, rate)
    uc = excite(plant, tc, str(rng.choice(["multisine", "sweep", "random"])), rng)
    vc = airspeed_profile(tc, rng.uniform(2, 6), rng.uniform(12, 26), int(rng.integers(1 << 30)))
    return tc, uc, vc, int(rng.integers(1 << 30))


def run_case(plant: Family, seed: int, index: int, k: int, names: tuple[str, ...], case_seed: int, model: Path,
             args, work: Path, timed: bool) -> dict:
    fc = field_case(plant, case_seed, names, args.duration, args.rate, args.magnitude)
    noise, t, u, v, f_seed, spec, mags = fc.noise, fc.t, fc.u, fc.airspeed, fc.f_seed, fc.spec, fc.mags
    fld = run_log(plant, t, u, v, spec, noise, f_seed)
    clean0 = run_log(plant, t, u, v, {}, 0.0, f_seed).w_clean
    tc, uc, vc, c_seed = check_input(plant, fc, args.duration, args.rate)
    chk = run_log(plant, tc, uc, vc, spec, noise, c_seed)
    chk0 = run_log(plant, tc, uc, vc, {}, noise, c_seed)
    tag = f"{plant.name}-c{k}"
    field_csv, check_csv, check0_csv = (work / f"{tag}-{x}.csv" for x in ("field", "check", "check0"))
    write_log(field_csv, fld)
    write_log(check_csv, chk)
    write_log(check0_csv, chk0)
    report = work / f"{tag}-report.json"
    threads = args.threads
    t0 = time.perf_counter()
    code, text = run_cli(["diagnose", str(field_csv), "--model", str(model), "--report", str(report),
                          "--sensitivity", "--quiet", "--jobs", str(threads)])
    seconds_sens = time.perf_counter() - t0
    if code != 0:
        raise RuntimeError(f"diagnose failed on {tag}: {text}")
    rep = json.loads(report.read_text())
    seconds = None
    if timed:
        t0 = time.perf_counter()
        code, text = run_cli(["diagnose", str(field_csv), "--model", str(model), "--report",
                              str(work / f"{tag}-plain.json"), "--quiet", "--jobs", str(threads)])
        seconds = time.perf_counter() - t0
    from warpbridge.bridge.commands.modelio import load_model, save_model
    from warpbridge.model.effects import Effects

    nominal = load_model(model)
    mse_nom, mse_nom0 = (predict_mse(check_csv, model, chk.w, chk.t, work, f"{tag}-nom"),
                         predict_mse(check0_csv, model, chk0.w, chk0.t, work, f"{tag}-nom0"))
    bare_nom, bare_nom0 = (predict_mse(check_csv, model, chk.w, chk.t, work, f"{tag}-nom", False),
                           predict_mse(check0_csv, model, chk0.w, chk0.t, work, f"{tag}-nom0", False))
    by_decision: dict[str, dict] = {}
    mse_of: dict[str, tuple[float, float]] = {}  # (with the correction, bare)
    for alt in rep["alternatives"]:
        eff = {n: {f: (math.inf if v is None else v) for f, v in p.items()} for n, p in alt["effects"].items()}
        ek = json.dumps(eff, sort_keys=True, default=str)
        if ek not in mse_of:
            if not eff:
                mse_of[ek] = (mse_nom, bare_nom)
            else:
                aug = work / f"{tag}-aug{len(mse_of)}.json"
                mf = load_model(model)
                mf.effects = nominal.effects.merged(Effects.from_dict(eff))
                save_model(aug, mf)
                mse_of[ek] = tuple(predict_mse(check_csv, aug, chk.w, chk.t, work, f"{tag}-aug{len(mse_of)}", c)
                                   for c in (True, False))
        closed = [(m0 - m) / (m0 - m00) if names and m0 - m00 > 0 else None
                  for m, m0, m00 in zip(mse_of[ek], (mse_nom, bare_nom), (mse_nom0, bare_nom0), strict=True)]
        by_decision[blind_lofo.key(alt["decision"])] = {"verdict": sorted(alt["verdict"]), "gap_closed": closed[0],
                                                        "gap_closed_bare": closed[1],
                                                        "check_rms_after": math.sqrt(mse_of[ek][0]),
                                                        "to_aero_load": alt.get("to_aero_load", [])}
    fitq = nominal.fit
    misfit = math.sqrt(max(fitq.heldout_rms_deg ** 2 - fitq.noise_deg ** 2, 0.0))
    return {"family": plant.family, "plant": plant.name, "seed": seed, "plant_index": index, "case": k,
            "truth": sorted(names), "spec": describe(spec), "magnitude_x_noise": mags, "noise": noise,
            "effect_rms_deg": float(np.sqrt(np.mean((fld.w_clean - clean0) ** 2))),
            "bench_misfit_deg": misfit, "model_error_deg": rep["model_error_deg"],
            "default_decision": blind_lofo.key(rep["decision"]), "verdict": sorted(rep["verdict"]),
            "by_decision": by_decision, "seconds_sensitivity": seconds_sens, "seconds": seconds,
            "check_rms_nominal": math.sqrt(mse_nom), "check_rms_nominal_without_effects": math.sqrt(mse_nom0),
            "check_rms_bare": math.sqrt(bare_nom), "check_rms_bare_without_effects": math.sqrt(bare_nom0),
            "bound_hits": rep.get("bound_hits", []), "kept_beside_aero_load": rep.get("band_gain_by_airspeed", []),
            "sources": source_hash(DIAG_SOURCES)}


def case_job(family: str, seed: int, index: int, k: int, names, case_seed: int, args) -> dict:
    plant = draw_plants(seed, family, index + 1)[index]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        model = identified_model(plant, seed, index, args, work)
        timed = args.timing_every > 0 and (k % args.timing_every == 0)
        return run_case(plant, seed, index, k, tuple(names), case_seed, model, args, work, timed)


def plant_job(family: str, seed: int, index: int, args) -> str:
    plant = draw_plants(seed, family, index + 1)[index]
    with tempfile.TemporaryDirectory() as tmp:
        identified_model(plant, seed, index, args, Path(tmp))
    return plant.name


def run_all(jobs: list, fn, args, label: str, on_result=None) -> list:
    """Run ``fn(*job, args)`` for every job (in parallel when asked or when cores are free), handing each
    result to ``on_result`` as soon as it is there."""
    out = []
    workers = args.jobs or free_cores()
    bar = None
    if sys.stderr.isatty():
        from tqdm import tqdm

        bar = tqdm(total=len(jobs), desc=label, file=sys.stderr)
    if workers <= 1:
        for j in jobs:
            out.append(fn(*j, args))
            if on_result:
                on_result(out[-1])
            _tick(bar, label, len(out), len(jobs), out[-1])
        return out
    with ProcessPoolExecutor(workers) as pool:
        futs = [pool.submit(fn, *j, args) for j in jobs]
        for f in as_completed(futs):
            out.append(f.result())
            if on_result:
                on_result(out[-1])
            _tick(bar, label, len(out), len(jobs), out[-1])
    return out


def _tick(bar, label: str, i: int, n: int, res) -> None:
    if bar is not None:
        bar.update(1)
        return
    if isinstance(res, dict):
        mark = "ok" if res["verdict"] == res["truth"] else "WRONG"
        print(f"[{i}/{n}] {mark:<5} {res['plant']:<26} {res['spec']:<40} -> {res['verdict'] or '[]'}", flush=True)
    else:
        print(f"[{i}/{n}] {label}: {res}", flush=True)


def results_dir(cache: Path, duration: float = FIELD_S, rate: float = RATE, bench_duration: float = BENCH_S,
                magnitude: tuple[float, float] = MAGNITUDE, bench_check: bool = False) -> Path:
    """Where the results of these settings and of this code (the hash of ``DIAG_SOURCES``) are cached."""
    sizes = "" if tuple(magnitude) == MAGNITUDE else f"-m{magnitude[0]:g}-{magnitude[1]:g}"
    return cache / "results" / (f"d{duration:g}-r{rate:g}-b{bench_duration:g}{sizes}-{source_hash(DIAG_SOURCES)}"
                                + ("-check" if bench_check else ""))


def case_list(seeds: list[int], families: list[str], args: argparse.Namespace) -> list[tuple]:
    """Every case of those seeds and families: (family, seed, plant index, case index, effect names, specs)."""
    return [(fam, seed, i, k, list(names), cs) for seed in seeds for fam in families for i in range(args.plants)
            for k, (names, cs) in enumerate(draw_cases(seed, fam, i, args.nones, args.pairs))
            if not args.singles_only or len(names) == 1]


def cached_results(cases: list[tuple], res_dir: Path) -> tuple[list[dict], list[tuple]]:
    """(the cached results of these cases, the cases not in the cache)."""
    results, todo = [], []
    for c in cases:
        f = res_dir / f"{c[0]}-s{c[1]}-p{c[2]}-c{c[3]}.json"
        if f.is_file():
            results.append(json.loads(f.read_text()))
        else:
            todo.append(c)
    return results, todo


def provenance(results: list[dict]) -> str:
    """Which code the results were computed on: those of this code's sources (the hash the cache folder is
    named by) against results other sources computed (carried over by hand) or that predate the record."""
    here = source_hash(DIAG_SOURCES)
    by = Counter(r.get("sources") for r in results)
    text = f"computed on this code's sources ({here}): {by.pop(here, 0)} of {len(results)}"
    unrecorded = by.pop(None, 0)
    if by:
        text += "; on other sources: " + ", ".join(f"{h} {n}" for h, n in sorted(by.items()))
    if unrecorded:
        text += f"; not recorded (computed before the benchmark recorded it): {unrecorded}"
    return text


def choice_pool(args: argparse.Namespace, families: list[str]) -> tuple[list[dict] | None, str]:
    """The cached results of ``--choose-on-seed`` (every case of those seeds, at the benchmark's own sizes and
    with every kind of case, or exit saying which to run), and the phrase the fold table's heading gets;
    (None, "") without the option."""
    seeds = [int(s) for s in args.choose_on_seed.split(",") if s.strip()]
    if not seeds:
        return None, ""
    whole = argparse.Namespace(**{**vars(args), "singles_only": False})
    pool, missing = cached_results(case_list(seeds, families, whole),
                                   results_dir(args.cache, args.duration, args.rate, args.bench_duration,
                                               bench_check=args.bench_check))
    if missing:
        sys.exit(f"--choose-on-seed {args.choose_on_seed}: {len(missing)} of {len(missing) + len(pool)} cases are "
                 f"not in the cache; run `--seed {args.choose_on_seed}` (without --magnitude and --singles-only) "
                 f"with the same options first")
    return pool, f" of seed{'s' if len(seeds) > 1 else ''} {', '.join(map(str, seeds))}"


def plant_notes(results: list[dict]) -> dict[str, str]:
    """A word on each plant drawn again from its seed: a sheath's capstan wrap mu x bend and the tension ratio
    e^(mu x bend) across it (the friction's reach: the band's width and how much one Bouc-Wen state must hold);
    for the LuGre sheath also its viscous drag (the share of mu_c it adds at 20 mm/s: how rate dependent)."""
    notes = {}
    for fam, seed in sorted({(r["family"], r["seed"]) for r in results if r["family"] in ("sheath", "lugre-sheath")}):
        count = 1 + max(r["plant_index"] for r in results if (r["family"], r["seed"]) == (fam, seed))
        for plant in draw_plants(seed, fam, count):
            if fam == "sheath":
                bend, mu, extra = plant.params.bend_deg, plant.params.mu, ""
            else:
                bend, mu, extra = plant.bend_deg, plant.mu_c, f", viscous {plant.mu_v / plant.mu_c:.0%}"
            wrap = mu * math.radians(bend)
            notes[plant.name] = (f"bend {bend:.0f} deg, mu {mu:.2f}: wrap {wrap:.2f}, tension ratio "
                                 f"{math.exp(wrap):.1f}{extra}")
    return notes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--family", default=",".join(FAMILIES), help=f"families (default: all of {', '.join(FAMILIES)})")
    ap.add_argument("--seed", default="0,1", help="seeds (plants and magnitudes differ per seed; default 0,1)")
    ap.add_argument("--plants", type=int, default=PLANTS, help=f"plants per family and seed (default {PLANTS})")
    ap.add_argument("--pairs", type=int, default=PAIRS, help=f"random pairs of effects per plant (default {PAIRS})")
    ap.add_argument("--nones", type=int, default=NONES, help=f"no-effect cases per plant (default {NONES})")
    ap.add_argument("--quick", action="store_true", help="one plant per family and seed, one pair, one no-effect")
    ap.add_argument("--duration", type=float, default=FIELD_S, help="field log seconds (check logs: half)")
    ap.add_argument("--rate", type=float, default=RATE, help="samples per second")
    ap.add_argument("--bench-duration", type=float, default=BENCH_S, help="bench (identification) log seconds")
    ap.add_argument("--jobs", type=int, default=0, help="parallel cases (default: the cores free now)")
    ap.add_argument("--threads", type=int, default=1,
                    help="threads each diagnose fits on (default 1: --jobs already runs cases side by side)")
    ap.add_argument("--timing-every", type=int, default=4,
                    help="time a plain diagnose (no --sensitivity) on every n-th case (default 4)")
    ap.add_argument("--cache", type=Path, default=default_cache(), help="cache folder (outside the repository)")
    ap.add_argument("--magnitude", default="2.5,15",
                    help="range of the effects' sizes, RMS change of the warp in multiples of the noise (default "
                         "2.5,15; another range is cached apart)")
    ap.add_argument("--singles-only", action="store_true",
                    help="only the single-effect cases (the same draws as with the no-effect cases and pairs)")
    ap.add_argument("--report-only", action="store_true", help="print the tables from the cached results")
    ap.add_argument("--bench-check", action="store_true",
                    help="score each bench model on a second bench log of another input (identify --check), so "
                         "diagnose takes the larger of the two known errors (results cached apart)")
    ap.add_argument("--choose-on-seed", default="",
                    help="choose each fold's decision on the other families of these seeds (cached: run them "
                         "first), so the seeds scored are held out as well as the family")
    args = ap.parse_args()
    if args.quick:
        args.plants, args.pairs, args.nones = 1, 1, 1
    families = [f.strip() for f in args.family.split(",") if f.strip()]
    bad = [f for f in families if f not in FAMILIES]
    if bad:
        sys.exit(f"unknown family {', '.join(bad)} (known: {', '.join(FAMILIES)})")
    seeds = [int(s) for s in args.seed.split(",") if s.strip()]
    try:
        lo, hi = (float(x) for x in args.magnitude.split(","))
    except ValueError:
        sys.exit(f"--magnitude takes two numbers, low,high (got {args.magnitude!r})")
    if not 0 < lo <= hi:
        sys.exit(f"--magnitude needs 0 < low <= high (got {lo:g},{hi:g})")
    args.magnitude = (lo, hi)
    args.cache.mkdir(parents=True, exist_ok=True)
    res_dir = results_dir(args.cache, args.duration, args.rate, args.bench_duration, args.magnitude, args.bench_check)
    res_dir.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()

    cases = case_list(seeds, families, args)
    plants = sorted({(c[0], c[1], c[2]) for c in cases})
    results, todo = cached_results(cases, res_dir)
    pool, chosen_on = choice_pool(args, families)  # before the run: a missing seed is said at once
    if todo and not args.report_only:
        print(f"{len(cases)} cases ({len(results)} cached), {len(plants)} plants; cache {args.cache}", flush=True)
        need = sorted({(c[0], c[1], c[2]) for c in todo})
        run_all(need, plant_job, args, "identify bench logs")
        def keep(r: dict) -> None:
            (res_dir / f"{r['family']}-s{r['seed']}-p{r['plant_index']}-c{r['case']}.json").write_text(
                json.dumps(r, indent=1))
            results.append(r)

        run_all(todo, case_job, args, "diagnose cases", keep)
    if not results:
        print("no results")
        return
    default = results[0]["default_decision"]
    folds = blind_lofo.lofo(results, default, pool)
    print()
    print(f"blind diagnosis benchmark: {len(results)} cases, families {', '.join(sorted(folds))}, "
          f"seeds {', '.join(map(str, seeds))}; field logs {args.duration:g} s at {args.rate:g} Hz")
    print(provenance(results))
    print(f"\nleave-one-family-out: the decision for each family is chosen on the others{chosen_on}")
    print(blind_lofo.fold_table(folds, seeds))
    print()
    print(blind_lofo.pooled_table(folds, seeds))
    print()
    print(blind_lofo.effect_table(results, folds))
    print("\nthe nominal model on the bench (identify's held-out RMS) and what its model-error model still "
          "leaves (cross-validated)")
    print(blind_lofo.bench_error_table(results))
    print("\nthe nominal model on the check logs without effects (another excitation, RMS after the first "
          f"{CHECK_SKIP_S:g} s): bare (predict) and with its model-error correction (predict --correction)")
    print(blind_lofo.check_log_table(results))
    print("\neach plant, worst first: the nominal on the bench and on the check logs without effects (deg RMS, "
          "corrected), and its cases named exactly (its fold's decision)")
    print(blind_lofo.plant_table(results, folds, plant_notes(results)))
    print("\nthe decision's switches (each fold's decision with one forced on, scored as the pooled table)")
    print(blind_lofo.switch_table(folds))
    print("\nclose calls (each fold's decision and the best-scoring other one, on the other families, that gives its "
          "family a different result)")
    print(blind_lofo.close_calls(results, folds, pool))
    print("\neffects named beside an aero load, their held-out gain split by airspeed (fastest third of the log / "
          "slowest; such an effect goes to the load when the ratio exceeds the dynamic pressure's)")
    print(blind_lofo.aero_split_table(results, folds))
    print("\nwith the shipped default decision " + default + ":")
    rt = blind_lofo.rates(results, default)
    print(f"  singles {rt['single_ok']}/{rt['singles']}, pairs {rt['pair_ok']}/{rt['pairs']}, false alarms "
          f"{rt['false_alarms']}/{rt['nones']}, gap closed min {rt['min_closed']:.0%} median {rt['median_closed']:.0%}")
    print("  per family (not held out: the default was set on these families' folds in an earlier round):")
    print(blind_lofo.default_table(results, default))
    secs = [r["seconds"] for r in results if r.get("seconds") is not None]
    if secs:
        print(f"\ndiagnose run time ({len(secs)} timed cases, {args.duration:g} s at {args.rate:g} Hz, plain): "
              f"median {np.median(secs):.1f} s, max {np.max(secs):.1f} s (target < "
              f"{blind_lofo.TARGETS['seconds']:.0f} s); load average now {os.getloadavg()[0]:.1f}")
        for fam in sorted({r["family"] for r in results}):
            fs = [r["seconds"] for r in results if r["family"] == fam and r.get("seconds") is not None]
            if fs:
                print(f"  {fam:<20} {len(fs):>3} timed: median {np.median(fs):.1f} s, max {np.max(fs):.1f} s")
    print("\nmisattributed (each with its fold's decision):")
    print(blind_lofo.misses(results, folds))
    print(f"\nsingle effects closing less than {blind_lofo.TARGETS['min_closed']:.0%} of their check-log gap:")
    print(blind_lofo.short_closures(results, folds))
    print(f"\nsingle effects whose check-log gap is not scored (the effect adds under {blind_lofo.MIN_GAP:.0%} to the "
          f"nominal's check-log MSE, or lowers it):")
    print(blind_lofo.unscored_gaps(results))
    print("\nmisattributed with the shipped default decision:")
    print(blind_lofo.misses(results, default=default))
    if args.bench_check:
        plain_dir = res_dir.with_name(res_dir.name.removesuffix("-check"))
        without, _ = cached_results(cases, plain_dir)
        print("\nwith a check log of another input (identify --check) against the same cases without it, shipped "
              "default decision; a model 'does not carry' when its check raised the known error over 2x and over "
              "the noise (as identify warns; the field log's noise stands in for the check log's):")
        print(blind_lofo.check_comparison(results, without, default))
    hits = [r for r in results if r.get("bound_hits")]
    if hits:
        print(f"\nfitted parameters at a bound: {len(hits)} cases")
        for r in hits:
            print(f"  {r['plant']:<26} {r['spec']:<40} " + "; ".join(
                f"{h['parameter']} at {h['bound']} bound" for h in r["bound_hits"]))
    print(f"\n{len(results)} cases, {time.perf_counter() - t_start:.0f} s this run")


if __name__ == "__main__":
    main()
