"""Benchmark: does identification's answer depend on its seed? Held-out RMS over seeds, old code beside new.

Three sets of logs, each identified with ``--seed`` 0..N-1 by the current code and by a
previous revision (``--baseline REV``, extracted from git into a temporary package by
``bench_identify.load_baseline`` and run interleaved with the current code, so both see
the same load), each with the defaults a user gets (no prior, no delay):

- ``bench``: the 24 bench logs of ``bench_identify`` (4 Bouc-Wen plants x 6 excitations,
  60 s at 500 Hz, 0.05 deg of sensor noise), scored on their held-out last quarter;
- ``sitl``: the bridge's own cycle logs (``bridge-cycles.csv``, both wings) of ``warpbridge sitl``
  runs, closed loop (ff+PI against the hysteresis, sensor noise, the servo's lag), for the
  Bouc-Wen wing and ``--plant sheath``, several scenarios and seeds (recorded into ``--sitl-dir``
  when missing), scored on their held-out last quarter; beside them the open-loop bench log of
  the same plant (``sitl.wing.bench_log``, 90 s at 200 Hz) identified the same way, and per
  closed-loop log the same run's true tendon travel against the rig sensor's warp (what a tendon
  encoder would log; ``rig.npz`` of the run, seed 0, no servo in front), which has the run's own
  excitation without the command, the PI or the servo between it and the warp;
- ``realdata``: the measured tendon-sheath logs of ``../shared/realdata/tsm-kaist`` (read, never
  copied), scored on their held-out last quarter and on the other logs of their series (the
  other sine amplitudes of configuration 0; the other bends), predicted whole from their first
  samples.

Per log: held-out RMS of each seed (min, median, max), the spread (max / min), the default
run's (seed 0) held-out against the best seed of the old code, the straight line's held-out
RMS and the noise floor, the wall time per fit (median) and each fit's servo lag. Writes every
figure as JSON (``--json``, default ``benchmarks/results/identify-seeds.json``) after each log,
keyed by the sources the run imported (``stored.py``; ``results_page.py`` shows it and says when
it is stale), so a run cut short keeps what it measured.
Run: python benchmarks/bench_identify_seeds.py --baseline REV [--seeds 10] [--old-seeds-bench 10]
     [--sets sitl,bench,realdata] [--sitl-dir DIR] [--realdata DIR] [--json PATH]
"""

from __future__ import annotations

import argparse
import inspect
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_identify as BI  # noqa: E402
from _common import table  # noqa: E402
from bench_realdata_identify import default_dir as realdata_dir  # noqa: E402
from bench_realdata_identify import load as load_realdata  # noqa: E402
from stored import keyed, write_json  # noqa: E402

from warpbridge.bridge.commands.logfile import read_log  # noqa: E402
from warpbridge.model import identification as current  # noqa: E402
from warpbridge.model.boucwen import BoucWenParams, forward  # noqa: E402
from warpbridge.model.initial_state import estimate_z0  # noqa: E402
from warpbridge.model.signals import linear_fit, noise_floor  # noqa: E402
from warpbridge.sitl.flex_sensor import FlexSensorSpec  # noqa: E402
from warpbridge.sitl.like_for_like import bench_params, rigged, sheath_spec  # noqa: E402
from warpbridge.sitl.sheath import SheathPlant  # noqa: E402
from warpbridge.sitl.wing import WingSpec, bench_log  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SITL_PLANTS = ("bouc-wen", "sheath")
SITL_SCENARIOS = ("random", "steps", "sweep")
SITL_SEEDS = (0, 1)
BENDS = (0, 60, 120, 180, 240)
SUBPROCESS = ("warpbridge.bridge.cli",)  # record_sitl's `warpbridge sitl` runs
AMPLITUDES = (50, 60, 70)


def shown_paths(arg: str | None) -> str | None:
    """Comma-separated files as the results show them: relative to the repository when inside it, else by name
    (no path of the machine that ran the benchmark is written into a result)."""
    if not arg:
        return arg
    out = []
    for part in arg.split(","):
        p = Path(part).resolve()
        out.append(str(p.relative_to(REPO)) if p.is_relative_to(REPO) else p.name)
    return ",".join(out)


def rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e ** 2)))


