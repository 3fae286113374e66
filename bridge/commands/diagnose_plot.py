"""Figure for ``warpbridge diagnose``: residual by phase and band, loops and time series before/after (Agg)."""

from __future__ import annotations

import os

import numpy as np

from warpbridge.bridge.commands.plots import loop_axis
from warpbridge.model.diagnosis import Diagnosis
from warpbridge.model.effect_registry import RIG_EFFECTS


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _bars(ax, rows: list[dict], key_before: str, key_after: str, title: str, ylabel: str, floor: float | None,
          log: bool = False) -> None:
    if not rows:
        ax.set_visible(False)
        return
    x = np.arange(len(rows))
    ax.bar(x - 0.2, [r[key_before] for r in rows], 0.4, color="C3", label="nominal")
    if key_after in rows[0]:
        ax.bar(x + 0.2, [r[key_after] for r in rows], 0.4, color="C2", label="augmented")
    if floor is not None:
        ax.axhline(floor, color="0.3", ls="--", lw=0.8, label="noise floor")
    ax.set_xticks(x)
    ax.set_xticklabels([r["cell"].replace("after reversal to ", "after rev. ") for r in rows], rotation=20,
                       ha="right", fontsize=8)
    if log:
        ax.set_yscale("log")
    ax.set_title(title)
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=8)


def plot_diagnosis(path: str | os.PathLike, d: Diagnosis, title: str = "") -> None:
    """Six panels: held-out residual by phase and band, residual in time, loops, a time-series window."""
    plt = _pyplot()
    rep = d.report
    where = rep["shrinkage"]["where"]
    fig, axes = plt.subplots(2, 3, figsize=(16, 9), constrained_layout=True)
    _bars(axes[0, 0], where.get("phase", {}).get("cells", []), "rms_deg", "rms_after_deg",
          "held-out residual by phase", "RMS (deg)", rep["noise_deg"])
    bands = where.get("band", {}).get("cells", [])
    if bands:
        for b in bands:
            b.setdefault("noise_power", 0.0)
        _bars(axes[0, 1], bands, "power", "power_after", "held-out residual power by band", "power (deg^2)", None,
              log=True)
        axes[0, 1].plot(np.arange(len(bands)), [max(b["noise_power"], 1e-12) for b in bands], "k_", ms=20,
                        label="noise")
    else:
        axes[0, 1].set_visible(False)
    t, w = d.t, d.w
    r0, r1 = w - d.w_nominal, w - d.w_augmented
    ax = axes[0, 2]
    k = max(1, int(round(0.25 * (t.size - 1) / max(t[-1] - t[0], 1e-9))))  # 0.25 s moving RMS
    kern = np.ones(k) / k
    ax.plot(t, np.sqrt(np.convolve(r0 ** 2, kern, "same")), color="C3", lw=0.8, label="nominal")
    ax.plot(t, np.sqrt(np.convolve(r1 ** 2, kern, "same")), color="C2", lw=0.8, label="augmented")
    for a, b, kind in d.split.blocks:
        if kind == "score":
            ax.axvspan(t[a], t[b - 1], color="C0", alpha=0.08)
    left = rep.get("left_over")
    if left and left["mostly"]:  # the scored block that holds most of what the verdict leaves
        ax.axvspan(*left["block_s"], color="C1", alpha=0.2, label="most of what is left")
    ax.axhline(rep["noise_deg"], color="0.3", ls="--", lw=0.8)
    ax.set_title("residual RMS over 0.25 s (shaded: scored blocks)")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("deg")
    ax.legend(fontsize=8)
    ax = axes[1, 0]
    sc = d.split.score
    # against the travel through the rig's servo, which both models share (the field's effects are the models'
    # difference): a closed loop's command jumps, the travel through the servo is the loop the wing went round
    x, xlabel = loop_axis(d.model.effects.only(RIG_EFFECTS), t, d.u)
    ax.plot(x[sc], w[sc], ".", ms=1.0, color="0.6", label="measured")
    ax.plot(x[sc], d.w_nominal[sc], ".", ms=0.8, color="C3", label="nominal")
    ax.plot(x[sc], d.w_augmented[sc], ".", ms=0.8, color="C2", label="augmented")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("warp (deg)")
    ax.set_title("loops on the scored blocks")
    ax.legend(fontsize=8, markerscale=8)
    ax = axes[1, 1]
    a, b, _ = next(((a, b, kind) for a, b, kind in d.split.blocks if kind == "score"), (0, t.size, ""))
    window = "a scored window"
    if left and left["mostly"]:
        a, b = int(np.searchsorted(t, left["block_s"][0])), int(np.searchsorted(t, left["block_s"][1])) + 1
        window = "the scored block holding most of what is left"
    span = min(b, a + int(5.0 * (t.size - 1) / max(t[-1] - t[0], 1e-9)))
    if left and left["mostly"] and span < b:  # the 5 s window centred on the block's largest residual
        width = span - a
        a = int(np.clip(a + int(np.argmax(np.abs(r1[a:b]))) - width // 2, a, b - width))
        span = a + width
    sl = slice(a, span)
    ax.plot(t[sl], w[sl], color="0.6", lw=0.8, label="measured")
    ax.plot(t[sl], d.w_nominal[sl], color="C3", lw=0.9, label="nominal")
    ax.plot(t[sl], d.w_augmented[sl], color="C2", lw=0.9, label="augmented")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("warp (deg)")
    ax.set_title(window)
    ax.legend(fontsize=8)
    ax = axes[1, 2]
    ax.plot(t, r0, color="C3", lw=0.5, label="nominal")
    ax.plot(t, r1, color="C2", lw=0.5, label="augmented")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("residual (deg)")
    sh = rep["shrinkage"]
    gc = sh["gap_closed"]
    ax.set_title(f"held-out RMS {sh['heldout_rms_before_deg']:.3f} -> {sh['heldout_rms_after_deg']:.3f} deg"
                 + (f", gap closed {gc:.0%}" if gc is not None else ""))
    ax.legend(fontsize=8)
    verdict = ", ".join(rep["verdict"]) or ("none: the residual is noise" if rep.get("residual_is_noise") else
                                             "none named (the report says why)")
    fig.suptitle(f"{title}\nverdict: {verdict}" if title else f"verdict: {verdict}")
    fig.savefig(path, dpi=110)
    plt.close(fig)
