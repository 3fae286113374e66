"""Figures and the HTML page of ``warpbridge review`` (matplotlib, Agg; PNGs embedded as base64).

Each ``fig_*`` function draws one figure from the review's arrays and returns it; ``write_html``
renders them into one self-contained page with the tables of the summary.
"""

from __future__ import annotations

import base64
import html
import io
import math
from pathlib import Path

import numpy as np

from warpbridge.bridge.commands.fclog import FcLog
from warpbridge.bridge.commands.logfile import write_text_atomic
from warpbridge.bridge.commands.logjoin import WINGS, Alignment, CycleLog
from warpbridge.bridge.commands.review import MIN_FIT_R2, PHASES, Flight, Review, fmt_number

MAX_POINTS = 20000  # per line: a long flight is thinned for drawing (never for the numbers)
EVENT_COLOURS = {"mode": "tab:blue", "param": "tab:purple", "failsafe": "tab:red", "text": "0.5", "bridge": "tab:green"}
WING_COLOURS = {"left": "tab:blue", "right": "tab:orange"}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _thin(*arrays: np.ndarray) -> list[np.ndarray]:
    n = arrays[0].size
    k = max(1, n // MAX_POINTS)
    return [a[::k] for a in arrays]


def _events(ax, rv: Review, label: bool) -> None:
    shown = 0
    for e in rv.events:
        if e.kind == "text":
            continue
        ax.axvline(e.t, color=EVENT_COLOURS.get(e.kind, "0.5"), lw=0.8, alpha=0.6, ls="--")
        if label and shown < 40:
            ax.annotate(e.text[:28], (e.t, 1.0), xycoords=("data", "axes fraction"), rotation=90, fontsize=6,
                        va="top", ha="right", color=EVENT_COLOURS.get(e.kind, "0.3"))
            shown += 1


def fig_overview(rv: Review, f: Flight):
    """Per wing: the FC's aileron output, setpoint, achieved warp; the errors; airspeed and roll rate."""
    plt = _plt()
    fig, axes = plt.subplots(4, 1, figsize=(12, 10), sharex=True, gridspec_kw={"height_ratios": [3, 3, 2, 2]})
    for ax, w in zip(axes[:2], WINGS, strict=True):
        wt = f.wings[w]
        t, sp, wa = _thin(f.t, wt.setpoint, wt.warp)
        ax.plot(t, sp, color="k", lw=0.9, label="setpoint")
        if wt.measured:
            ax.plot(t, wa, color=WING_COLOURS[w], lw=0.9, label="achieved warp")
        ax.set_ylabel(f"{w} wing warp, deg")
        if np.isfinite(f.aileron).any():
            ax2 = ax.twinx()
            ta, aa = _thin(f.t, f.aileron)
            ax2.plot(ta, aa, color="0.6", lw=0.7, label=f"FC aileron output {f.aileron_channel}")
            ax2.set_ylabel("FC output, us", color="0.4")
            ax2.legend(loc="upper right", fontsize=8)
        ax.legend(loc="upper left", fontsize=8)
        _events(ax, rv, label=(w == "left"))
    ax = axes[2]
    for w in WINGS:
        wt = f.wings[w]
        if wt.measured:
            t, e = _thin(f.t, wt.error)
            ax.plot(t, e, color=WING_COLOURS[w], lw=0.7, label=f"{w}")
    if not any(f.wings[w].measured for w in WINGS):
        ax.text(0.5, 0.5, "no warp sensor: tracking error not measured", transform=ax.transAxes, ha="center")
    ax.axhline(0, color="k", lw=0.5)
    ax.set_ylabel("warp error, deg")
    ax.legend(loc="upper left", fontsize=8)
    _events(ax, rv, label=False)
    ax = axes[3]
    t, a, p = _thin(f.t, f.airspeed, f.roll_rate)
    ax.plot(t, a, color="tab:green", lw=0.9, label="airspeed")
    ax.set_ylabel("airspeed, m/s", color="tab:green")
    ax2 = ax.twinx()
    ax2.plot(t, p, color="tab:red", lw=0.6, label="roll rate")
    ax2.set_ylabel("roll rate, deg/s", color="tab:red")
    ax.set_xlabel("time, s (FC clock)")
    _events(ax, rv, label=False)
    fig.suptitle(f"Flight: {Path(rv.fc_log).name}" + (f" + {Path(rv.cycle_log).name}" if rv.cycle_log else "")
                 + f"  ({rv.source}, {rv.rate_hz:.0f} Hz)")
    fig.tight_layout()
    return fig


def fig_hysteresis(f: Flight):
    """Per wing: tendon command against warp setpoint (the feed-forward's inverse loop) and, with a
    sensor, achieved warp against tendon command (the wing's loop)."""
    plt = _plt()
    measured = any(f.wings[w].measured for w in WINGS)
    fig, axes = plt.subplots(1, 2 if measured else 1, figsize=(11 if measured else 6, 4.5), squeeze=False)
    ax = axes[0, 0]
    for w in WINGS:
        wt = f.wings[w]
        sp, u = _thin(wt.setpoint, wt.u)
        ax.plot(sp, u, color=WING_COLOURS[w], lw=0.6, alpha=0.8, label=w)
    ax.set_xlabel("warp setpoint, deg")
    ax.set_ylabel("tendon command, mm")
    ax.set_title("feed-forward: command against setpoint")
    ax.legend(fontsize=8)
    if measured:
        ax = axes[0, 1]
        for w in WINGS:
            wt = f.wings[w]
            if wt.measured:
                u, wa = _thin(wt.u, wt.warp)
                ax.plot(u, wa, color=WING_COLOURS[w], lw=0.6, alpha=0.8, label=w)
        ax.set_xlabel("tendon command, mm")
        ax.set_ylabel("achieved warp, deg")
        ax.set_title("wing: achieved warp against command")
        ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def fig_tracking(rv: Review):
    """RMS tracking error by airspeed band and by phase, per wing."""
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    for ax, key, title in ((axes[0], "airspeed", "by airspeed band"), (axes[1], "phase", "by phase")):
        labels = [s.label for s in rv.tracking["left"][key]]
        x = np.arange(len(labels))
        for i, w in enumerate(WINGS):
            rms = [s.rms if s.n else 0.0 for s in rv.tracking[w][key]]
            ax.bar(x + (i - 0.5) * 0.38, rms, 0.38, color=WING_COLOURS[w], label=w)
        ax.set_xticks(x, labels, rotation=20, fontsize=8)
        ax.set_ylabel("RMS warp error, deg")
        ax.set_title(f"tracking error {title}")
        ax.legend(fontsize=8)
        if not labels:
            ax.text(0.5, 0.5, "no airborne samples", transform=ax.transAxes, ha="center")
    fig.tight_layout()
    return fig


def fig_roll_authority(rv: Review, f: Flight):
    """Roll rate against differential warp, by airspeed band, with the fitted gain per band."""
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8), gridspec_kw={"width_ratios": [3, 2]})
    ax = axes[0]
    delta, measured = f.differential()
    lag = rv.roll_lag_s
    ok = np.isfinite(f.roll_rate)
    p = np.interp(f.t + lag, f.t[ok], f.roll_rate[ok], left=np.nan, right=np.nan) if ok.sum() > 2 else f.roll_rate
    cmap = plt.get_cmap("viridis")
    n = max(len(rv.roll_authority), 1)
    for i, g in enumerate(rv.roll_authority):
        sel = (f.airspeed >= g.lo_ms) & (f.airspeed < g.hi_ms) & np.isfinite(p) & np.isfinite(delta)
        c = cmap(i / max(n - 1, 1))
        d, pp = _thin(delta[sel], p[sel])
        ax.scatter(d, pp, s=3, color=c, alpha=0.35, label=None if g.reliable else f"{g.band}: no fit (R2 {g.r2:.2f})")
        if math.isfinite(g.gain) and g.reliable:
            xs = np.linspace(np.nanmin(delta[sel]), np.nanmax(delta[sel]), 2)
            ax.plot(xs, g.gain * xs + g.bias, color=c, lw=2, label=f"{g.band}: {g.gain:.2f} deg/s/deg")
    ax.axhline(0, color="k", lw=0.4)
    ax.axvline(0, color="k", lw=0.4)
    ax.set_xlabel(("measured" if measured else "commanded") + " differential warp (left - right), deg")
    ax.set_ylabel(f"roll rate {lag * 1e3:.0f} ms later, deg/s")
    ax.set_title("roll authority by airspeed band")
    if rv.roll_authority:
        ax.legend(fontsize=8)
    ax = axes[1]
    good = [g for g in rv.roll_authority if g.reliable]
    v = [0.5 * (g.lo_ms + g.hi_ms) for g in good]
    ax.plot(v, [g.gain for g in good], "o-", color="tab:red", label="gain, deg/s per deg")
    if not good:
        ax.text(0.5, 0.5, f"no band fits with R2 >= {MIN_FIT_R2}", transform=ax.transAxes, ha="center")
    ax.set_xlabel("airspeed, m/s")
    ax.set_ylabel("roll-rate gain, deg/s per deg", color="tab:red")
    ax2 = ax.twinx()
    if rv.autopilot == "px4":  # no single feed-forward parameter to imply (docs/review.md, FW_RR_FF)
        ax2.plot(v, [g.output_gain for g in good], "s--", color="tab:blue", label="deg/s per full output")
        ax2.set_ylim(0, 1.3 * max([g.output_gain for g in good if math.isfinite(g.output_gain)] + [0.0]) or 1.0)
        ax2.set_ylabel("roll rate per full output, deg/s", color="tab:blue")
        ax2.legend(loc="lower right", fontsize=8)
        ax.set_title(f"gain per band (bands with R2 >= {MIN_FIT_R2})")
        fig.tight_layout()
        return fig
    ax2.plot(v, [g.ff_ardupilot for g in good], "s--", color="tab:blue", label="RLL_RATE_FF implied")
    top = max([g.ff_ardupilot for g in good if math.isfinite(g.ff_ardupilot)]
              + [rv.fc_roll_ff if math.isfinite(rv.fc_roll_ff) else 0.0, 0.0])
    if math.isfinite(rv.fc_roll_ff):
        ax2.axhline(rv.fc_roll_ff, color="tab:blue", lw=0.8, ls=":", label=f"in the log: {rv.fc_roll_ff:.3f}")
    ax2.set_ylim(0, 1.3 * top if top > 0 else 1.0)
    ax2.set_ylabel("RLL_RATE_FF", color="tab:blue")
    ax2.legend(loc="lower right", fontsize=8)
    ax.set_title(f"gain per band (bands with R2 >= {MIN_FIT_R2})")
    fig.tight_layout()
    return fig


