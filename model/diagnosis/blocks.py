"""The block split of a log for the diagnosis: alternating training and scored blocks after the warm-up,
the scored ones cut into chunks for the paired tests."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from warpbridge.model.diagnosis.stats import chunk_ids
from warpbridge.model.signals import warmup_end


@dataclass
class Split:
    """Blocked split after the warm-up: ``train`` and ``score`` masks, ``chunks`` labels the scored
    samples for paired tests (-1 elsewhere)."""

    train: np.ndarray
    score: np.ndarray
    chunks: np.ndarray
    start: int
    blocks: list[tuple[int, int, str]]
    pattern: tuple[int, ...] = ()  # the scored blocks, numbered from 0 (empty blocks included)


SCORE_PATTERN = (1, 4, 6, 9)  # of 10 blocks: 40 % scored, spread over the log, the last block scored
# scored chunks the paired tests aim for (each between 5 samples and 1 s): more chunks, more degrees of freedom
# for the tests but the more correlated neighbours are (the tests use an autocorrelation-robust variance)
SCORE_CHUNKS = 96
SPEED_WINDOW_S = 0.05  # input speed is measured over this span (robust to a stepped, quantised command)


def input_speed(t: np.ndarray, u: np.ndarray, fs: float) -> np.ndarray:
    """|u(t + h) - u(t)| / h per sample (mm/s), h about ``SPEED_WINDOW_S`` (``fs`` samples per second); 0 on
    the last samples."""
    n = t.size
    k = max(1, int(round(SPEED_WINDOW_S * fs)))
    speed = np.zeros(n)
    if n > k:
        speed[:-k] = np.abs(u[k:] - u[:-k]) / np.maximum(t[k:] - t[:-k], 1e-12)
    return speed


def block_speeds(t: np.ndarray, u: np.ndarray, fs: float, pos: np.ndarray, n_blocks: int,
                 after: np.ndarray) -> np.ndarray:
    """Peak input speed (mm/s) of each block: the 99th percentile of ``input_speed``; 0 for a block
    without samples."""
    speed = input_speed(t, u, fs)
    out = np.zeros(n_blocks)
    for b in range(n_blocks):
        sel = after & (pos == b)
        if sel.any():
            out[b] = float(np.percentile(speed[sel], 99))
    return out


def balanced_pattern(speeds: np.ndarray, pattern: tuple[int, ...]) -> tuple[int, ...]:
    """The scored blocks, changed so that the two fastest blocks of the log fall one on each side.

    A slew limit, a delay or a lag shows most where the command moves fastest. If the log's fastest
    stretches all fall in training blocks, the held-out test sees no evidence of such an effect; if they
    all fall in scored blocks, the fit sees none. When the two fastest blocks are on the same side, the
    fastest one changes side (the other one if the fastest is the last block) with the block of the
    other side nearest to it in time, the slower of two equally near. The last block, when scored, never
    moves: a drift is tested where it has grown most. No threshold: on a log whose blocks all move
    alike the two fastest are picked by small differences, as arbitrary as the fixed pattern itself."""
    n = speeds.size
    scored = set(p for p in pattern if p < n)
    if n < 4 or len(scored) < 2 or not np.any(speeds > 0):
        return tuple(sorted(scored))
    a, b = (int(i) for i in np.argsort(-speeds, kind="stable")[:2])
    if (a in scored) != (b in scored):
        return tuple(sorted(scored))
    last = n - 1 if n - 1 in scored else -1
    if a in scored:  # both scored: one goes to training
        mover = a if a != last else b
        others = [x for x in range(n) if x not in scored]
    else:  # both trained on: the fastest is scored
        mover = a
        others = [x for x in scored if x != last]
    if not others:
        return tuple(sorted(scored))
    partner = min(others, key=lambda x: (abs(x - mover), speeds[x]))
    scored ^= {mover, partner}
    return tuple(sorted(scored))


def make_split(t: np.ndarray, u: np.ndarray, n_blocks: int = 10, chunk_s: float | None = None) -> Split:
    """Alternating contiguous blocks: blocks 1, 4, 6, 9 of 10 scored, the rest trained on, unless the log's
    two fastest blocks would then sit on the same side (``balanced_pattern``).

    Scored blocks are cut into chunks of ``chunk_s`` (default: about ``SCORE_CHUNKS`` chunks, each between
    5 samples and 1 s long) for the paired tests."""
    n = t.size
    start = warmup_end(u)
    edges = np.linspace(t[start], t[-1], n_blocks + 1)
    pos = np.searchsorted(edges, t, side="right") - 1
    pos = np.clip(pos, 0, n_blocks - 1)
    train = np.zeros(n, bool)
    score = np.zeros(n, bool)
    after = np.arange(n) >= start
    fs = (n - 1) / max(t[-1] - t[0], 1e-12)
    pattern = balanced_pattern(block_speeds(t, u, fs, pos, n_blocks, after), SCORE_PATTERN)
    is_score = np.isin(pos, pattern)
    score[after & is_score] = True
    train[after & ~is_score] = True
    if chunk_s is None:  # ~SCORE_CHUNKS chunks, 5 samples to 1 s long
        scored_s = (t[-1] - t[start]) * len(pattern) / n_blocks
        chunk_s = min(1.0, max(scored_s / SCORE_CHUNKS, 5.0 / fs))
    chunks = chunk_ids(score, t, chunk_s)
    blocks = []
    for b in range(n_blocks):
        idx = np.flatnonzero(after & (pos == b))
        if idx.size:
            blocks.append((int(idx[0]), int(idx[-1]) + 1, "score" if b in pattern else "train"))
    return Split(train, score, chunks, start, blocks, pattern)
