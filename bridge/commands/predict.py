"""``warpbridge predict LOG.csv --model MODEL.json -o PRED.csv``: warp the model predicts from the logged tendon input.

Applies the model's effects (delay, rate limit, backlash, ..., sensor lag,
drift, aero load with the log's airspeed). ``--correction`` also adds the
model-error correction ``identify`` learned from the bench residual (what the
nominal model got wrong there; ``diagnose`` always judges a field log against
it): it carries a bench's servo, link and sensor dynamics over to any log, but
on measured data it can be worse than the bare model on another amplitude, so
it is not the default. The hysteretic state at the start
of the log is estimated from its first samples when it has measured warp
(a log rarely starts at rest), and for a model with a play (backlash,
capstan stall) the edge its slack was last taken up on, by a pull or a
release; otherwise MODEL.json's ``z0`` is used (and a pull). Writes
``t,warp_pred``; if the log has measured warp, prints the RMS error over the
whole log and after its first 5 s, and ``--plot`` draws the prediction against
the log. It says when the log drives the tendon beyond the travel of the log the
model was identified on (``fit.travel_mm``): the model extrapolates there.
Every output path is checked before the work starts.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from warpbridge.bridge.commands.identify import check_outputs
from warpbridge.bridge.commands.logfile import read_log, write_csv_atomic
from warpbridge.bridge.commands.modelio import load_model, travel_note
from warpbridge.model.plant import Plant

SETTLE_S = 5.0  # the RMS is also reported after this much of the log


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="CSV log with columns t,u (warp optional)")
    p.add_argument("--model", required=True, help="MODEL.json (or 'paper')")
    p.add_argument("-o", "--output", required=True, help="CSV to write: t,warp_pred")
    p.add_argument("--wing", choices=("left", "right"), help="read this wing's columns of a bridge log")
    p.add_argument("--plot", help="PNG of the prediction against the logged warp (needs a warp column)")
    p.add_argument("--correction", action="store_true",
                   help="add the model-error correction MODEL.json carries (what the model got wrong on its bench "
                        "log, as diagnose uses it)")


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan")


def main(args: argparse.Namespace) -> int:
    from warpbridge.model.effects import slack_side_name
    from warpbridge.model.initial_state import estimate_plant_start

    check_outputs({"-o": args.output, "--plot": args.plot}, plots=("--plot",))
    mf = load_model(args.model)
    data = read_log(args.log, wing=args.wing, require_warp=False, min_rows=2)
    for note in data.notes:
        print(f"note: {note}", file=sys.stderr)
    if mf.effects.active() and "aero_load" in mf.effects.active() and data.airspeed is None:
        print("note: the model has aero_load but the log has no airspeed column: assuming no airflow",
              file=sys.stderr)
    beyond = travel_note(mf, data.u)
    if beyond:
        print(f"note: {beyond}", file=sys.stderr)
    has_warp = data.warp is not None and np.isfinite(data.warp).any()
    if args.plot and not has_warp:
        print("note: the log has no measured warp: --plot skipped", file=sys.stderr)
    em = mf.model_error if args.correction else None
    if args.correction and em is None:
        em_note = "no model-error correction (the model file carries none)"
    elif em is not None:
        em_note = (f"model-error correction added ({', '.join(em.sets)}; bench RMS {em.rms_before_deg:.4f} -> "
                   f"{em.rms_after_deg:.4f} deg)")
    else:
        em_note = "bare model" + (" (--correction adds its model-error correction)" if mf.model_error else "")
    plant = Plant(mf.params, mf.effects, em)
    if has_warp:
        z0, side = estimate_plant_start(plant, data.t, data.u, data.warp, data.airspeed)
        plant = replace(plant, slack_side=side)
        play = f", the play's slack taken up by a {slack_side_name(side)}," if mf.effects.has_slack else ""
        z0_note = f"initial state z0 = {z0:.4g}{play} estimated from the log's first samples"
    else:
        z0 = mf.z0
        z0_note = f"initial state z0 = {z0:.4g} from the model file (no measured warp to estimate it from)"
    _, w_pred = plant.simulate(data.t, data.u, data.airspeed, z0=z0, sent=data.u_sent)
    write_csv_atomic(args.output, {"t": data.t, "warp_pred": w_pred})
    print(f"wrote {args.output}: {len(data)} predictions; {z0_note}; {em_note}")
    if has_warp:
        ok = np.isfinite(data.warp)
        late = ok & (data.t >= data.t[0] + SETTLE_S)
        rms = _rms(data.warp[ok] - w_pred[ok])
        msg = (f"RMS error against the logged warp {rms:.4f} deg over the whole log "
               f"({int(ok.sum())} samples, t = {data.t[0]:.2f}-{data.t[-1]:.2f} s)")
        if late.any() and late.sum() < ok.sum():
            msg += f"; {_rms(data.warp[late] - w_pred[late]):.4f} deg after its first {SETTLE_S:g} s"
        print(msg)
        if args.plot:
            from warpbridge.bridge.commands.plots import loop_axis, plot_prediction

            x, xlabel = loop_axis(plant.effects, data.t, data.u, data.u_sent, plant.slack_side)
            plot_prediction(args.plot, data.t[ok], x[ok], data.warp[ok], w_pred[ok],
                            title=f"{Path(args.log).name} predicted by {Path(str(args.model)).name}", xlabel=xlabel)
            print(f"wrote {args.plot}")
    return 0
