"""sitl.png: readable for short and long runs; the binning and the zoom window it relies on."""

from __future__ import annotations

import math

import numpy as np
import pytest

from warpbridge.sitl.lockstep import RunResult
from warpbridge.sitl.report import LONG_RUN_S, binned_rms, plot_run, worst_window


def test_binned_rms_by_hand():
    t = np.arange(0.0, 3.0, 0.25)  # 4 samples per 1 s bin, 3 bins
    e = np.array([1, 1, 1, 1, 0, 0, 0, 0, 3, -3, 3, -3], dtype=float)
    centres, rms = binned_rms(t, e, 1.0)
    assert centres.tolist() == [0.5, 1.5, 2.5]
    assert rms.tolist() == [1.0, 0.0, 3.0]
    centres, rms = binned_rms(np.append(t, 3.0), np.append(e, 9.0), 1.0)  # a one-sample sliver at the end
    assert centres.tolist() == [0.5, 1.5, 2.5]


def test_worst_window_finds_the_burst():
    t = np.arange(0.0, 100.0, 0.01)
    e = np.full(t.size, 0.1)
    e[(t >= 61.0) & (t < 66.0)] = 1.0  # 5 s of large error
    a, b = worst_window(t, e, 2.0, 100.0, 10.0)
    assert b - a == 10.0 and a <= 61.0 and b >= 66.0
    assert worst_window(t, e, 2.0, 8.0, 10.0) == (2.0, 8.0)  # shorter than the window: the whole stretch


def result(duration: float, rate: float = 100.0) -> RunResult:
    t = np.arange(0.0, duration, 1.0 / rate)
    sp = {w: 6 + 3 * np.sin(2 * np.pi * 0.7 * t + k) for k, w in enumerate(("left", "right"))}
    warp = {w: v - 0.1 * np.cos(2 * np.pi * 0.7 * t) for w, v in sp.items()}
    u = {w: 0.7 * v for w, v in warp.items()}
    r = RunResult("random", "ff+pi", t, np.full(t.size, 12.0), sp, warp, warp, u, u)
    r.compute_rms(t_from=2.0)
    return r


@pytest.mark.parametrize("duration", [10.0, 4 * LONG_RUN_S])
def test_plot_of_a_short_and_a_long_run(tmp_path, duration):
    import matplotlib.image as mpimg

    rt, other = result(duration), result(duration)
    png = plot_run(rt, tmp_path / "sitl.png", other=other)
    img = mpimg.imread(png)
    rows = 4 if duration > LONG_RUN_S else 3  # long runs get the zoomed row
    assert img.shape[0] == pytest.approx(90 * (3.1 * rows + 1.0), abs=2)
    assert math.isfinite(rt.rms["left"])
