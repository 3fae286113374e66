"""``warpbridge predict LOG.csv --model MODEL.json -o PRED.csv``: warp the model predicts from the logged tendon input.

Applies the model's effects (delay, rate limit, backlash, ..., sensor lag,
drift, aero load with the log's airspeed). Writes ``t,warp_pred``; if the log
has measured warp, prints the RMS error.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from warpbridge.bridge.commands.logfile import read_log, write_csv_atomic
from warpbridge.bridge.commands.modelio import load_model


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="CSV log with columns t,u (warp optional)")
    p.add_argument("--model", required=True, help="MODEL.json (or 'paper')")
    p.add_argument("-o", "--output", required=True, help="CSV to write: t,warp_pred")
    p.add_argument("--wing", choices=("left", "right"), help="read this wing's columns of a bridge log")
    p.add_argument("--plot", help="PNG of measured vs predicted loops")


def main(args: argparse.Namespace) -> int:
    mf = load_model(args.model)
    data = read_log(args.log, wing=args.wing, require_warp=False, min_rows=2)
    for note in data.notes:
        print(f"note: {note}", file=sys.stderr)
    if mf.effects.active() and "aero_load" in mf.effects.active() and data.airspeed is None:
        print("note: the model has aero_load but the log has no airspeed column: assuming no airflow",
              file=sys.stderr)
    _, w_pred = mf.plant.simulate(data.t, data.u, data.airspeed, z0=mf.z0)
    write_csv_atomic(args.output, {"t": data.t, "warp_pred": w_pred})
    msg = f"wrote {args.output}: {len(data)} predictions"
    if data.warp is not None and np.isfinite(data.warp).any():
        ok = np.isfinite(data.warp)
        rms = float(np.sqrt(np.mean((data.warp[ok] - w_pred[ok]) ** 2)))
        msg += f"; RMS error against the logged warp {rms:.4f} deg"
        if args.plot:
            from warpbridge.bridge.commands.plots import plot_identification

            plot_identification(args.plot, data.t[ok], data.u[ok], data.warp[ok], w_pred[ok],
                                np.zeros(int(ok.sum()), bool), title="prediction")
    print(msg)
    return 0
