"""SITL results for people: the comparison table in the terminal and a PNG per run.

``comparison_table(rows)`` formats lock-step ``CompareRow`` s (RMS tracking error
per wing and mode, beside the paper's bench figures); ``run_table(results)``
formats one or more runs' RMS per wing; ``plot_run(result, path, other=)`` draws
setpoint vs true warp, the tracking error and the hysteresis loop (tendon
travel vs warp) for each wing, with matplotlib's Agg backend (no display).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from warpbridge.sitl.lockstep import PAPER_BENCH_RMS, CompareRow, RunResult

MODE_LABEL = {"open": "open loop", "pi": "PI only", "ff": "feed-forward", "ff+pi": "feed-forward + PI"}


def _num(v: float | None, width: int = 7) -> str:
    return f"{'-':>{width}}" if v is None or not np.isfinite(v) else f"{v:{width}.3f}"


def comparison_table(rows: Iterable[CompareRow], note: str | None = None) -> str:
    """RMS tracking error (deg) per scenario and mode (mean over seeds, and the range over seeds when
    there are several), with the paper's bench figure where it has one."""
    rows = list(rows)
    many = any(len(r.rms) > 1 for r in rows)
    head = (f"{'scenario':<9} {'window s':<9} {'mode':<26} {'RMS':>7} "
            + (f"{'seeds min-max':>15} " if many else "") + f"{'paper':>7}")
    lines = [head, "-" * len(head)]
    last = None
    for r in rows:
        key = (r.scenario, r.window)
        if last is not None and key != last:
            lines.append("")
        last = key
        lo, hi = r.window
        win = f"{lo:g}-{'end' if not np.isfinite(hi) else f'{hi:g}'}"
        mode = MODE_LABEL.get(r.mode, r.mode) + (f" ({r.label})" if r.label else "")
        spread = f"{f'{r.rms_min:.3f}-{r.rms_max:.3f}':>15} " if many else ""
        lines.append(f"{r.scenario:<9} {win:<9} {mode:<26} {_num(r.rms_mean)} {spread}{_num(r.paper)}")
    lines.append("")
    seeds = max((len(r.rms) for r in rows), default=0)
    lines.append(f"RMS of setpoint - true warp, deg, mean of both wings{f' and {seeds} seeds' if seeds > 1 else ''}. "
                 "Paper (Lee et al. 2017, bench, 1 Hz 4 deg random, Kp = 7, Ki = 1): "
                 + ", ".join(f"{MODE_LABEL[m]} {v:g}" for m, v in PAPER_BENCH_RMS.items()) + ".")
    if note:
        lines.append(note)
    return "\n".join(lines)


def run_table(results: dict[str, RunResult]) -> str:
    """RMS per wing for named runs (e.g. {"real time": ..., "lock-step": ...})."""
    head = f"{'run':<12} {'scenario':<9} {'mode':<18} {'left':>7} {'right':>7} {'cycles':>7}"
    lines = [head, "-" * len(head)]
    for name, r in results.items():
        cycles = r.cycles if r.cycles else r.t.size
        lines.append(f"{name:<12} {r.scenario:<9} {MODE_LABEL.get(r.mode, r.mode):<18} "
                     f"{_num(r.rms.get('left'))} {_num(r.rms.get('right'))} {cycles:>7d}")
    lines.append("RMS of setpoint - true warp (deg) over the control cycles of the same stretch of the scenario.")
    return "\n".join(lines)


def plot_run(result: RunResult, path: str | Path, title: str | None = None, other: RunResult | None = None,
             other_label: str = "lock-step") -> Path:
    """PNG of one run: per wing, setpoint and warp over time, error, and the hysteresis loop.

    The stretch the RMS covers is shaded; ``other`` (e.g. the lock-step run) is drawn thin beside it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    wings = list(result.setpoint)
    fig, axes = plt.subplots(3, len(wings), figsize=(6 * len(wings), 9), squeeze=False)
    for j, w in enumerate(wings):
        t, sp, wt = result.t, result.setpoint[w], result.warp[w]
        ax = axes[0, j]
        ax.plot(t, sp, "--", lw=1, label="setpoint")
        ax.plot(t, wt, lw=1, label="warp (true)")
        if other is not None:
            ax.plot(other.t, other.warp[w], lw=0.6, alpha=0.8, label=f"warp ({other_label})")
        ax.set_title(f"{w} wing: RMS {result.rms.get(w, float('nan')):.3f} deg"
                     + (f" ({other_label} {other.rms.get(w, float('nan')):.3f})" if other is not None else ""))
        ax.set_xlabel("t (s)")
        ax.set_ylabel("warp (deg)")
        ax.legend(loc="upper right", fontsize=8)
        ax = axes[1, j]
        ax.plot(t, sp - wt, lw=0.8, color="C3")
        if other is not None:
            ax.plot(other.t, other.setpoint[w] - other.warp[w], lw=0.5, alpha=0.6, color="C1")
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_xlabel("t (s)")
        ax.set_ylabel("setpoint - warp (deg)")
        lo, hi = result.stretch
        if np.isfinite(lo) and np.isfinite(hi):
            for a in axes[:2, j]:
                a.axvspan(lo, hi, color="0.9", zorder=0)
        ax = axes[2, j]
        ax.plot(result.u[w], wt, lw=0.6, color="C2")
        ax.set_xlabel("tendon travel u (mm)")
        ax.set_ylabel("warp (deg)")
        ax.set_title("hysteresis (tendon -> warp)")
    fig.suptitle(title or f"{result.scenario}, {MODE_LABEL.get(result.mode, result.mode)}")
    fig.tight_layout()
    p = Path(path)
    fig.savefig(p, dpi=90)
    plt.close(fig)
    return p
