"""``warpbridge identify LOG.csv -o MODEL.json``: the nominal Bouc-Wen model from a log.

The steps of ``model.identification``: a deterministic start design whose backbone and
state coefficients are solved exactly per trial shape, then Levenberg-Marquardt
on the forward output error, the last part of the log held out, the initial
hysteretic state estimated from the first samples, and with ``--max-delay`` a
transport delay in front of the model (the rig's servo, link and sensor lag,
written to the model's effects as ``delay_s``); then the model-error model for
``diagnose`` and a 95 % interval for every parameter. Prints training and
held-out RMS, the noise floor, a straight-line baseline fitted on the same
training samples and whether the model beats it (if not, one line saying why the
data do not support the model), what the log does not excite, and the
parameters the data do not determine; ``--plot`` draws measured vs model loops
and time series. Every output path is checked before the fit starts.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from tqdm import tqdm

from warpbridge.bridge.commands.logfile import LogData, read_log
from warpbridge.bridge.commands.modelio import save_model
from warpbridge.bridge.commands.plots import loop_axis, plot_identification
from warpbridge.bridge.errors import UserError
from warpbridge.model.diagnosis.check import input_check
from warpbridge.model.diagnosis.start import bench_known_error
from warpbridge.model.effects import Effects
from warpbridge.model.identification import DELAY_GRID_S, LAG_GRID_S, identify
from warpbridge.model.model_error import ErrorModel, bench_error_model
from warpbridge.model.modelfile import FitQuality, ModelFile

PLOT_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")
MAX_LAG_S = LAG_GRID_S[-1]  # the longest servo lag the scan tries
MAX_DELAY_S = DELAY_GRID_S[-1]  # the longest delay the scan tries: the search a model to diagnose with needs


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="CSV log with columns t,u,warp (or a bridge log with --wing)")
    p.add_argument("-o", "--output", required=True, help="MODEL.json to write")
    p.add_argument("--wing", choices=("left", "right"), help="read this wing's columns of a bridge log")
    p.add_argument("--plot", help="PNG of measured vs model loops, time series and residual")
    p.add_argument("--heldout", type=float, default=0.25, help="fraction of the log held out (default 0.25)")
    p.add_argument("--seed", type=int, default=0,
                   help="scramble of the start design (default 0, the fixed default design). On a log that "
                        "excites the loop well, seeds end at fits within a few percent of each other; on a poorly "
                        "excited one (the report says so) they can end in basins of different depth. Another seed "
                        "is a check: keep the fit with the lower training RMS, never choose by the held-out part")
    p.add_argument("--maxiter", type=int, default=150,
                   help="most Levenberg-Marquardt steps of each refinement (default 150; at most 40 are taken on "
                        "the search's part of the log)")
    p.add_argument("--max-delay", type=float, default=0.0,
                   help="search a transport delay up to this long (s) in front of the model: the servo, link and "
                        f"sensor lag of the rig; {MAX_DELAY_S:g} for a model to diagnose with (default 0: "
                        "none, the model the feed-forward flies best with)")
    p.add_argument("--max-lag", type=float, default=MAX_LAG_S,
                   help="scan a servo lag (first-order, its position loop, and its rated speed) up to this long "
                        f"(s) in front of the model, kept when it fits the log better (default {MAX_LAG_S:g}; 0: "
                        "none). A closed-loop log's command jumps faster than the servo follows: fed the raw "
                        "command, the model reverses where the tendon never went")
    p.add_argument("--check", metavar="LOG",
                   help="a second bench log of the same rig, recorded with another input (a sweep, a multisine), "
                        "in the bench log's format (read with the same --wing): the model is scored on it, and "
                        "diagnose takes its error there as the model's known error when it is larger than on the "
                        "bench log (a model that does not carry to another input)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def check_outputs(outputs: dict[str, str | None], plots: tuple[str, ...] = ()) -> None:
    """Refuse, before any work, output paths that cannot be written: a missing or unwritable folder,
    a folder given as a file, a figure in a format matplotlib does not write."""
    for opt, path in outputs.items():
        if not path:
            continue
        p = Path(path)
        d = p.parent if str(p.parent) else Path(".")
        if not d.is_dir():
            raise UserError(f"{opt} {path}: directory {d} does not exist")
        if p.is_dir():
            raise UserError(f"{opt} {path}: is a directory, not a file")
        if not os.access(d, os.W_OK):
            raise UserError(f"{opt} {path}: directory {d} is not writable")
        if opt in plots and p.suffix.lower() not in PLOT_SUFFIXES:
            raise UserError(f"{opt} {path}: a figure must end in {', '.join(PLOT_SUFFIXES)}")


class Progress:
    """A tqdm bar per stage on stderr (silent when not a terminal unless forced)."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self.bar = None
        self.stage = None

    def __call__(self, stage: str, i: int, n: int) -> None:
        if not self.enabled:
            return
        label = {"design": "start design (linear solve per trial shape)", "refine": "refinement (Levenberg-Marquardt)",
                 "refine again": "refinement again, from the next starts",
                 "global": "global search (differential evolution), the starts disagreeing",
                 "refine without a fold": "refinement again, the backbone kept from folding",
                 "line": "refinement again, from the straight line", "polish": "refinement on more of the log",
                 "delay": "transport delay scan",
                 "lag": "refinement with the servo lag the scan found"}.get(stage, stage)
        if not sys.stderr.isatty():  # a log file gets a line per quarter, not a redrawn bar
            q = 4 * i // max(n, 1)
            if stage != self.stage or q != getattr(self, "_q", -1):
                self.stage, self._q = stage, q
                print(f"{label}: {i}/{n}", file=sys.stderr, flush=True)
            return
        if stage != self.stage:
            self.close()
            self.bar = tqdm(total=n, desc=label, unit="it", file=sys.stderr, leave=False)
            self.stage = stage
        self.bar.n = min(i, n)
        self.bar.refresh()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None


