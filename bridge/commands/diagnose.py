"""``warpbridge diagnose LOG.csv --model MODEL.json --report REPORT.json``: why the wing disobeys its model.

Free-runs the model on the logged tendon input, splits the residual by
hysteresis phase, warp level, frequency band, time and airspeed, fits every
effect of the vocabulary as an augmentation on part of the log and scores it on
the rest, and names the effects that explain the gap (``[]`` when it is only
noise and the model's known error). Writes REPORT.json, prints a summary,
optionally writes the augmented model (``--out-model``, usable by ``predict``
and the bridge's feed-forward) and a figure (``--plot``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

from warpbridge.bridge.commands.logfile import read_log, write_text_atomic
from warpbridge.bridge.commands.modelio import load_model, save_model, travel_note
from warpbridge.bridge.errors import UserError
from warpbridge.model.diagnosis import diagnose
from warpbridge.model.diagnosis.options import DECISION_GRID, Decision, DiagnoseOptions
from warpbridge.model.effect_registry import EFFECT_NAMES


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", help="CSV log with columns t,u,warp[,airspeed] (or a bridge log with --wing)")
    p.add_argument("--model", required=True, help="MODEL.json the log is compared with (or 'paper')")
    p.add_argument("--report", required=True, help="REPORT.json to write")
    p.add_argument("--out-model", help="write the augmented model (effects set) to this MODEL.json")
    p.add_argument("--plot", help="PNG: residual by phase and band, loops and time series before/after")
    p.add_argument("--wing", choices=("left", "right"), help="read this wing's columns of a bridge log")
    p.add_argument("--effects", default=",".join(EFFECT_NAMES),
                   help="comma-separated candidate effects (default: all)")
    p.add_argument("--max-effects", type=int, default=3, help="most effects named at once (default 3)")
    p.add_argument("--alpha", type=float, default=0.05,
                   help="family-wise significance level of the held-out tests (default 0.05)")
    p.add_argument("--no-model-error", action="store_true",
                   help="ignore the model-error model MODEL.json carries (judge the field against the bare model)")
    p.add_argument("--sensitivity", action="store_true",
                   help="also report the verdict under stricter and looser decision thresholds (slower)")
    p.add_argument("--jobs", type=int, default=0,
                   help="worker processes fitting the candidates side by side (default 0: the cores free now; the "
                        "verdict is the same for any number)")
    p.add_argument("--quiet", action="store_true", help="no summary and no progress on the terminal, only the "
                                                      "file names")


def _options(args: argparse.Namespace) -> DiagnoseOptions:
    names = tuple(n.strip() for n in args.effects.split(",") if n.strip())
    bad = [n for n in names if n not in EFFECT_NAMES]
    if bad:
        raise UserError(f"unknown effect(s) {', '.join(bad)} (known: {', '.join(EFFECT_NAMES)})")
    if not names:
        raise UserError("--effects lists no effect")
    if not 1 <= args.max_effects <= len(EFFECT_NAMES):
        raise UserError(f"--max-effects must lie between 1 and {len(EFFECT_NAMES)}")
    if not 0 < args.alpha < 0.5:
        raise UserError("--alpha must lie between 0 and 0.5")
    if args.jobs < 0:
        raise UserError("--jobs must be 0 (the cores free now) or a number of workers")
    return DiagnoseOptions(max_effects=args.max_effects, decision=Decision(alpha=args.alpha), effects=names,
                           use_model_error=not args.no_model_error,
                           alternatives=DECISION_GRID if args.sensitivity else (),
                           workers=args.jobs or free_cores())


def free_cores(window_s: float = 0.2) -> int:
    """Cores idle now, at least 1: a companion computer may be flying the bridge beside the diagnosis.
    Measured from the kernel's CPU counters over ``window_s`` where there are any (Linux), else the core
    count less the one-minute load average (which still counts a job that has just finished)."""
    n = os.cpu_count() or 1
    idle = idle_cores(window_s)
    if idle is None:
        try:
            idle = n - os.getloadavg()[0]
        except OSError:
            idle = float(n)
    return max(1, min(n, int(idle + 0.5)))


def idle_cores(window_s: float, stat: Path = Path("/proc/stat")) -> float | None:
    """Cores' worth of idle time over the next ``window_s`` seconds from ``stat`` (None if unreadable)."""
    def sample() -> tuple[int, int] | None:
        try:
            fields = stat.read_text().split("\n", 1)[0].split()
        except OSError:
            return None
        if len(fields) < 5 or fields[0] != "cpu":
            return None
        ticks = [int(x) for x in fields[1:9]]  # user nice system idle iowait irq softirq steal
        return ticks[3] + ticks[4], sum(ticks)

    a = sample()
    time.sleep(window_s)
    b = sample()
    if a is None or b is None or b[1] <= a[1]:
        return None
    return (b[0] - a[0]) / (b[1] - a[1]) * (os.cpu_count() or 1)


