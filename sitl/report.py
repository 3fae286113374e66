"""SITL results for people: the comparison table in the terminal and a PNG per run.

``comparison_table(rows)`` formats lock-step ``CompareRow`` s (RMS tracking error
per wing and mode, beside the paper's bench figures); ``run_table(results)``
formats one or more runs' RMS per wing; ``plot_run(result, path, other=)`` draws
setpoint vs true warp, the tracking error and the hysteresis loop (tendon
travel vs warp) for each wing, with matplotlib's Agg backend (no display); long
runs are decimated, with a zoom on their worst stretch.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from warpbridge.sitl.lockstep import PAPER_BENCH_RMS, CompareRow, RunResult

MODE_LABEL = {"open": "open loop", "pi": "PI only", "ff": "feed-forward", "ff+pi": "feed-forward + PI"}


def _num(v: float | None, width: int = 7) -> str:
    return f"{'-':>{width}}" if v is None or not np.isfinite(v) else f"{v:{width}.3f}"


def comparison_table(rows: Iterable[CompareRow]) -> str:
    """RMS tracking error (deg) per scenario and mode, with the paper's bench figure where it has one."""
    head = f"{'scenario':<9} {'mode':<18} {'left':>7} {'right':>7} {'mean':>7} {'paper':>7}"
    lines = [head, "-" * len(head)]
    last = None
    for r in rows:
        if last is not None and r.scenario != last:
            lines.append("")
        last = r.scenario
        lines.append(f"{r.scenario:<9} {MODE_LABEL.get(r.mode, r.mode):<18} {_num(r.rms_left)} "
                     f"{_num(r.rms_right)} {_num(r.rms_mean)} {_num(r.paper)}")
    lines.append("")
    lines.append("RMS of setpoint - true warp, deg. Paper (Lee et al. 2017, bench, 1 Hz 4 deg random, Kp = 7, "
                 "Ki = 1): " + ", ".join(f"{MODE_LABEL[m]} {v:g}" for m, v in PAPER_BENCH_RMS.items()) + ".")
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


LONG_RUN_S = 30.0  # longer runs get a zoomed window beside the whole run
ZOOM_S = 10.0
MAX_POINTS = 4000  # per line over the whole run (decimated beyond)


def _stride(n: int) -> int:
    return max(1, int(np.ceil(n / MAX_POINTS)))