def main(args: argparse.Namespace) -> int:
    check_outputs({"-o": args.output, "--plot": args.plot}, plots=("--plot",))
    if not 0.05 <= args.heldout <= 0.5:
        raise UserError("--heldout must lie between 0.05 and 0.5")
    if args.maxiter < 1:
        raise UserError("--maxiter must be at least 1")
    if not 0.0 <= args.max_delay <= MAX_DELAY_S:
        raise UserError(f"--max-delay must lie between 0 and {MAX_DELAY_S:g} s (the longest delay the scan tries)")
    if not 0.0 <= args.max_lag <= MAX_LAG_S:
        raise UserError(f"--max-lag must lie between 0 and {MAX_LAG_S:g} s (the longest lag the scan tries)")
    data = read_log(args.log, wing=args.wing)
    for note in data.notes:
        print(f"note: {note}", file=sys.stderr)
    check = read_log(args.check, wing=args.wing) if args.check else None  # a bad check log is said before the fit
    for note in check.notes if check is not None else ():
        print(f"note: {args.check}: {note}", file=sys.stderr)
    progress = Progress(enabled=not args.quiet)
    t0 = time.perf_counter()
    try:
        res = identify(data.t, data.u, data.warp, heldout_frac=args.heldout, seed=args.seed, maxiter=args.maxiter,
                       max_delay_s=args.max_delay, max_lag_s=args.max_lag, sent=data.u_sent, progress=progress)
    except ValueError as e:
        raise UserError(f"{args.log}: {e}") from None
    finally:
        progress.close()
    elapsed = time.perf_counter() - t0
    fit = FitQuality(train_rms_deg=res.train_rms, heldout_rms_deg=res.heldout_rms, noise_deg=res.noise,
                     extra={k: v for k, v in res.fit_dict().items()
                            if k not in ("train_rms_deg", "heldout_rms_deg", "noise_deg")} | {"seconds": elapsed})
    meta = {"source_log": Path(args.log).name, "wing": args.wing, "samples": len(data),
            "created": datetime.now(UTC).isoformat(timespec="seconds"), "seed": args.seed}
    # z0 stays at rest: the state at the start of this log says nothing about another log's (predict
    # and diagnose estimate it from each log's first samples); the fit record keeps this log's
    mf = ModelFile(params=res.params, effects=Effects(delay_s=res.delay_s, servo_tau_s=res.servo_tau_s,
                                                         servo_rate_mm_s=res.servo_rate_mm_s,
                                                         servo_deadband_mm=res.servo_deadband_mm), fit=fit,
                   meta=meta)
    mf.model_error = bench_model_error(mf, data)
    check_lines = []
    if check is not None:
        try:
            fit.extra["check"], check_lines = score_check_log(mf, check, Path(args.check).name)
        except ValueError as e:
            raise UserError(f"--check {args.check}: {e}") from None
    save_model(args.output, mf)
    if args.plot:
        x, xlabel = loop_axis(mf.effects, data.t, data.u, data.u_sent)
        plot_identification(args.plot, data.t, x, data.warp, res.w_pred, res.heldout_mask,
                            title=f"{Path(args.log).name}: identified generalized Bouc-Wen model", xlabel=xlabel)
    ratio = res.heldout_rms / res.noise if res.noise > 0 else float("nan")
    split = res.split_time
    print(f"identified {Path(args.log).name} ({len(data)} samples, {data.t[-1] - data.t[0]:.1f} s) in {elapsed:.1f} s")
    print(f"  training RMS {res.train_rms:.4f} deg (t < {split:.2f} s, {res.n_train} samples), held-out RMS "
          f"{res.heldout_rms:.4f} deg (t >= {split:.2f} s, {res.n_heldout} samples; {ratio:.2f}x the noise floor "
          f"{res.noise:.4f} deg)")
    print(f"  straight-line baseline (fitted on the same training samples) held-out RMS "
          f"{res.linear_heldout_rms:.4f} deg")
    p = res.params
    if res.delay_s > 0:
        print(f"  transport delay {1e3 * res.delay_s:.1f} ms in front of the model (the rig's servo, link and sensor "
              "lag; effects.delay_s)")
    if res.servo_tau_s > 0 or math.isfinite(res.servo_rate_mm_s) or res.servo_deadband_mm > 0:
        cap = f", capped at {res.servo_rate_mm_s:.3g} mm/s" if math.isfinite(res.servo_rate_mm_s) else ""
        band = f", dead band {res.servo_deadband_mm:.3g} mm" if res.servo_deadband_mm > 0 else ""
        print(f"  servo lag {1e3 * res.servo_tau_s:.1f} ms{cap}{band} in front of the model (the servo's position "
              "loop, a first-order lag at most at its rated speed to the edge of its dead band; effects.servo_lag)")
    print(f"  u = {p.a1:.5g} w^2 + {p.a2:.5g} w + {p.a3:.5g} + {p.az:g} z;  A = {p.A:.5g}, n = {p.n:.4g}, "
          f"b = [{', '.join(f'{b:.4g}' for b in p.b)}]")
    if res.trace.restarts:
        print("  the first refinement ended at the upper limit of the exponent n: searched again from the next "
              "starts, " + ("the second fitted the training part better and was kept" if res.trace.restart_kept
                            else "the first still fitted the training part better"))
    if res.trace.line_restart:
        print(f"  the first result fitted the training part worse than the best straight line "
              f"({res.linear_train_rms:.4f} deg): refined again from the line and the quadratic backbone")
    if res.trace.fold_deg is not None:
        lo, hi = res.trace.working_range_deg
        first, unfolded = res.trace.fold_train_rms
        if res.trace.fold_outcome == "kept":
            outcome = f"and that model was kept (training RMS {first:.4f} -> {unfolded:.4f} deg)"
        elif res.trace.fold_outcome == "still folds":
            outcome = "but found none without a fold: the first model kept"
        else:
            outcome = (f"but it fits the training part worse ({first:.4f} -> {unfolded:.4f} deg): the data show the "
                       "fold, the first model kept")
        print(f"  the first search's backbone folded at {res.trace.fold_deg:.2f} deg, inside the working range "
              f"{lo:.2f}..{hi:.2f} deg (beyond the fold the model would hold its warp): searched again with the "
              f"fold kept outside it, {outcome}")
    if res.support is not None and not res.support.supported:
        print(f"warning: {res.support.reason}")
    for line in excitation_lines(res):
        print(line)
    print(f"wrote {args.output}" + (f" and {args.plot}" if args.plot else ""))
    if mf.model_error is not None:
        em = mf.model_error
        print(f"  model-error model for diagnose: bench residual {em.rms_before_deg:.4f} -> {em.rms_after_deg:.4f} deg "
              f"RMS cross-validated ({', '.join(em.sets) or 'no correction'})")
    for line in check_lines:
        print(line)
    if not np.isfinite(res.heldout_rms):
        return 1
    return 0


