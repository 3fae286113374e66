"""``warpbridge identify LOG.csv -o MODEL.json``: the nominal Bouc-Wen model from a log.

Differential evolution then Nelder-Mead on the forward output error, the last
part of the log held out; prints training and held-out RMS, the noise floor
and a straight-line baseline; ``--plot`` draws measured vs model loops.
"""

from __future__ import annotations

import argparse
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from warpbridge.bridge.commands.logfile import read_log
from warpbridge.bridge.commands.modelio import save_model
from warpbridge.bridge.errors import UserError
from warpbridge.model.identify import identify
from warpbridge.model.model_error import ErrorModel, bench_error_model
from warpbridge.model.modelfile import FitQuality, ModelFile


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="CSV log with columns t,u,warp (or a bridge log with --wing)")
    p.add_argument("-o", "--output", required=True, help="MODEL.json to write")
    p.add_argument("--wing", choices=("left", "right"), help="read this wing's columns of a bridge log")
    p.add_argument("--plot", help="PNG of measured vs model loops")
    p.add_argument("--heldout", type=float, default=0.25, help="fraction of the log held out (default 0.25)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the search (default 0)")
    p.add_argument("--maxiter", type=int, default=150, help="generations of the global search (default 150)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


class Progress:
    """A tqdm bar per stage on stderr (silent when not a terminal unless forced)."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self.bar = None
        self.stage = None

    def __call__(self, stage: str, i: int, n: int) -> None:
        if not self.enabled:
            return
        from tqdm import tqdm

        label = {"search": "global search (DE)", "polish": "polish (Nelder-Mead)"}.get(stage, stage)
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
    data = read_log(args.log, wing=args.wing)
    for note in data.notes:
        print(f"note: {note}", file=sys.stderr)
    if not 0.05 <= args.heldout <= 0.5:
        raise UserError("--heldout must lie between 0.05 and 0.5")
    progress = Progress(enabled=not args.quiet)
    t0 = time.perf_counter()
    try:
        res = identify(data.t, data.u, data.warp, heldout_frac=args.heldout, seed=args.seed, maxiter=args.maxiter,
                       progress=progress)
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
    mf = ModelFile(params=res.params, fit=fit, meta=meta)
    mf.model_error = bench_model_error(mf, data)
    save_model(args.output, mf)
    if args.plot:
        from warpbridge.bridge.commands.plots import plot_identification

        plot_identification(args.plot, data.t, data.u, data.warp, res.w_pred, res.heldout_mask,
                            title=f"{Path(args.log).name}: identified generalized Bouc-Wen model")
    ratio = res.heldout_rms / res.noise if res.noise > 0 else float("nan")
    print(f"identified {Path(args.log).name} ({len(data)} samples, {data.t[-1] - data.t[0]:.1f} s) in {elapsed:.1f} s")
    print(f"  training RMS {res.train_rms:.4f} deg, held-out RMS {res.heldout_rms:.4f} deg "
          f"({ratio:.2f}x the noise floor {res.noise:.4f} deg)")
    print(f"  straight-line baseline held-out RMS {res.linear_heldout_rms:.4f} deg")
    p = res.params
    print(f"  u = {p.a1:.5g} w^2 + {p.a2:.5g} w + {p.a3:.5g} + {p.az:g} z;  A = {p.A:.5g}, n = {p.n:.4g}, "
          f"b = [{', '.join(f'{b:.4g}' for b in p.b)}]")
    print(f"wrote {args.output}" + (f" and {args.plot}" if args.plot else ""))
    if mf.model_error is not None:
        em = mf.model_error
        print(f"  model-error model for diagnose: bench residual {em.rms_before_deg:.4f} -> {em.rms_after_deg:.4f} deg "
              f"RMS cross-validated ({', '.join(em.sets) or 'no correction'})")
    if not np.isfinite(res.heldout_rms):
        return 1
    return 0


def bench_model_error(mf: ModelFile, data) -> ErrorModel | None:
    """What the identified model still gets wrong on this (bench) log, learned for ``diagnose``."""
    try:
        return bench_error_model(mf.params, mf.effects, data.t, data.u, data.warp)
    except (ValueError, np.linalg.LinAlgError) as e:
        print(f"note: no model-error model: {e}", file=sys.stderr)
        return None
