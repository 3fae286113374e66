"""Excitation signals for identification and tests, as in the paper.

The paper identified the wing with a random tendon input low-pass filtered at
1 Hz and tested tracking with a 1 Hz-cutoff random warp reference of 4 deg
amplitude; its sine tests ran 0.5-3 Hz at 5-20 deg. Every function takes a time
vector (s) and returns one value per sample; random ones take a seed and are
reproducible.
"""

from __future__ import annotations

import numpy as np
from scipy import signal


def filtered_random(t, cutoff_hz: float = 1.0, amplitude: float = 4.0, offset: float = 0.0,
                    seed: int = 0, order: int = 4) -> np.ndarray:
    """White noise through a zero-phase Butterworth low-pass, scaled so that
    its peak deviation from ``offset`` is ``amplitude``."""
    t = np.asarray(t, dtype=np.float64)
    if t.size < 2:
        return np.full(t.shape, offset)
    fs = 1.0 / float(np.median(np.diff(t)))
    if not 0 < cutoff_hz < fs / 2:
        raise ValueError(f"cutoff {cutoff_hz} Hz must lie below Nyquist ({fs / 2:g} Hz)")
    rng = np.random.default_rng(seed)
    pad = int(fs / cutoff_hz) * 4
    x = rng.standard_normal(t.size + 2 * pad)
    sos = signal.butter(order, cutoff_hz, fs=fs, output="sos")
    y = signal.sosfiltfilt(sos, x)[pad:pad + t.size]
    y -= y.mean()
    peak = np.max(np.abs(y))
    return offset + amplitude * y / peak if peak > 0 else np.full(t.shape, offset)


def sine(t, freq_hz: float = 1.0, amplitude: float = 5.0, offset: float = 0.0, phase: float = -np.pi / 2,
         ) -> np.ndarray:
    """offset + amplitude * sin(2 pi f t + phase); the default phase starts at the trough."""
    return offset + amplitude * np.sin(2 * np.pi * freq_hz * np.asarray(t, dtype=np.float64) + phase)


def sweep(t, f0_hz: float = 0.5, f1_hz: float = 3.0, amplitude: float = 5.0, offset: float = 0.0) -> np.ndarray:
    """Linear chirp from f0 to f1 over the span of t, starting at the trough."""
    t = np.asarray(t, dtype=np.float64)
    span = max(t[-1] - t[0], 1e-9) if t.size else 1.0
    return offset + amplitude * signal.chirp(t - t[0], f0_hz, span, f1_hz, method="linear", phi=-90)


def steps(t, levels=(0.0, 4.0, 8.0, 4.0), hold_s: float = 2.0, offset: float = 0.0) -> np.ndarray:
    """Staircase through ``levels``, each held ``hold_s``, repeating."""
    t = np.asarray(t, dtype=np.float64)
    idx = (np.floor((t - t[0]) / hold_s).astype(int)) % len(levels) if t.size else np.zeros(0, int)
    return offset + np.asarray(levels, dtype=np.float64)[idx]


def doublet(t, amplitude: float = 4.0, width_s: float = 1.0, period_s: float = 6.0, offset: float = 0.0,
            ) -> np.ndarray:
    """+amplitude for width_s, -amplitude for width_s, then rest, repeating every period_s."""
    t = np.asarray(t, dtype=np.float64)
    ph = np.mod(t - t[0], period_s) if t.size else t
    y = np.where(ph < width_s, amplitude, np.where(ph < 2 * width_s, -amplitude, 0.0))
    return offset + y


def multisine_reversals(t, amplitudes=(5.0, 2.0, 0.8), freqs_hz=(0.5, 1.3, 3.1), offset: float = 8.0,
                        ) -> np.ndarray:
    """Sum of sines: a reversal-dense input with nested minor loops (non-local memory)."""
    t = np.asarray(t, dtype=np.float64)
    y = np.full(t.shape, offset)
    for a, f in zip(amplitudes, freqs_hz, strict=True):
        y += a * np.sin(2 * np.pi * f * t)
    return y