CARRY_FACTOR = 2.0  # a check-log error this many times the bench's own (and over its noise) is worth a warning


def score_check_log(mf: ModelFile, check, name: str) -> tuple[dict, list[str]]:
    """The model's error on a check log of another input (``model.diagnosis.check``): the record MODEL.json keeps
    under ``fit.check`` and the lines ``identify`` prints (a warning when it is over ``CARRY_FACTOR`` x the
    bench's and over the check log's noise)."""
    rec = {"log": name} | input_check(mf.params, mf.effects, mf.model_error, check.t, check.u, check.warp,
                                      check.airspeed).to_dict()
    corrected = mf.model_error is not None
    bench = bench_known_error(mf, rec["noise_deg"], corrected)  # the bench's alone, as diagnose weighs it
    on_check = rec["known_error_corrected_deg" if corrected else "known_error_bare_deg"]
    kind = "with the model-error correction" if corrected else "bare"
    lines = [f"  check log {name} ({rec['samples']} samples after its first second): RMS "
             + (f"{rec['rms_corrected_deg']:.4f} deg with the correction, " if corrected else "")
             + f"{rec['rms_bare_deg']:.4f} deg bare; noise {rec['noise_deg']:.4f} deg; error beyond the noise "
             f"{on_check:.4f} deg {kind}, against {bench:.4f} on the bench log"]
    if on_check > CARRY_FACTOR * max(bench, 0.5 * rec["noise_deg"]):
        than = f"{on_check / bench:.1f}x its error on the bench log" if bench > 0 else "none on the bench log"
        lines.append(f"warning: the model misses the check log by {on_check:.4f} deg beyond its noise, "
                     f"{than}: it does not carry to another "
                     "input as well as to its own (a sheath whose friction remembers many reversals). diagnose "
                     "takes the check log's error as the model's known error, so it names only changes above it; "
                     "identified on a bench input with reversals at several amplitudes (a multisine) it may fit better")
    return rec, lines


