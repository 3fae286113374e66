"""Figures for identify and predict: the model against the log as time series, hysteresis loops and
residual (matplotlib, Agg). A figure is written whole or not at all."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import numpy as np

from warpbridge.model.effects import PULLED, Effects, apply_input_effects

COMMAND_LABEL = "tendon u (mm)"
INPUT_STAGES = (("delay", "delay"), ("servo_lag", "servo"), ("rate_limit", "rate limit"), ("backlash", "backlash"))


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan")


def _save(fig, path: str | os.PathLike) -> None:
    """Save through a temporary file beside the target, then rename: never a half-written figure."""
    p = Path(path)
    tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp{p.suffix}")
    try:
        fig.savefig(tmp, dpi=110)
        os.replace(tmp, p)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def loop_axis(effects: Effects, t: np.ndarray, u: np.ndarray, sent: np.ndarray | None = None,
              slack_side: float = PULLED) -> tuple[np.ndarray, str]:
    """The loops' x axis and its label: the tendon travel the model is fed (the command through its delay,
    servo, rate limit and play), or the command itself when the model has none of these. A closed loop's
    command jumps at every setpoint step and its PI's jitter; plotted against it the loop is a scribble, through
    the servo it is the loop the wing went round."""
    x = apply_input_effects(effects, t, u, slack_side, sent)
    if np.array_equal(x, np.asarray(u, dtype=np.float64)):
        return x, COMMAND_LABEL
    active = effects.active()
    names = [text for name, text in INPUT_STAGES if name in active]
    if effects.capstan_pull_ratio > 0 or effects.capstan_release_ratio > 0:
        names.append("capstan stall")
    return x, f"tendon travel into the model (mm): u through its {', '.join(names) or 'input effects'}"


def _loop(ax, u: np.ndarray, w: np.ndarray, w_pred: np.ndarray, title: str, xlabel: str) -> None:
    ax.plot(u, w, ".", ms=1.5, color="0.55", label="logged warp")
    ax.plot(u, w_pred, "-", lw=0.8, color="C3", label=f"model (RMS {_rms(w - w_pred):.3f} deg)")
    ax.set_title(title)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("warp (deg)")
    ax.legend(loc="upper left", fontsize="small")


def plot_identification(path: str | os.PathLike, t: np.ndarray, u: np.ndarray, w: np.ndarray, w_pred: np.ndarray,
                        heldout: np.ndarray, title: str = "", xlabel: str = COMMAND_LABEL) -> None:
    """Loops (u vs warp, logged and model; ``u`` the loops' axis, ``loop_axis``) for the training and held-out
    parts, the warp in time with the held-out part shaded, and the residual."""
    plt = _pyplot()
    heldout = np.asarray(heldout, bool)
    parts = [(m, name) for m, name in ((~heldout, "training part"), (heldout, "held-out part")) if m.any()]
    fig = plt.figure(figsize=(12, 8), layout="constrained")
    grid = fig.add_gridspec(2, len(parts))
    for k, (mask, name) in enumerate(parts):
        _loop(fig.add_subplot(grid[0, k]), u[mask], w[mask], w_pred[mask], f"{name}: u -> warp", xlabel)
    bottom = grid[1, :].subgridspec(2, 1, height_ratios=(2, 1))
    ax = fig.add_subplot(bottom[0])
    ax.plot(t, w, color="0.55", lw=0.6, label="logged warp")
    ax.plot(t, w_pred, color="C3", lw=0.8, label="model")
    if heldout.any():
        ax.axvspan(t[heldout][0], t[-1], color="C0", alpha=0.08, label="held out (never fitted)")
    ax.set_ylabel("warp (deg)")
    ax.legend(loc="upper right", fontsize="small")
    ax2 = fig.add_subplot(bottom[1], sharex=ax)
    ax2.plot(t, w - w_pred, color="C0", lw=0.5)
    ax2.axhline(0, color="k", lw=0.5)
    ax2.set_xlabel("t (s)")
    ax2.set_ylabel("residual (deg)")
    if title:
        fig.suptitle(title)
    _save(fig, path)
    plt.close(fig)


def plot_prediction(path: str | os.PathLike, t: np.ndarray, u: np.ndarray, w: np.ndarray, w_pred: np.ndarray,
                    title: str = "", xlabel: str = COMMAND_LABEL) -> None:
    """The prediction against the logged warp: time series, loop (u vs warp; ``u`` the loop's axis,
    ``loop_axis``) and residual, with the RMS."""
    plt = _pyplot()
    rms = _rms(w - w_pred)
    fig = plt.figure(figsize=(12, 8), layout="constrained")
    grid = fig.add_gridspec(2, 2, width_ratios=(2, 1))
    ax = fig.add_subplot(grid[0, 0])
    ax.plot(t, w, color="0.55", lw=0.6, label="logged warp")
    ax.plot(t, w_pred, color="C3", lw=0.8, label="predicted")
    ax.set_ylabel("warp (deg)")
    ax.set_title("warp in time")
    ax.legend(loc="upper right", fontsize="small")
    ax2 = fig.add_subplot(grid[1, 0], sharex=ax)
    ax2.plot(t, w - w_pred, color="C0", lw=0.5, label=f"logged - predicted (RMS {rms:.3f} deg)")
    ax2.axhline(0, color="k", lw=0.5)
    ax2.set_xlabel("t (s)")
    ax2.set_ylabel("residual (deg)")
    ax2.legend(loc="upper right", fontsize="small")
    _loop(fig.add_subplot(grid[:, 1]), u, w, w_pred, "loop: u -> warp", xlabel)
    fig.suptitle(f"{title}: RMS {rms:.3f} deg over {t.size} samples" if title else
                 f"prediction: RMS {rms:.3f} deg over {t.size} samples")
    _save(fig, path)
    plt.close(fig)