class Progress:
    """Diagnosis progress on stderr: a tqdm bar per stage on a terminal, a line per stage otherwise."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self.bar = None
        self.stage: str | None = None
        self.t0 = time.perf_counter()

    def __call__(self, stage: str, i: int, n: int) -> None:
        if not self.enabled:
            return
        if not sys.stderr.isatty():
            if stage != self.stage:
                self.stage = stage
                print(f"diagnose: {stage} ({time.perf_counter() - self.t0:.0f} s)", file=sys.stderr, flush=True)
            return
        from tqdm import tqdm

        if stage != self.stage:
            self.close()
            self.bar = tqdm(total=max(n, 1), desc=stage, unit="fit", file=sys.stderr, leave=False)
            self.stage = stage
        self.bar.n = min(i, max(n, 1))
        self.bar.refresh()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None


def _json_safe(x):
    """Replace NaN/inf by None so that the report is strict JSON."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {str(k): _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    if hasattr(x, "item"):  # numpy scalar
        return _json_safe(x.item())
    return x


def main(args: argparse.Namespace) -> int:
    opts = _options(args)
    for path in (args.report, args.out_model, args.plot):
        if path and not (Path(path).parent if str(Path(path).parent) else Path(".")).is_dir():
            raise UserError(f"{path}: directory {Path(path).parent} does not exist")
    mf = load_model(args.model)
    data = read_log(args.log, wing=args.wing)
    beyond = travel_note(mf, data.u)
    if beyond:
        data.notes.append(beyond)
    for note in data.notes:
        print(f"note: {note}", file=sys.stderr)
    if "aero_load" in mf.effects.active() and data.airspeed is None:
        print("note: the model has aero_load but the log has no airspeed column: assuming no airflow",
              file=sys.stderr)
    t0 = time.perf_counter()
    progress = Progress(enabled=not args.quiet)
    try:
        d = diagnose(data.t, data.u, data.warp, data.airspeed, mf, opts, progress=progress)
    except ValueError as e:
        raise UserError(f"{args.log}: {e}") from None
    finally:
        progress.close()
    elapsed = time.perf_counter() - t0
    rep = d.report
    rep["log"] = {"file": Path(args.log).name, "wing": args.wing, "samples": len(data), "notes": data.notes,
                  "airspeed": data.airspeed is not None}
    rep["model_file"] = Path(args.model).name if args.model != "paper" else "paper"
    rep["created"] = datetime.now(UTC).isoformat(timespec="seconds")
    rep["seconds"] = elapsed
    if args.out_model:
        d.model.meta["diagnosed_log"] = Path(args.log).name
        save_model(args.out_model, d.model)
        rep["out_model"] = Path(args.out_model).name
    write_text_atomic(args.report, json.dumps(_json_safe(rep), indent=2, allow_nan=False) + "\n")
    if args.plot:
        from warpbridge.bridge.commands.diagnose_plot import plot_diagnosis

        plot_diagnosis(args.plot, d, title=f"{Path(args.log).name} vs {rep['model_file']}")
    if not args.quiet:
        print(f"diagnosed {Path(args.log).name} ({len(data)} samples, {data.t[-1] - data.t[0]:.1f} s) "
              f"against {rep['model_file']} in {elapsed:.1f} s")
        for line in rep["summary"]:
            print(line)
    wrote = [args.report] + [p for p in (args.out_model, args.plot) if p]
    print(f"wrote {', '.join(wrote)}")
    return 0