def fig_link(rv: Review, f: Flight):
    """The link: age of the servo output at use over the flight, and named values received vs expected."""
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(12, 3.8), gridspec_kw={"width_ratios": [3, 2]})
    ax = axes[0]
    ok = np.isfinite(f.latency_ms)
    if ok.sum() > 2:  # per second: the median age and the oldest
        sec = np.floor(f.t[ok]).astype(np.int64)
        edges = np.flatnonzero(np.r_[True, np.diff(sec) > 0, True])
        mids = [f.t[ok][a:b].mean() for a, b in zip(edges[:-1], edges[1:], strict=False)]
        med = [np.median(f.latency_ms[ok][a:b]) for a, b in zip(edges[:-1], edges[1:], strict=False)]
        top = [np.max(f.latency_ms[ok][a:b]) for a, b in zip(edges[:-1], edges[1:], strict=False)]
        ax.fill_between(mids, med, top, color="tab:purple", alpha=0.25, label="oldest in the second")
        ax.plot(mids, med, color="tab:purple", lw=1.2, label="median per second")
        ax.legend(fontsize=8)
    ax.set_xlabel("time, s (FC clock)")
    ax.set_ylabel("servo output age at use, ms")
    ax.set_title(f"latency ({rv.link.latency_source})", fontsize=9)
    ax = axes[1]
    names = list(rv.link.named_received)
    if names:
        x = np.arange(len(names))
        ax.bar(x, [rv.link.named_expected[k] for k in names], color="0.8", label="expected")
        ax.bar(x, [rv.link.named_received[k] for k in names], color="tab:green", width=0.5, label="received")
        ax.set_xticks(x, names, rotation=60, fontsize=7)
        ax.legend(fontsize=8)
    else:
        ax.text(0.5, 0.5, "no named values in the FC log", transform=ax.transAxes, ha="center")
    ax.set_title("named values in the FC log", fontsize=9)
    fig.tight_layout()
    return fig