def binned_rms(t: np.ndarray, e: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
    """RMS of ``e`` in consecutive bins of ``width`` s (bin centres, values; bins with fewer than half
    the usual samples dropped)."""
    ok = np.isfinite(t) & np.isfinite(e)
    t, e = t[ok], e[ok]
    if t.size == 0:
        return np.zeros(0), np.zeros(0)
    k = np.floor((t - t[0]) / width).astype(np.int64)
    n = np.bincount(k)
    s = np.bincount(k, weights=e * e)
    keep = n >= max(1.0, 0.5 * float(np.median(n[n > 0])))  # a sliver of a bin at the end says nothing
    centres = t[0] + (np.arange(n.size) + 0.5) * width
    return centres[keep], np.sqrt(s[keep] / n[keep])


def worst_window(t: np.ndarray, e: np.ndarray, lo: float, hi: float, width: float) -> tuple[float, float]:
    """The ``width``-second window inside [lo, hi] with the largest RMS of ``e`` (1 s steps)."""
    if not (np.isfinite(lo) and np.isfinite(hi)) or hi - lo <= width:
        return (lo, hi) if np.isfinite(lo) and np.isfinite(hi) else (float(t[0]), float(t[-1]))
    best, best_v = lo, -1.0
    e2 = np.where(np.isfinite(e), e * e, 0.0)
    c = np.concatenate([[0.0], np.cumsum(e2)])
    for a in np.arange(lo, hi - width + 1e-9, 1.0):
        i, j = np.searchsorted(t, a), np.searchsorted(t, a + width)
        if j > i and (v := (c[j] - c[i]) / (j - i)) > best_v:
            best, best_v = float(a), v
    return best, best + width


def plot_run(result: RunResult, path: str | Path, title: str | None = None, other: RunResult | None = None,
             other_label: str = "lock-step") -> Path:
    """PNG of one run: per wing, setpoint and true warp over time, the tracking error, the hysteresis loop.

    The grey band is the stretch the RMS covers (after the start-up settling). ``other`` (e.g. the
    lock-step replay) is drawn beside the run. Runs longer than ``LONG_RUN_S`` get a row zoomed on the
    ``ZOOM_S`` seconds with the largest error, the whole run decimated above it, and the error as RMS
    per second; the hysteresis loop then shows the zoomed window."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    wings = list(result.setpoint)
    t = result.t
    long_run = t.size > 1 and float(t[-1] - t[0]) > LONG_RUN_S
    rows = 4 if long_run else 3
    fig, axes = plt.subplots(rows, len(wings), figsize=(6.5 * len(wings), 3.1 * rows + 1.0), squeeze=False)
    lo, hi = result.stretch
    shaded = np.isfinite(lo) and np.isfinite(hi)
    band = Patch(color="0.93", label="RMS stretch (after settling)")
    sp_style = dict(color="0.35", lw=3.0, alpha=0.45, solid_capstyle="butt", label="setpoint")
    rt_style = dict(color="tab:red", lw=0.9, label="real time: true warp, its error")
    ot_style = dict(color="tab:blue", lw=0.7, ls=(0, (3, 2)), label=f"{other_label}: true warp, its error")
    zoom_patch = Patch(color="gold", alpha=0.35, label=f"window zoomed below ({ZOOM_S:g} s)")
    for j, w in enumerate(wings):
        sp, wt = result.setpoint[w], result.warp[w]
        err = sp - wt
        k = _stride(t.size)
        ax = axes[0, j]
        ax.plot(t[::k], sp[::k], **sp_style)
        ax.plot(t[::k], wt[::k], **rt_style)
        if other is not None:
            ko = _stride(other.t.size)
            ax.plot(other.t[::ko], other.warp[w][::ko], **ot_style)
        rms = f"RMS {result.rms.get(w, float('nan')):.3f} deg"
        if other is not None:
            rms += f" ({other_label} {other.rms.get(w, float('nan')):.3f})"
        ax.set_title(f"{w} wing: {rms}" + (" - whole run" if long_run else ""))
        ax.set_ylabel("warp (deg)")
        zoom = worst_window(t, err, lo, hi, ZOOM_S) if long_run else None
        if zoom is not None:
            ax.axvspan(*zoom, color=zoom_patch.get_facecolor(), zorder=0)
            ax = axes[1, j]
            m = (t >= zoom[0]) & (t <= zoom[1])
            ax.plot(t[m], sp[m], **sp_style)
            ax.plot(t[m], wt[m], **rt_style)
            if other is not None:
                mo = (other.t >= zoom[0]) & (other.t <= zoom[1])
                ax.plot(other.t[mo], other.warp[w][mo], **ot_style)
            ax.set_title(f"{zoom[0]:.0f}..{zoom[1]:.0f} s: the {ZOOM_S:g} s with the largest error")
            ax.set_ylabel("warp (deg)")
        ax = axes[rows - 2, j]
        if long_run:
            for res, style in ((other, ot_style), (result, rt_style)):
                if res is None:
                    continue
                bt, br = binned_rms(res.t, res.setpoint[w] - res.warp[w], 1.0)
                ax.plot(bt, br, color=style["color"], lw=1.0, ls=style.get("ls", "-"))
            ax.set_ylabel("RMS per 1 s of\nsetpoint - true warp (deg)")
        else:
            if other is not None:
                ax.plot(other.t, other.setpoint[w] - other.warp[w], color=ot_style["color"], lw=0.6,
                        ls=ot_style["ls"])
            ax.plot(t, err, color=rt_style["color"], lw=0.8)
            ax.axhline(0.0, color="k", lw=0.5)
            ax.set_ylabel("setpoint - true warp (deg)")
        for r in range(rows - 1):
            a = axes[r, j]
            if shaded:
                a.axvspan(lo, hi, color=band.get_facecolor(), zorder=-1)
            a.set_xlabel("t (s)")
        if zoom is not None:
            axes[1, j].set_xlim(*zoom)
        ax = axes[rows - 1, j]
        m = ((t >= zoom[0]) & (t <= zoom[1])) if zoom is not None else np.ones(t.size, dtype=bool)
        ax.plot(result.u[w][m], wt[m], lw=0.6, color="tab:green")
        ax.set_xlabel("tendon travel u (mm)")
        ax.set_ylabel("true warp (deg)")
        ax.set_title("hysteresis (tendon -> warp)" + (f", {zoom[0]:.0f}..{zoom[1]:.0f} s" if zoom else ""))
    fig.suptitle((title or f"{result.scenario}, {MODE_LABEL.get(result.mode, result.mode)}")
                 + "\ntrue warp: the simulated wing's warp at each sensor read of the bridge", fontsize=11)
    handles = [Line2D([], [], **sp_style), Line2D([], [], **rt_style)]
    handles += [Line2D([], [], **ot_style)] if other is not None else []
    handles += ([band] if shaded else []) + ([zoom_patch] if long_run else [])
    fig.legend(handles=handles, loc="upper center", ncol=len(handles), fontsize=8, frameon=False,
               bbox_to_anchor=(0.5, 1.0 - 0.75 / fig.get_figheight()))
    fig.tight_layout(rect=(0, 0, 1, 1.0 - 0.85 / fig.get_figheight()))
    p = Path(path)
    fig.savefig(p, dpi=90)
    plt.close(fig)
    return p
