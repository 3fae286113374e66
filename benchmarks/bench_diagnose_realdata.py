"""Local benchmark (not a test): diagnose measured tendon-sheath data with a model from another configuration.

    python benchmarks/bench_diagnose_realdata.py [--data DIR] [--base 0] [--keep DIR] [--json OUT]

Uses the TSM-KAIST measurements (``<data>/README.md``: a tendon-sheath joint of
an endoscopic surgery robot; ``N.txt`` with N the sheath bend in degrees,
``conf0_A.txt`` sine runs of amplitude A at bend 0). The data are read from
their folder and converted to temporary CSV logs (t, u = desired angle,
warp = measured angle); nothing is copied into the repository. Skips with a
message when the folder is absent (default: ``$WARPBRIDGE_REALDATA/tsm-kaist``
or ``shared/realdata/tsm-kaist`` beside the repository).

Steps: ``identify`` on the base configuration; ``diagnose`` every other bend
and the base configuration's other-amplitude runs; prints what it names, the
held-out shrinkage inside the log, and how far the gap shrinks when the
augmented model predicts the files it did not fit (the neighbouring bends).
``--json OUT`` also writes those figures, keyed by the hash of the diagnosis's sources as the blind
benchmark's archives are (``benchmarks/results/realdata-diagnose-<hash>.json`` is what
``results_page.py`` reads).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_diagnose_blind import DIAG_SOURCES, source_hash  # noqa: E402

from warpbridge.bridge.cli import main as cli  # noqa: E402
from warpbridge.bridge.commands.logfile import write_csv_atomic  # noqa: E402

# the data sit beside the repository (``<repo>/../shared/realdata/tsm-kaist``) unless told otherwise
DEFAULT = Path(os.environ.get("WARPBRIDGE_REALDATA",
                              Path(__file__).resolve().parents[2] / "shared" / "realdata")) / "tsm-kaist"


def run_cli(argv: list[str]) -> tuple[int, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli(argv)
    return code, out.getvalue() + err.getvalue()


def convert(src: Path, dst: Path) -> Path:
    """t, u (desired angle), warp (measured angle) of the first run in the file, one row per time stamp."""
    d = np.loadtxt(src, delimiter=",")
    ycol = 3 if src.name[0].isdigit() else 5
    t = d[:, 0]
    back = np.flatnonzero(np.diff(t) < 0)
    end = int(back[0]) + 1 if back.size else t.size
    if src.name.startswith("conf0"):  # 2 kHz: decimate to 200 Hz
        sl = slice(0, end, 10)
    else:
        sl = slice(0, end)
    t, u, w = t[sl], d[sl, 1], d[sl, ycol]
    last = np.concatenate([np.diff(t) > 0, [True]])  # repeated rows: keep the last of each time stamp
    write_csv_atomic(dst, {"t": t[last], "u": u[last], "warp": w[last]})
    return dst


def rms_of(log: Path, model: Path, tmp: Path) -> float:
    pred = tmp / f"pred-{log.stem}-{model.stem}.csv"
    code, text = run_cli(["predict", str(log), "--model", str(model), "-o", str(pred)])
    if code != 0:
        raise RuntimeError(text)
    w = np.loadtxt(log, delimiter=",", skiprows=1)[:, 2]
    wp = np.loadtxt(pred, delimiter=",", skiprows=1)[:, 1]
    return float(np.sqrt(np.mean((w - wp) ** 2)))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=DEFAULT)
    ap.add_argument("--base", default="0", help="bend configuration identified (default 0)")
    ap.add_argument("--keep", type=Path, default=None, help="keep logs, models and reports here")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures to this JSON file")
    args = ap.parse_args()
    if not (args.data / f"{args.base}.txt").is_file():
        print(f"skipped: no measured data at {args.data} (set --data or WARPBRIDGE_REALDATA)")
        return 0
    bends = sorted(int(p.stem) for p in args.data.glob("[0-9]*.txt"))
    with tempfile.TemporaryDirectory() as tmpname:
        tmp = args.keep or Path(tmpname)
        tmp.mkdir(parents=True, exist_ok=True)
        logs = {str(b): convert(args.data / f"{b}.txt", tmp / f"bend{b}.csv") for b in bends}
        for p in sorted(args.data.glob("conf0_*.txt")):
            logs[p.stem] = convert(p, tmp / f"{p.stem}.csv")
        model = tmp / f"model-bend{args.base}.json"
        code, text = run_cli(["identify", str(logs[args.base]), "-o", str(model), "--quiet"])
        if code != 0:
            print(text)
            return 1
        md = json.loads(model.read_text())
        fit = md["fit"]
        record = {"benchmark": "bench_diagnose_realdata", "sources": source_hash(DIAG_SOURCES),
                  "data": "tsm-kaist", "base": args.base,
                  "identified": {k: fit[k] for k in ("train_rms_deg", "heldout_rms_deg", "noise_deg")}, "logs": []}
        print(f"identified bend {args.base}: training RMS {fit['train_rms_deg']:.3f}, held-out RMS "
              f"{fit['heldout_rms_deg']:.3f} deg, noise {fit['noise_deg']:.3f} deg")
        em = md.get("model_error")
        if em:
            print(f"model-error model on the bench log: {em['bench_rms_before_deg']:.3f} -> "
                  f"{em['bench_rms_after_deg']:.3f} deg RMS cross-validated ({', '.join(em['sets']) or 'none'})")
        print(f"\n{'log':<10} {'verdict':<34} {'held-out RMS':>22} {'gap':>6}   other logs (nominal -> augmented RMS)")
        for name, log in logs.items():
            if name == args.base:
                continue
            rep_path, aug = tmp / f"report-{name}.json", tmp / f"aug-{name}.json"
            code, text = run_cli(["diagnose", str(log), "--model", str(model), "--report", str(rep_path),
                                  "--out-model", str(aug), "--quiet"])
            if code != 0:
                print(f"{name:<10} diagnose failed: {text.strip()}")
                continue
            rep = json.loads(rep_path.read_text())
            sh = rep["shrinkage"]
            gc = sh["gap_closed"]
            verdict = ", ".join(rep["verdict"]) or "[]"
            others, others_rms = [], []
            if name.isdigit():
                i = bends.index(int(name))
                for j in (i - 1, i + 1):
                    if 0 <= j < len(bends) and str(bends[j]) != args.base:
                        o = logs[str(bends[j])]
                        r0, r1 = rms_of(o, model, tmp), rms_of(o, aug, tmp)
                        others.append(f"bend{bends[j]} {r0:.2f} -> {r1:.2f}")
                        others_rms.append({"log": str(bends[j]), "nominal_rms_deg": r0, "augmented_rms_deg": r1})
            gap = f"{gc:.0%}" if gc is not None and math.isfinite(gc) else "n/a"
            record["logs"].append({
                "log": name, "verdict": rep["verdict"], "effects": rep["effects"],
                "kept_unnamed": {n: k["fitted"] for n, k in (rep.get("kept_unnamed") or {}).items()},
                "ambiguous": [a["equally_good"] for a in rep["ambiguities"]],
                "heldout_rms_before_deg": sh["heldout_rms_before_deg"],
                "heldout_rms_after_deg": sh["heldout_rms_after_deg"],
                "gap_closed": gc, "other_logs": others_rms})
            print(f"{name:<10} {verdict:<34} {sh['heldout_rms_before_deg']:>9.3f} -> "
                  f"{sh['heldout_rms_after_deg']:<8.3f} {gap:>6}   {'; '.join(others)}")
            for n, p in rep["effects"].items():
                vals = ", ".join(f"{k} {v:.4g}" for k, v in p.items() if v is not None)
                print(f"{'':<10}   {n}: {vals}")
            for n, k in (rep.get("kept_unnamed") or {}).items():  # in the augmented model, read as another's part
                vals = ", ".join(f"{f} {v:.4g}" for f, v in k["fitted"].items() if v is not None)
                print(f"{'':<10}   kept in the model, not named: {n}: {vals}")
            for a in rep["ambiguities"]:
                print(f"{'':<10}   ambiguous: {' / '.join(a['equally_good'])}")
            for h in rep.get("bound_hits", []):
                print(f"{'':<10}   AT A BOUND: {h['parameter']} = {h['value']:.4g} at its {h['bound']} bound "
                      f"{h['limit']:.4g}")
            conf = {c["effect"]: c["confidence"] for c in rep["candidates"] if c.get("in_verdict")}
            if conf:
                print(f"{'':<10}   confidence: " + ", ".join(f"{k} {v:.2f}" for k, v in conf.items()))
    if args.json:
        args.json.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