def fig_join(al: Alignment, f: Flight, fc: FcLog, cl: CycleLog):
    """The join: the FC's aileron output and the bridge's differential setpoint on the FC's clock."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(12, 3.5))
    ch = f.aileron_channel
    s_ail = fc.output(ch) if ch is not None else None
    diff = f.wings["left"].setpoint - f.wings["right"].setpoint
    # the busiest 10 s of the flight: where the aileron moves most
    mid = f.t[np.nanargmax(np.abs(np.gradient(np.nan_to_num(diff))))] if f.t.size else 0.0
    sel = (f.t > mid - 5) & (f.t < mid + 5)
    ax.plot(f.t[sel], diff[sel], color="tab:blue", lw=1.0, label="bridge: left - right setpoint (cycle log)")
    ax.set_ylabel("differential setpoint, deg", color="tab:blue")
    ax.set_xlabel("time, s (FC clock)")
    if s_ail is not None:
        k = (s_ail.t > mid - 5) & (s_ail.t < mid + 5)
        ax2 = ax.twinx()
        ax2.plot(s_ail.t[k], s_ail.v[k], ".--", color="tab:orange", ms=3, lw=0.8, label=f"FC output {ch} (FC log)")
        ax2.set_ylabel("FC output, us")
        ax2.legend(loc="upper right", fontsize=8)
    ax.legend(loc="upper left", fontsize=8)
    if al.unchecked:
        ax.set_title(f"join ({al.method}): alignment not checked: {al.unchecked}", fontsize=10)
    else:
        ax.set_title(f"join ({al.method}): check lag {fmt_number(al.check_lag_s * 1e3, 1)} ms, expected "
                     f"{fmt_number(al.expected_lag_s * 1e3, 1)} ms, residual {fmt_number(al.residual_s * 1e3, 1)} ms",
                     fontsize=10)
    fig.tight_layout()
    return fig


def png(fig) -> str:
    """The figure as a base64 PNG (the figure is closed)."""
    plt = _plt()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _table(head: list[str], rows: list[list[str]]) -> str:
    h = "".join(f"<th>{html.escape(c)}</th>" for c in head)
    b = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{h}</tr>{b}</table>"


CSS = """body{font-family:sans-serif;max-width:1150px;margin:auto;padding:1em;color:#222}
table{border-collapse:collapse;margin:0.5em 0 1em}td,th{border:1px solid #ccc;padding:2px 8px;font-size:13px;
text-align:right}th{background:#eee}td:first-child{text-align:left}img{max-width:100%}
.warn{background:#fff3cd;border:1px solid #e0c060;padding:0.4em 0.8em;margin:0.3em 0}
h2{border-bottom:1px solid #ccc;margin-top:1.5em}"""


def write_html(out: Path, rv: Review, f: Flight, fc: FcLog, cl: CycleLog | None, al: Alignment | None) -> None:
    """The report: one HTML file with every figure inside."""
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>warpbridge review: "
             f"{html.escape(Path(rv.fc_log).name)}</title><style>{CSS}</style></head><body>",
             f"<h1>Flight review: {html.escape(Path(rv.fc_log).name)}</h1>",
             _table(["", ""], [["FC log", f"{rv.fc_log} ({rv.fc_format}, {rv.autopilot})"],
                               ["cycle log", rv.cycle_log or "none: the FC's logged named values stand in"],
                               ["bridge data", f"{rv.source}, {rv.rate_hz:.1f} Hz"],
                               ["duration", f"{rv.duration_s:.1f} s"],
                               ["aileron output", str(f.aileron_channel or "not found")]])]
    parts += [f"<div class='warn'>{html.escape(w)}</div>" for w in rv.warnings]
    if al is not None and cl is not None:
        parts.append("<h2>Join</h2>")
        parts.append(_table(["method", "offset, s", "drift, ppm", "check lag, ms", "expected, ms", "residual, ms",
                             "|r|", "overlap, s", "telemetry lag, ms"],
                            [[al.method, f"{al.offset_s:.4f}", f"{al.drift * 1e6:.1f}",
                              fmt_number(al.check_lag_s * 1e3, 1),
                              fmt_number(al.expected_lag_s * 1e3, 1), fmt_number(al.residual_s * 1e3, 1),
                              fmt_number(al.check_corr), f"{al.overlap_s:.1f}",
                              fmt_number(al.telemetry_lag_s * 1e3, 0)]]))
        parts.append(f"<img src='data:image/png;base64,{png(fig_join(al, f, fc, cl))}'>")
    parts.append("<h2>Per wing over the flight</h2>")
    parts.append(f"<img src='data:image/png;base64,{png(fig_overview(rv, f))}'>")
    parts.append("<h2>Tracking error</h2>")
    for w in WINGS:
        rows = [[s.label, s.n, fmt_number(s.rms), fmt_number(s.mean), fmt_number(s.p95)]
                for key in ("all", "airspeed", "phase") for s in rv.tracking[w][key]]
        parts.append(f"<h3>{w} wing</h3>" + _table(["where", "samples", "RMS, deg", "mean, deg", "95% |e|, deg"], rows))
    parts.append(f"<img src='data:image/png;base64,{png(fig_tracking(rv))}'>")
    parts.append("<p>Phases of the setpoint: " + ", ".join(PHASES) + " (after reversal: the first 0.5 s after "
                 "the setpoint turns).</p>")
    parts.append("<h2>Hysteresis loops</h2>")
    parts.append(f"<img src='data:image/png;base64,{png(fig_hysteresis(f))}'>")
    parts.append("<h2>Roll authority</h2>")
    px4 = rv.autopilot == "px4"
    parts.append(_table(["airspeed band", "samples", "gain, deg/s per deg", "bias, deg/s", "R2",
                         "deg/s per full output", "output R2", *([] if px4 else ["RLL_RATE_FF implied"]),
                         "no FF because"],
                        [[g.band, g.n, fmt_number(g.gain), fmt_number(g.bias, 2), fmt_number(g.r2, 2),
                          fmt_number(g.output_gain, 1), fmt_number(g.output_r2, 2),
                          *([] if px4 else [fmt_number(g.ff_ardupilot)]), g.no_ff or "-"]
                         for g in rv.roll_authority]))
    lead = (f"<p>Roll rate {rv.roll_lag_s * 1e3:.0f} ms after the "
            f"{'measured' if rv.roll_uses_measured_warp else 'commanded'} differential warp (the lag where they "
            "match best). ")
    if px4:
        parts.append(lead + "PX4's FW_RR_FF acts through its control allocation: docs/review.md says how to set it "
                     "from the roll rate per full output.</p>")
    else:
        parts.append(lead + "The implied RLL_RATE_FF is the feed-forward that alone would give the fitted rate at "
                     "the band's airspeed (output = rate x FF x SCALING_SPEED / airspeed, full output 45).</p>")
    parts.append(f"<img src='data:image/png;base64,{png(fig_roll_authority(rv, f))}'>")
    parts.append("<h2>Link</h2>")
    ls = rv.link
    parts.append(_table(["latency median, ms", "95%, ms", "max, ms", "servo messages", "lost"],
                        [[fmt_number(ls.latency_median_ms, 1), fmt_number(ls.latency_p95_ms, 1),
                          fmt_number(ls.latency_max_ms, 1), ls.servo_messages or "-", ls.servo_lost]]))
    if ls.tlog_loss:
        parts.append(_table(["source (sys/comp)", "received", "lost (sequence gaps)"],
                            [[k, v[0], v[1]] for k, v in sorted(ls.tlog_loss.items())]))
    parts.append(f"<img src='data:image/png;base64,{png(fig_link(rv, f))}'>")
    parts.append("<h2>Events</h2>")
    parts.append(_table(["t, s", "kind", "what"], [[f"{e.t:.2f}", e.kind, e.text] for e in rv.events[:500]]))
    if rv.notes:
        parts.append("<h2>Notes</h2><ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in rv.notes) + "</ul>")
    parts.append("</body></html>")
    write_text_atomic(out, "\n".join(parts))