def bench_model_error(mf: ModelFile, data: LogData) -> ErrorModel | None:
    """What the identified model still gets wrong on this (bench) log, learned for ``diagnose``."""
    try:
        return bench_error_model(mf.params, mf.effects, data.t, data.u, data.warp, data.u_sent)
    except (ValueError, np.linalg.LinAlgError) as e:
        print(f"note: no model-error model: {e}", file=sys.stderr)
        return None


def excitation_lines(res) -> list[str]:
    """What the log does not excite and which parameters it leaves undetermined (95 % intervals wider than the
    value, or than a tenth of the search box), one line each."""
    lines = []
    if res.excitation is not None:
        lines += [f"note: excitation: {n}" for n in res.excitation.notes]
    unc = res.uncertainty
    if unc is not None and unc.undetermined:
        shown = []
        for name in unc.undetermined:
            iv = unc.params.get(name) or unc.search.get(name)
            shown.append(f"{name} = {iv.value:.4g} [{iv.lo:.4g}, {iv.hi:.4g}]" if iv is not None else name)
        lines.append("note: the data do not determine " + "; ".join(shown) + f" (95 % intervals, "
                     f"{unc.effective_samples:.0f} effective samples of {unc.samples}): the log does not pin "
                     "them down; a richer input (reversals at several levels, the whole travel) would")
    return lines
