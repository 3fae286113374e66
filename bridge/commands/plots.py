"""Figures for identify and predict: measured vs model hysteresis loops and time series (matplotlib, Agg)."""

from __future__ import annotations

import os

import numpy as np


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_identification(path: str | os.PathLike, t: np.ndarray, u: np.ndarray, w: np.ndarray, w_pred: np.ndarray,
                        heldout: np.ndarray, title: str = "") -> None:
    """Loops (u vs warp, measured and model) for the training and held-out parts, and the residual in time."""
    plt = _pyplot()
    fig, axes = plt.subplots(2, 2, figsize=(12, 8), constrained_layout=True)
    for ax, mask, name in ((axes[0, 0], ~heldout, "training"), (axes[0, 1], heldout, "held out")):
        if mask.any():
            ax.plot(u[mask], w[mask], ".", ms=1.5, color="0.6", label="measured")
            ax.plot(u[mask], w_pred[mask], "-", lw=0.8, color="C3", label="model")
            rms = float(np.sqrt(np.mean((w[mask] - w_pred[mask]) ** 2)))
            ax.set_title(f"{name}: RMS {rms:.3f} deg")
        ax.set_xlabel("tendon u (mm)")
        ax.set_ylabel("warp (deg)")
        ax.legend(loc="upper left")
    ax = axes[1, 0]
    ax.plot(t, w, color="0.6", lw=0.6, label="measured")
    ax.plot(t, w_pred, color="C3", lw=0.8, label="model")
    if heldout.any():
        ax.axvspan(t[heldout][0], t[-1], color="C0", alpha=0.08, label="held out")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("warp (deg)")
    ax.legend(loc="upper right")
    ax = axes[1, 1]
    ax.plot(t, w - w_pred, color="C0", lw=0.5)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("residual (deg)")
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)
