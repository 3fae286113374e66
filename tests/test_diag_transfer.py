"""The transfer check: does the bench's model-error correction carry to the field log?"""

from __future__ import annotations

import math

import numpy as np
import pytest

from warpbridge.model.diagnosis.options import DiagnoseOptions
from warpbridge.model.diagnosis.stats import chunk_ids
from warpbridge.model.diagnosis.transfer import Transfer, mean_se, raised_floor, transfer

FS = 500.0


def _field(gain_here: float, seed: int = 0, seconds: float = 40.0, jitter: float = 0.0):
    """A log whose bare model misses by a structured error the corrected model removes to ``gain_here``'s
    extent (the drop of the squared error); ``jitter`` (deg) is what the correction adds of its own, a
    slowly varying error that makes the gain vary from chunk to chunk; chunks as diagnose scores them."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / FS)
    miss = 0.2 * np.sin(2 * np.pi * 0.7 * t) * np.sign(np.sin(2 * np.pi * 0.13 * t))
    w = 5.0 + 0.03 * rng.standard_normal(t.size)
    w_bare = w - miss
    # the corrected model removes the share of the miss whose squared error drop is gain_here
    full = float(np.mean(miss ** 2))
    keep = 1.0 - math.sqrt(max(1.0 - gain_here / full, 0.0))
    w_corr = w_bare + keep * miss
    if jitter:
        slow = np.convolve(rng.standard_normal(t.size), np.ones(200) / np.sqrt(200), mode="same")
        w_corr = w_corr + jitter * slow
    chunks = chunk_ids(np.ones(t.size, bool), t, 0.25)
    return w, w_bare, w_corr, chunks, full


def test_a_correction_that_gains_here_what_it_gained_on_the_bench_carries():
    w, wb, wc, ch, full = _field(0.015)
    tr = transfer(w, wb, wc, ch, bench_gain=0.015)
    assert tr.field_gain == pytest.approx(0.015, rel=0.05)
    assert not tr.short and tr.shortfall < 0.002


def test_a_correction_that_gains_a_fraction_here_falls_short_by_the_difference():
    w, wb, wc, ch, full = _field(0.004)
    tr = transfer(w, wb, wc, ch, bench_gain=0.015)
    assert tr.short and tr.p_value < DiagnoseOptions.transfer_alpha
    assert tr.shortfall == pytest.approx(0.011, rel=0.1)


def test_gaining_more_here_than_on_the_bench_is_no_shortfall():
    w, wb, wc, ch, full = _field(0.02)
    tr = transfer(w, wb, wc, ch, bench_gain=0.005)
    assert tr.shortfall == 0.0 and not tr.short and tr.p_value > 0.5


def test_too_few_chunks_or_a_broken_prediction_is_never_short():
    w, wb, wc, ch, _ = _field(0.0)
    few = np.where(ch < 3, ch, -1)
    assert not transfer(w, wb, wc, few, bench_gain=0.05).short
    wc = wc.copy()
    wc[100] = np.nan
    broken = transfer(w, wb, wc, ch, bench_gain=0.05)
    assert math.isnan(broken.field_gain) and broken.p_value == 1.0


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_gain_that_varies_from_chunk_to_chunk_is_judged_by_its_spread(seed):
    # the correction's own slow error (0.03 deg) makes the gain vary along the log: the same gain as the bench's
    # is not short, and a bench gain within a standard error or two of it is not either
    w, wb, wc, ch, _ = _field(0.010, seed=seed, jitter=0.03)
    same = transfer(w, wb, wc, ch, bench_gain=0.010 - 0.03 ** 2)
    assert same.se > 1e-4 and not same.short
    near = transfer(w, wb, wc, ch, bench_gain=same.field_gain + 1.5 * same.se)
    assert not near.short and 0.01 < near.p_value < 0.2
    far = transfer(w, wb, wc, ch, bench_gain=same.field_gain + 5 * same.se)
    assert far.short


def test_the_standard_error_widens_with_the_series_memory():
    rng = np.random.default_rng(4)
    white = rng.standard_normal(4000)
    se, dof = mean_se(white)
    assert se == pytest.approx(1.0 / math.sqrt(4000), rel=0.15) and dof > 2000
    ar = np.zeros(4000)
    for i in range(1, ar.size):
        ar[i] = 0.8 * ar[i - 1] + white[i]
    # an AR(1) of 0.8: the mean's variance is (1 + 0.8) / (1 - 0.8) = 9 times the white one's
    se_ar, dof_ar = mean_se(ar)
    assert se_ar > 2.5 * float(np.std(ar)) / math.sqrt(ar.size) and dof_ar < 4000 / 5
    assert mean_se(np.ones(1)) == (math.inf, 0.0)


def _ar1_chunk_means(rng, rho: float, n: int = 96) -> np.ndarray:
    e = rng.standard_normal(n + 100)
    x = np.empty_like(e)
    x[0] = e[0]
    for i in range(1, e.size):
        x[i] = rho * x[i - 1] + e[i]
    return x[100:]


@pytest.mark.parametrize("rho", [0.0, 0.5])
def test_a_correction_that_carries_is_rarely_called_short_on_correlated_chunks(rho):
    # the field's chunk gains around the bench's own gain, with memory from chunk to chunk as a slow model
    # error gives them: a test at level 0.001 calls it short in few of 3000 logs (1 expected of 1000)
    rng = np.random.default_rng(11)
    fired = 0
    for _ in range(3000):
        gain = 0.01 * (1.0 + 0.2 * _ar1_chunk_means(rng, rho))  # the chunks' gains about the bench's 0.01
        w_corr = np.full(gain.size, 0.5)  # a squared error of 0.25 left by the correction, more without it
        w_bare = np.sqrt(0.25 + gain)
        fired += transfer(np.zeros(gain.size), w_bare, w_corr, np.arange(gain.size), bench_gain=0.01).short
    assert fired <= 12  # 0.4 %: short correlated series understate their memory a little


def test_the_floor_rises_by_the_smaller_shortfall_only_when_both_are_significant():
    short_big = Transfer(0.05, 0.01, 0.002, 1e-9)
    short_small = Transfer(0.05, 0.03, 0.002, 1e-6)
    carried = Transfer(0.05, 0.049, 0.002, 0.3)
    assert raised_floor(short_big, short_small) == pytest.approx(0.02)
    assert raised_floor(short_small, short_big) == pytest.approx(0.02)
    assert raised_floor(short_big, carried) == 0.0
    assert raised_floor(carried, short_big) == 0.0
