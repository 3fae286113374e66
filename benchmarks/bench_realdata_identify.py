"""Local benchmark on measured tendon-sheath data (not a test): identify on one sine amplitude, predict the others.

Reads the surgical-robot tendon-sheath measurements in ``../shared/realdata/tsm-kaist``
(or the folder given as the first argument) without copying them: each file is
converted to the log format (t, u = desired angle, warp = measured angle) in a
temporary directory and the real ``warpbridge identify`` / ``predict`` commands
run on it. Reports held-out RMS beside a straight-line fit, and on ``0.txt``
(first 2000 rows, repeated rows dropped) the mean squared error beside the
published classic Bouc-Wen figure (0.72-0.78 deg^2).
Run: python benchmarks/bench_realdata_identify.py [DATA_DIR]
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import table  # noqa: E402

DEFAULT = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "tsm-kaist"


def to_csv(src: Path, dst: Path, u_col: int, w_col: int, max_rows: int | None = None, decimate: int = 1) -> Path:
    d = np.loadtxt(src, delimiter=",")
    t = d[:, 0]
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:  # two runs concatenated: keep the first
        d = d[: back[0] + 1]
    if max_rows:
        d = d[:max_rows]
    d = d[::decimate]
    np.savetxt(dst, np.column_stack([d[:, 0], d[:, u_col], d[:, w_col]]), delimiter=",", header="t,u,warp",
               comments="", fmt="%.9g")
    return dst


def line_rms(train: Path, test: Path) -> float:
    a = np.loadtxt(train, delimiter=",", skiprows=1)
    b = np.loadtxt(test, delimiter=",", skiprows=1)
    c1, c0 = np.polyfit(a[:, 1], a[:, 2], 1)
    return float(np.sqrt(np.mean((b[:, 2] - (c0 + c1 * b[:, 1])) ** 2)))


def predict_rms(cli, model: Path, log: Path, out: Path) -> float:
    assert cli(["predict", str(log), "--model", str(model), "-o", str(out)]) == 0
    pred = np.loadtxt(out, delimiter=",", skiprows=1)[:, 1]
    meas = np.loadtxt(log, delimiter=",", skiprows=1)[:, 2]
    # repeated timestamps are merged by the reader: compare on the merged grid
    t = np.loadtxt(log, delimiter=",", skiprows=1)[:, 0]
    keep = np.ones(t.size, bool)
    keep[:-1] = np.diff(t) > 0
    return float(np.sqrt(np.mean((pred - meas[keep]) ** 2)))


def main(data: Path) -> None:
    from warpbridge.bridge.cli import main as cli

    if not data.is_dir():
        print(f"no measured data at {data}: skipped")
        return
    tmp = Path(tempfile.mkdtemp(prefix="wb-realdata-"))
    rows = []
    conf = {a: to_csv(data / f"conf0_{a}.txt", tmp / f"conf0_{a}.csv", 1, 5, decimate=4) for a in (50, 60, 70)}
    for train_a in (50, 60, 70):
        model = tmp / f"model_{train_a}.json"
        t0 = time.perf_counter()
        assert cli(["identify", str(conf[train_a]), "-o", str(model), "--quiet"]) == 0
        wall = time.perf_counter() - t0
        fit = json.loads(model.read_text())["fit"]
        for test_a in (50, 60, 70):
            if test_a == train_a:
                continue
            rms = predict_rms(cli, model, conf[test_a], tmp / "pred.csv")
            rows.append([f"conf0 +-{train_a} deg", f"+-{test_a} deg", rms, line_rms(conf[train_a], conf[test_a]),
                         fit["heldout_rms_deg"], wall])
    print(table(rows, ["identified on", "predicted", "GBW RMS deg", "line RMS deg", "own held-out", "identify s"]))
    # the published classic Bouc-Wen baseline: 0.txt, first 2000 rows, repeated rows dropped
    base = to_csv(data / "0.txt", tmp / "zero.csv", 1, 3, max_rows=2000)
    model = tmp / "model_zero.json"
    assert cli(["identify", str(base), "-o", str(model), "--quiet", "--heldout", "0.25"]) == 0
    fit = json.loads(model.read_text())["fit"]
    full = predict_rms(cli, model, base, tmp / "pred0.csv")
    print()
    print(table([["0.txt first 2000 rows", full ** 2, fit["train_rms_deg"] ** 2, fit["heldout_rms_deg"] ** 2,
                  "0.72-0.78 (classic BW, SLSQP/BFGS/NM), 3.1 (GA)"]],
                ["log", "GBW MSE all", "GBW MSE train", "GBW MSE held-out", "published MSE deg^2"]))


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT)