def other_rms(params: BoucWenParams, others: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """Mean over the other logs of the RMS of the model run on each whole, z0 from its first samples."""
    out = []
    for u, w in others:
        z0 = estimate_z0(params, u, w)
        out.append(rms(forward(params, u, z0=z0)[0] - w))
    return float(np.mean(out)) if out else math.nan


def fit_once(ident, t, u, w, seed: int, others, sent=None) -> dict:
    """One identification with a user's defaults; the cycle log's send times when the log has them and the code
    takes them."""
    kw = {"sent": sent} if sent is not None and "sent" in inspect.signature(ident.identify).parameters else {}
    t0 = time.perf_counter()
    r = ident.identify(t, u, w, seed=seed, **kw)
    wall = time.perf_counter() - t0
    return {"seed": seed, "heldout_rms_deg": r.heldout_rms, "train_rms_deg": r.train_rms, "seconds": wall,
            "other_rms_deg": other_rms(r.params, others) if others else None, "params": r.params.to_dict(),
            "servo_tau_s": getattr(r, "servo_tau_s", None),
            "servo_rate_mm_s": rate if (rate := getattr(r, "servo_rate_mm_s", math.inf)) < math.inf else None}


def line_other(t, u, w, others) -> tuple[float, float | None]:
    """Held-out RMS of the straight line on the log's last quarter and, mean, on the other logs."""
    split = t[0] + 0.75 * (t[-1] - t[0])
    train = t < split
    c0, c1 = linear_fit(u, w, train)
    held = rms(c0 + c1 * u[~train] - w[~train])
    oth = float(np.mean([rms(c0 + c1 * uo - wo) for uo, wo in others])) if others else None
    return held, oth


def plain(out: dict) -> dict:
    """``out`` with numpy scalars as Python numbers, ready for ``write_json``."""
    return json.loads(json.dumps(out, default=float))


def summary(runs: list[dict], key: str = "heldout_rms_deg") -> dict:
    v = [r[key] for r in runs if r[key] is not None and math.isfinite(r[key])]
    if not v:
        return {"min": None, "median": None, "max": None, "spread": None}
    return {"min": min(v), "median": statistics.median(v), "max": max(v), "spread": max(v) / min(v)}


# ---- the logs ------------------------------------------------------------------------------------

def bench_logs() -> list[dict]:
    out = []
    for pi, name in enumerate(BI.PLANTS):
        for fi, fam in enumerate(BI.FAMILIES):
            t, u, w, _ = BI.bench_log(BI.PLANTS[name], fam, 10 * pi + fi)
            out.append({"set": "bench", "log": f"{name}/{fam}", "plant": name, "t": t, "u": u, "w": w, "others": []})
    return out


def record_sitl(d: Path, seeds: tuple[int, ...] = SITL_SEEDS) -> None:
    """``warpbridge sitl`` runs into d (each skipped when its cycle log is there)."""
    d.mkdir(parents=True, exist_ok=True)
    for plant in SITL_PLANTS:
        for sc in SITL_SCENARIOS:
            for seed in seeds:
                run = d / f"{plant}-{sc}-s{seed}"
                if (run / "bridge-cycles.csv").exists():
                    continue
                cmd = [sys.executable, "-m", "warpbridge.bridge.cli", "sitl", "--plant", plant, "--scenario", sc,
                       "--seed", str(seed), "--out", str(run), "--no-plot", "--no-gcs"]
                subprocess.run(cmd, check=True, capture_output=True, text=True)


def sitl_bench_log(plant: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The open-loop bench log (90 s, 200 Hz, low-passed random tendon) of the plant the SITL flies."""
    if plant == "sheath":
        params = rigged(bench_params())
        lo, hi = SheathPlant(params).travel_range(12.0)
        cols = bench_log(sheath_spec(params), lo, hi, seed=0)
    else:
        p = BoucWenParams.paper()
        lo, hi = p.a3, p.a1 * 144.0 + p.a2 * 12.0 + p.a3
        cols = bench_log(WingSpec(), lo, hi, seed=0)
    return cols["t"], cols["u"], cols["warp"]


def sitl_logs(d: Path, seeds: tuple[int, ...] = SITL_SEEDS) -> list[dict]:
    out = []
    for plant in SITL_PLANTS:
        t, u, w = sitl_bench_log(plant)
        out.append({"set": "sitl", "log": f"{plant} open-loop bench", "plant": plant, "t": t, "u": u, "w": w,
                    "others": [], "bench": True})
        for sc in SITL_SCENARIOS:
            for seed in seeds:
                for wing in ("left", "right"):
                    data = read_log(d / f"{plant}-{sc}-s{seed}" / "bridge-cycles.csv", wing=wing)
                    out.append({"set": "sitl", "log": f"{plant} {sc} s{seed} {wing}", "plant": plant, "t": data.t,
                                "u": data.u, "w": data.warp, "others": [], "bench": False, "sent": data.u_sent,
                                "rig": (d / f"{plant}-{sc}-s{seed}" / "rig.npz", wing)})
    return out


def true_travel_fit(rig: Path, wing: str) -> dict | None:
    """Seed-0 identification, without a servo in front, of a SITL run's true tendon travel against the warp its
    sensor read (``rig.npz``: per sensor read the time, counts, true warp, tendon mm and airspeed; counts to deg
    through the rig's calibration table), scored on the held-out last quarter; None when the run has no rig
    record."""
    if not rig.is_file():
        return None
    with np.load(rig) as z:
        reads = z[f"{wing}_reads"].reshape(-1, 5)
    t, u, w = reads[:, 0], reads[:, 3], np.asarray(FlexSensorSpec().deg_of_counts(reads[:, 1]), dtype=np.float64)
    keep = np.concatenate([[True], np.diff(t) > 0])
    t0 = time.perf_counter()
    r = current.identify(t[keep], u[keep], w[keep], seed=0, max_lag_s=0.0)
    return {"heldout_rms_deg": r.heldout_rms, "train_rms_deg": r.train_rms, "seconds": time.perf_counter() - t0,
            "samples": int(keep.sum())}


def realdata_logs(d: Path) -> list[dict]:
    series = {"bend": {f"{n}.txt": load_realdata(d / f"{n}.txt", 1, 3) for n in BENDS},
              "conf0": {f"conf0_{a}.txt": load_realdata(d / f"conf0_{a}.txt", 1, 5, decimate=4) for a in AMPLITUDES}}
    out = []
    for name, logs in series.items():
        for fname, rows in logs.items():
            others = [(r[:, 1], r[:, 2]) for f, r in logs.items() if f != fname]
            out.append({"set": "realdata", "log": fname, "plant": name, "t": rows[:, 0], "u": rows[:, 1],
                        "w": rows[:, 2], "others": others})
    return out


# ---- the run -------------------------------------------------------------------------------------

def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", help="git revision whose identification runs beside the current one")
    ap.add_argument("--seeds", type=int, default=10, help="seeds of the current code per log (default 10)")
    ap.add_argument("--seeds-bench", type=int, help="seeds of the current code per bench log (default --seeds)")
    ap.add_argument("--old-seeds-bench", type=int, default=10, help="seeds of the old code per bench log")
    ap.add_argument("--old-seeds-sitl", type=int, default=10, help="seeds of the old code per SITL log")
    ap.add_argument("--old-seeds-realdata", type=int, default=10, help="seeds of the old code per measured log")
    ap.add_argument("--sets", default="sitl,bench,realdata")
    ap.add_argument("--sitl-dir", help="folder of the SITL runs (recorded there when missing; default a temporary one)")
    ap.add_argument("--realdata", help="folder of the measured logs (default ../shared/realdata/tsm-kaist)")
    ap.add_argument("--json", default=str(REPO / "benchmarks" / "results" / "identify-seeds.json"))
    ap.add_argument("--versions", default="new,old",
                    help="which code to run: new, old, both (default) or none (with --resume and --merge: only the "
                         "table of figures measured before)")
    ap.add_argument("--sitl-seeds", default="0,1", help="seeds of the SITL runs (default 0,1)")
    ap.add_argument("--resume", help="JSONs of earlier runs of this benchmark (comma-separated: parts run side by "
                                     "side on the same code): their logs are kept, not run again")
    ap.add_argument("--merge", help="a JSON of this benchmark whose runs fill in the versions not run here "
                                    "(the old code's figures measured in an earlier run of the same logs)")
    args = ap.parse_args()
    merge_name, resume_names = shown_paths(args.merge), shown_paths(args.resume)

    versions = {}
    if "new" in args.versions.split(","):
        versions["new"] = current
    if args.baseline and "old" in args.versions.split(","):
        versions["old"] = BI.load_baseline(args.baseline)
    sitl_seeds = tuple(int(x) for x in args.sitl_seeds.split(","))
    done = {}
    for part in args.resume.split(",") if args.resume else ():
        if Path(part).exists():
            done |= {(r["set"], r["log"]): r for r in json.loads(Path(part).read_text())["logs"]}
    merged = {}
    if args.merge:
        prev = json.loads(Path(args.merge).read_text())
        merged = {(r["set"], r["log"]): r for r in prev["logs"]}
    t = np.arange(2000) / BI.FS  # compile every kernel before timing
    u = 4.5 + 2 * np.sin(2 * np.pi * t)
    for v in versions.values():
        v.identify(t, u, 5 + 2.5 * np.sin(2 * np.pi * t - 0.3), maxiter=2, polish_evals=20)
    old_seeds = {"bench": args.old_seeds_bench, "sitl": args.old_seeds_sitl, "realdata": args.old_seeds_realdata}
    head = (f"{os.cpu_count()} CPUs; load average at start {os.getloadavg()[0]:.1f}; "
            f"running {list(versions) or 'none'}; current code {args.seeds} seeds "
            f"({args.seeds_bench or args.seeds} on bench logs), old code "
            f"({args.baseline or 'none'}) seeds per set {old_seeds}; kept from {args.resume or '-'}, the versions not "
            f"run filled in from {args.merge or '-'}")
    print(head, flush=True)
    baseline = args.baseline or (prev.get("baseline") if args.merge and "old" not in versions else None)
    out = {"format": "warpbridge-bench-identify-seeds/1", "baseline": baseline, "seeds": args.seeds,
           "old_seeds": old_seeds, "merged_from": merge_name, "resumed_from": resume_names,
           "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "logs": []}
    sets = args.sets.split(",")
    logs: list[dict] = []
    for s in sets:
        if s == "sitl":
            d = Path(args.sitl_dir) if args.sitl_dir else Path(tempfile.mkdtemp(prefix="wb-sitl-"))
            record_sitl(d, sitl_seeds)
            logs += sitl_logs(d, sitl_seeds)
        elif s == "bench":
            logs += bench_logs()
        elif s == "realdata":
            d = Path(args.realdata) if args.realdata else realdata_dir()
            if d.is_dir():
                logs += realdata_logs(d)
            else:
                print(f"no measured data at {d}: skipped")
    shown = list(versions) + [k for k in ("new", "old") if k not in versions and merged]
    for lg in logs:
        t, u, w = lg["t"], lg["u"], lg["w"]
        if (lg["set"], lg["log"]) in done:
            rec = done[(lg["set"], lg["log"])] | {"resumed_from": resume_names}
            for key, runs in merged.get((lg["set"], lg["log"]), {}).get("runs", {}).items():
                if key not in rec["runs"]:
                    rec["runs"][key] = runs
                    rec.setdefault("merged_from", {})[key] = merge_name
            if "rig" in lg and "true_travel" not in rec:
                # only of the recording the kept figures are of (a run records its cycle logs afresh)
                same = rec.get("samples") == int(t.size) and math.isclose(rec.get("seconds_of_log", math.nan),
                                                                          float(t[-1] - t[0]))
                rec["true_travel"] = true_travel_fit(*lg["rig"]) if same else None
            summarise(rec, bool(lg["others"]))
            out["logs"].append(rec)
            print(f"{lg['set']}  {lg['log']}  (kept from {args.resume})", flush=True)
            continue
        line_held, line_oth = line_other(t, u, w, lg["others"])
        rec = {"set": lg["set"], "log": lg["log"], "plant": lg["plant"], "samples": int(t.size),
               "seconds_of_log": float(t[-1] - t[0]), "noise_deg": noise_floor(w), "line_heldout_rms_deg": line_held,
               "line_other_rms_deg": line_oth, "open_loop_bench": bool(lg.get("bench", False)), "runs": {}}
        n = {"new": args.seeds_bench if lg["set"] == "bench" and args.seeds_bench else args.seeds,
             "old": old_seeds[lg["set"]]}
        if "rig" in lg:
            rec["true_travel"] = true_travel_fit(*lg["rig"])
        for key in versions:
            rec["runs"][key] = []
        for key, runs in merged.get((lg["set"], lg["log"]), {}).get("runs", {}).items():
            if key not in versions:
                rec["runs"][key] = runs
                rec.setdefault("merged_from", {})[key] = merge_name
        for seed in range(max([n[k] for k in versions], default=0)):
            for key, ident in versions.items():  # interleaved: both see the same load
                if seed < n[key]:
                    try:
                        rec["runs"][key].append(fit_once(ident, t, u, w, seed, lg["others"], lg.get("sent")))
                    except ValueError as e:
                        rec["runs"][key].append({"seed": seed, "error": str(e), "heldout_rms_deg": None,
                                                 "train_rms_deg": None, "seconds": None, "other_rms_deg": None})
        summarise(rec, bool(lg["others"]))
        out["logs"].append(rec)
        write_json(Path(args.json), keyed(plain(out), also=SUBPROCESS))
        row = table_row(rec, shown)
        print("  ".join(f"{x:.4g}" if isinstance(x, float) else str(x) for x in row), flush=True)
    head = ["set", "log", "noise", "line held-out"]
    for key in shown:
        head += [f"{key} min", f"{key} median", f"{key} max", f"{key} s/fit"]
    head.append("new seed 0 / old best")
    print()
    print("Held-out RMS (deg) of the log's last quarter over seeds; s/fit: median wall seconds per fit")
    print(table([table_row(rec, shown) for rec in out["logs"]], head))
    print_summary(out, shown)
    out["finished"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    write_json(Path(args.json), keyed(plain(out), also=SUBPROCESS))
    print(f"load average at end {os.getloadavg()[0]:.1f}; wrote {args.json}")


def summarise(rec: dict, others: bool) -> None:
    """Each version's figures over its seeds, and the default run's over the old code's best."""
    for key in rec["runs"]:
        runs = rec["runs"][key]
        rec[key] = summary(runs) | {
            "seconds_median": statistics.median([r["seconds"] for r in runs if r["seconds"]] or [0]),
            "default_heldout_rms_deg": runs[0]["heldout_rms_deg"] if runs else None,
            "other": summary(runs, "other_rms_deg") if others else None}
    if "old" in rec and "new" in rec and rec["old"]["min"] and rec["new"]["default_heldout_rms_deg"] is not None:
        rec["default_over_old_best"] = rec["new"]["default_heldout_rms_deg"] / rec["old"]["min"]


def table_row(rec: dict, shown: list[str]) -> list:
    row = [rec["set"], rec["log"], rec["noise_deg"], rec["line_heldout_rms_deg"]]
    for key in shown:
        s = rec.get(key) or {"min": math.nan, "median": math.nan, "max": math.nan, "seconds_median": math.nan}
        row += [s["min"], s["median"], s["max"], s["seconds_median"]]
    row.append(rec.get("default_over_old_best", math.nan))
    return row


def print_summary(out: dict, versions: list[str]) -> None:
    for s in ("sitl", "bench", "realdata"):
        recs = [r for r in out["logs"] if r["set"] == s]
        if not recs:
            continue
        for key in versions:
            have = [r for r in recs if (r.get(key) or {}).get("median") is not None]
            if not have:
                continue
            spreads = [r[key]["spread"] for r in have]
            secs = [r[key]["seconds_median"] for r in have]
            beat = sum(1 for r in have if r[key]["median"] < r["line_heldout_rms_deg"])
            print(f"{s} {key}: seed spread (max/min held-out) median {statistics.median(spreads):.4f}, "
                  f"max {max(spreads):.4f}; beats the line (median seed) on {beat}/{len(have)}; "
                  f"s/fit median {statistics.median(secs):.2f}")
        ratios = [r["default_over_old_best"] for r in recs if "default_over_old_best" in r]
        if ratios:
            within = sum(1 for x in ratios if x <= 1.05)
            print(f"{s}: new seed 0 / old best of its seeds: median {statistics.median(ratios):.3f}, max "
                  f"{max(ratios):.3f}; within 1.05x on {within}/{len(ratios)}")
        if s == "sitl":
            for plant in SITL_PLANTS:
                for key in versions:
                    bench = [r for r in recs if r["plant"] == plant and r["open_loop_bench"]
                             and (r.get(key) or {}).get("median")]
                    closed = [r for r in recs if r["plant"] == plant and not r["open_loop_bench"]
                              and (r.get(key) or {}).get("default_heldout_rms_deg") is not None]
                    if not bench or not closed:
                        continue
                    ratio = [r[key]["default_heldout_rms_deg"] / bench[0][key]["median"] for r in closed]
                    print(f"sitl {plant} {key}: closed-loop held-out (seed 0) / open-loop bench held-out (median "
                          f"seed): median {statistics.median(ratio):.2f}, max {max(ratio):.2f}; within 1.5x on "
                          f"{sum(1 for x in ratio if x <= 1.5)}/{len(ratio)}")
                    own = [(r[key]["default_heldout_rms_deg"], r["true_travel"]["heldout_rms_deg"]) for r in closed
                           if r.get("true_travel")]
                    if own and key == "new":  # the reference is the current code's fit
                        ratio = [a / b for a, b in own]
                        print(f"sitl {plant} {key}: closed-loop held-out (seed 0) / the same run's true tendon travel "
                              f"held-out: median {statistics.median(ratio):.2f}, max {max(ratio):.2f}; that "
                              f"over the open-loop bench: {min(b for _, b in own) / bench[0][key]['median']:.2f}-"
                              f"{max(b for _, b in own) / bench[0][key]['median']:.2f}x")

if __name__ == "__main__":
    main()
