"""The blind benchmark's LuGre sheath (benchmarks/truth_lugre.py) obeys the mechanics it is written from."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from truth_lugre import lugre_params, lugre_run, wing_rest  # noqa: E402

BEND, N, K_T, T_REST, K_W, H, MMDEG = 270.0, 12, 4.0, 0.5, 1.2, 0.3, 0.5


def rig(mu_c=0.2, mu_v=0.0, mu_s=None, n=N):
    return lugre_params(BEND, n, K_T, T_REST, mu_c, mu_c if mu_s is None else mu_s, 1.0, 0.005, 0.001, mu_v, K_W,
                        H, MMDEG)


def run(prm, t, x, n=N, q=None, c0=0.0, c1=0.0):
    return lugre_run(t, x, np.zeros(t.size) if q is None else q, c0, c1, prm, n)


def cycle(freq_hz, cycles=3, rate=500.0, lo=1.0, hi=9.0):
    t = np.arange(int(cycles / freq_hz * rate)) / rate
    return t, lo + (hi - lo) * 0.5 * (1.0 - np.cos(2.0 * np.pi * freq_hz * t))


def loop_area(x, w):
    """|closed integral of w dx| over the last cycle's samples given."""
    return abs(float(np.sum(0.5 * (w[1:] + w[:-1]) * np.diff(x))))


def test_frictionless_sheath_is_the_elastic_chain():
    """mu = 0: one tension all along; the tendon's stretch and the wing's hardening spring fix the warp."""
    t, x = cycle(0.5)
    w, _, tens = run(rig(mu_c=0.0), t, x)
    a_h = H / (20.0 * MMDEG)
    p_rest = wing_rest(T_REST, K_W, a_h)
    pa = w * MMDEG  # far end from the wing's unloaded shape
    tension = K_W * pa * (1.0 + a_h * pa)
    stretch = (tension - T_REST) / K_T  # the tendon's elongation beyond rest
    assert np.allclose(x - (pa - p_rest), stretch, atol=1e-6)
    assert np.ptp(tens) < 1e-6


def test_slow_slip_follows_the_capstan_law():
    """A slow steady pull: each node holds theta (T_l + T_r) / 2 mu_c, so the servo end pulls
    ((1 + mu theta / 2) / (1 - mu theta / 2))^n times the far end (-> exp(mu bend))."""
    mu = 0.2
    t = np.arange(20000) / 500.0
    x = 0.5 * t  # 0.5 mm/s for 40 s: the whole tendon slides in
    _, _, tens = run(rig(mu_c=mu), t, x)
    th = math.radians(BEND) / N
    ratio = ((1 + 0.5 * mu * th) / (1 - 0.5 * mu * th)) ** N
    assert tens[0] / tens[-1] == pytest.approx(ratio, rel=2e-3)
    assert ratio == pytest.approx(math.exp(mu * math.radians(BEND)), rel=0.01)


def test_viscous_drag_widens_the_loop_with_speed():
    """Rate dependence: with a lubricant's drag the loop at 2 Hz is wider than at 0.2 Hz; without it (Coulomb
    bristles alone) the two are nearly the same."""
    areas = {}
    for mu_v in (0.0, 0.1):
        for f in (0.2, 2.0):
            t, x = cycle(f)
            w, _, _ = run(rig(mu_v=mu_v), t, x)
            last = t >= t[-1] - 1.0 / f
            areas[mu_v, f] = loop_area(x[last], w[last])
    assert areas[0.1, 2.0] > 1.3 * areas[0.1, 0.2]
    assert areas[0.0, 2.0] == pytest.approx(areas[0.0, 0.2], rel=0.1)
    assert areas[0.1, 0.2] > areas[0.0, 0.2]


def test_friction_widens_the_loop_and_the_result_holds_at_other_sample_rates():
    t, x = cycle(0.5)
    w1, _, _ = run(rig(mu_c=0.1), t, x)
    w2, _, _ = run(rig(mu_c=0.2), t, x)
    last = t >= t[-1] - 2.0
    assert loop_area(x[last], w2[last]) > 1.5 * loop_area(x[last], w1[last])
    t4, x4 = cycle(0.5, rate=2000.0)
    w4, _, _ = run(rig(mu_c=0.2, mu_v=0.05, mu_s=0.21), t4, x4)
    w2v, _, _ = run(rig(mu_c=0.2, mu_v=0.05, mu_s=0.21), t, x)
    assert np.max(np.abs(w4[::4] - w2v)) < 0.05


def test_aero_load_pushes_the_trailing_edge_back():
    t, x = cycle(0.5)
    w0, _, _ = run(rig(), t, x)
    wl, _, _ = run(rig(), t, x, q=np.full(t.size, 0.2), c0=2.0)
    assert np.all(wl[t > 1.0] < w0[t > 1.0])
