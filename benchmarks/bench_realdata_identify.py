"""Local benchmark on measured tendon-sheath data (not a test): does identification beat a straight line
on data it never saw?

Reads the surgical-robot tendon-sheath measurements in ``../shared/realdata/tsm-kaist``
(or the folder given as the first argument) without copying them: each file is
converted to the log format (t, u = desired angle, warp = measured angle; rows
with a repeated timestamp merged, keeping the last) in a temporary directory and
the real ``warpbridge identify`` / ``predict`` commands run on it. The straight
line is the least-squares line u -> warp fitted on the same training samples as
the model (the identified log's first 75 % by time). Every figure says which
samples it covers.

1. Each log, its own held-out last quarter (what ``identify`` reports), and whether
   ``identify`` says the data support the model.
2. The other logs of the same condition, predicted whole from their first sample
   (z0 estimated from it), with the model-error correction and without it: the
   three sine amplitudes of sheath configuration 0 (``conf0_A.txt``, 2 kHz logger,
   decimated to 500 Hz); for the bend series
   (``N.txt``, one log per bend) the other half of the same file, both ways.
3. ``0.txt``, first 2000 rows (the published baseline's segment): mean squared
   error over the training part, the held-out part and the whole segment, with the
   initial state estimated (the bare model, as the published fits are, and with the
   model-error correction of ``predict --correction``) and at rest (z0 = 0).
Run: python benchmarks/bench_realdata_identify.py [DATA_DIR]
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import table  # noqa: E402

from warpbridge.bridge.cli import main as cli  # noqa: E402
from warpbridge.model.boucwen import BoucWenParams, forward  # noqa: E402


def default_dir() -> Path:
    """``shared/realdata/tsm-kaist`` beside the repository or one of the folders above it."""
    here = Path(__file__).resolve()
    for up in here.parents[1:4]:
        d = up / "shared" / "realdata" / "tsm-kaist"
        if d.is_dir():
            return d
    return here.parents[2] / "shared" / "realdata" / "tsm-kaist"
BENDS = (0, 60, 120, 180, 240)
AMPLITUDES = (50, 60, 70)


def load(src: Path, u_col: int, w_col: int, max_rows: int | None = None, decimate: int = 1) -> np.ndarray:
    """Rows (t, u, warp): the first run of the file, repeated timestamps merged (the last row kept)."""
    d = np.loadtxt(src, delimiter=",")
    back = np.flatnonzero(np.diff(d[:, 0]) < 0)
    if back.size:  # a second run appended (t restarts): keep the first
        d = d[: back[0] + 1]
    if max_rows:
        d = d[:max_rows]
    d = d[::decimate]
    keep = np.ones(d.shape[0], bool)
    keep[:-1] = np.diff(d[:, 0]) > 0
    return d[keep][:, [0, u_col, w_col]]


def write(rows: np.ndarray, path: Path) -> Path:
    np.savetxt(path, rows, delimiter=",", header="t,u,warp", comments="", fmt="%.9g")
    return path


def rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e ** 2)))


class Bench:
    def __init__(self, tmp: Path) -> None:
        self.cli = cli
        self.tmp = tmp
        self.models: dict[str, tuple[Path, dict, np.ndarray, float]] = {}
        self.folds: list[str] = []  # fits whose first search's backbone folded inside the working range

    def identify(self, name: str, rows: np.ndarray) -> tuple[dict, float]:
        log = write(rows, self.tmp / f"{name}.csv")
        model = self.tmp / f"{name}.json"
        t0 = time.perf_counter()
        assert self.cli(["identify", str(log), "-o", str(model), "--quiet"]) == 0
        wall = time.perf_counter() - t0
        fit = json.loads(model.read_text())["fit"]
        train = rows[:, 0] < fit["split_time_s"]
        c1, c0 = np.polyfit(rows[train, 1], rows[train, 2], 1)
        self.models[name] = (model, fit, np.array([c0, c1]), wall)
        if "backbone_fold_deg" in fit:
            lo, hi = fit["working_range_deg"]
            self.folds.append(f"{name} (folded at {fit['backbone_fold_deg']:.1f} deg inside {lo:.1f}..{hi:.1f}; "
                              + ("searched again and kept)" if fit["fold_search_kept"] else "none without a fold)"))
        return fit, wall

    def predict(self, name: str, rows: np.ndarray, tag: str, corrected: bool = False) -> np.ndarray:
        """``warpbridge predict`` (with ``--correction``: plus the model-error correction the model carries)."""
        log = write(rows, self.tmp / f"{tag}.csv")
        out = self.tmp / f"{tag}.pred.csv"
        with open(os.devnull, "w") as null:
            stdout, sys.stdout = sys.stdout, null
            try:
                argv = ["predict", str(log), "--model", str(self.models[name][0]), "-o", str(out)]
                assert self.cli(argv + (["--correction"] if corrected else [])) == 0
            finally:
                sys.stdout = stdout
        return np.loadtxt(out, delimiter=",", skiprows=1)[:, 1]

    def line(self, name: str, u: np.ndarray) -> np.ndarray:
        c0, c1 = self.models[name][2]
        return c0 + c1 * u


def main(data: Path) -> None:
    if not data.is_dir():
        print(f"no measured data at {data}: skipped")
        return
    tmp = Path(tempfile.mkdtemp(prefix="wb-realdata-"))
    b = Bench(tmp)
    logs = {f"{n}.txt": load(data / f"{n}.txt", 1, 3) for n in BENDS}
    logs |= {f"conf0_{a}.txt": load(data / f"conf0_{a}.txt", 1, 5, decimate=4) for a in AMPLITUDES}

    print(f"load average at start {os.getloadavg()[0]:.1f} (2 cores shared)")
    # 1. each log, its own held-out last quarter
    rows1, walls, wins = [], [], 0
    for name, d in logs.items():
        fit, wall = b.identify(name, d)
        walls.append(wall)
        split = fit["split_time_s"]
        wins += fit["heldout_rms_deg"] < fit["linear_heldout_rms_deg"]
        rows1.append([name, d.shape[0], f"{d[0, 0]:.2f}-{split:.2f}", f"{split:.2f}-{d[-1, 0]:.2f}",
                      fit["train_rms_deg"], fit["heldout_rms_deg"], fit["linear_heldout_rms_deg"],
                      "yes" if fit["supported"] else "NO", wall])
        if not fit["supported"]:
            print(f"  {name}: {fit['support']}")
    print("1. Identified on each log's first 75 % (by time), scored on its last 25 % (RMS, deg)")
    print(table(rows1, ["log", "samples", "train t (s)", "held-out t (s)", "GBW train", "GBW held-out",
                        "line held-out", "supported", "identify s"]))
    print(f"GBW beats the line on {wins}/{len(logs)} held-out quarters; identify wall time median "
          f"{statistics.median(walls):.1f} s, max {max(walls):.1f} s")

    # 2. the other logs of the same condition, whole, from their first sample
    rows2, wins2, n2, corr_vs_bare = [], 0, 0, []
    for a in AMPLITUDES:
        name = f"conf0_{a}.txt"
        for other in AMPLITUDES:
            if other == a:
                continue
            d = logs[f"conf0_{other}.txt"]
            pred = b.predict(name, d, f"conf0_{a}_on_{other}")
            corr = b.predict(name, d, f"conf0_{a}_on_{other}_corr", corrected=True)
            g, ln = rms(pred - d[:, 2]), rms(b.line(name, d[:, 1]) - d[:, 2])
            late = d[:, 0] >= d[0, 0] + 1.0
            g1 = rms(pred[late] - d[late, 2])
            gc = rms(corr - d[:, 2])
            rows2.append([f"conf0 +-{a} deg", f"conf0 +-{other} deg (all {d.shape[0]})", g, g1, gc, ln])
            corr_vs_bare.append(gc - g)
            wins2 += g < ln
            n2 += 1
    for n in BENDS:
        d = logs[f"{n}.txt"]
        half = d[:, 0] < d[0, 0] + 0.5 * (d[-1, 0] - d[0, 0])
        parts = {"first half": d[half], "second half": d[~half]}
        for k, (which, part) in enumerate(parts.items()):
            name = f"{n}_{k}"
            b.identify(name, part)
            other_name, other = list(parts.items())[1 - k]
            pred = b.predict(name, other, f"{n}_{k}_on_other")
            corr = b.predict(name, other, f"{n}_{k}_on_other_corr", corrected=True)
            g, ln = rms(pred - other[:, 2]), rms(b.line(name, other[:, 1]) - other[:, 2])
            late = other[:, 0] >= other[0, 0] + 1.0
            gc = rms(corr - other[:, 2])
            rows2.append([f"{n}.txt {which}", f"{n}.txt {other_name} (all {other.shape[0]})", g,
                          rms(pred[late] - other[late, 2]), gc, ln])
            corr_vs_bare.append(gc - g)
            wins2 += g < ln
            n2 += 1
    print()
    print("2. Predicted on the other logs of the same condition, whole (z0 estimated from their first samples); "
          "the line is fitted on the same training samples as the model (RMS, deg)")
    print(table(rows2, ["identified on", "predicted (samples)", "GBW all", "GBW after 1 s",
                        "GBW all, predict --correction", "line all"]))
    dv = np.array(corr_vs_bare)
    print(f"GBW beats the line on {wins2}/{n2} other logs; against the bare model, predict --correction is better "
          f"on {int(np.sum(dv < -1e-9))}, worse on {int(np.sum(dv > 1e-9))} and the same on "
          f"{int(np.sum(abs(dv) <= 1e-9))} (no correction learned)")

    # 3. the published baseline's segment
    seg = load(data / "0.txt", 1, 3, max_rows=2000)
    fit, _ = b.identify("zero2000", seg)
    pred = b.predict("zero2000", seg, "zero2000_self")
    corrected = b.predict("zero2000", seg, "zero2000_corrected", corrected=True)
    t = seg[:, 0]
    train, held = t < fit["split_time_s"], t >= fit["split_time_s"]
    late = t >= t[0] + 1.1
    p = BoucWenParams.from_dict(json.loads((tmp / "zero2000.json").read_text())["params"])
    at_rest = forward(p, seg[:, 1])[0]
    errs = [pred - seg[:, 2], corrected - seg[:, 2], at_rest - seg[:, 2]]
    print()
    print(f"3. 0.txt, first 2000 rows ({seg.shape[0]} after merging repeated timestamps, t = {t[0]:.2f}-{t[-1]:.2f} s);"
          " published classic Bouc-Wen MSE 0.72-0.78 deg^2 (SLSQP/BFGS/NM), 3.1 (GA)")
    parts = [("training part", f"t < {fit['split_time_s']:.2f} s", train),
             ("held-out part", f"t >= {fit['split_time_s']:.2f} s", held),
             ("whole segment", "all", np.ones(t.size, bool)),
             ("whole segment after 1.1 s", f"t >= {t[0] + 1.1:.2f} s", late)]
    print(table([[part, f"{cover} ({int(m.sum())})", *(float(np.mean(e[m] ** 2)) for e in errs)]
                 for part, cover, m in parts],
                ["part", "samples", "GBW MSE deg^2 (z0 estimated)", "with predict --correction",
                 "GBW MSE deg^2 (z0 = 0)"]))
    print(f"identifications whose first search's backbone folded inside the working range and were searched "
          f"again: {', '.join(b.folds) or 'none'}")
    print(f"load average at end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else default_dir())
