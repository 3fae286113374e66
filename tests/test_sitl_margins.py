"""Loop margins: the analysis against closed forms and textbook cases, the measurement on lock-step."""

from __future__ import annotations

import math

import numpy as np
import pytest

from warpbridge.sitl.margins import LOW_TONES, linear_margins, linear_response, margins, measure_loop, plant_slope
from warpbridge.sitl.wing import LinearPlant


def test_textbook_type_one_loop():
    # L(s) = 1 / (s (s + 1)^2): the phase is -180 deg at w = 1 rad/s where |L| = 1/2, so the gain margin
    # is 2; |L| = 1 at w = 0.6823 rad/s (w^6 + 2 w^4 + w^2 = 1), phase margin 90 - 2 atan(0.6823) = 21.4 deg
    w = np.geomspace(0.01, 100.0, 20001)
    s = 1j * w
    m = margins(w / (2 * np.pi), 1.0 / (s * (s + 1.0) ** 2))
    assert m.gain == pytest.approx(2.0, rel=1e-3)
    assert m.phase_crossover_hz == pytest.approx(1.0 / (2 * np.pi), rel=1e-3)
    assert m.phase_deg == pytest.approx(21.39, abs=0.05)
    assert m.crossover_hz == pytest.approx(0.6823 / (2 * np.pi), rel=1e-3)
    assert m.stable


def test_pure_gain_with_one_sample_delay_has_its_margin_at_nyquist():
    # no servo lag, no integrator: L(z) = kp k / z, so L = -kp k at Nyquist: gain margin 1 / (kp k)
    m = linear_margins(0.25, 0.0, 2.0, loop_hz=100.0, tau_s=0.0)
    assert m.gain == pytest.approx(2.0, rel=1e-9)
    assert m.phase_crossover_hz == pytest.approx(50.0)
    assert m.phase_deg == math.inf  # |L| = 0.5 everywhere: never crosses 1
    assert not linear_margins(1.0, 0.0, 2.0, tau_s=0.0).stable  # kp k = 2: unstable


def test_first_order_servo_gain_margin_closed_form():
    # L = kp k (1 - a) / (z - a), a = exp(-T / tau): at z = -1, |L| = kp k (1 - a) / (1 + a);
    # T = 10 ms, tau = 20 ms: a = exp(-0.5) = 0.6065307, (1 + a) / (1 - a) = 4.0830 by hand
    m = linear_margins(1.0, 0.0, 1.0, loop_hz=100.0, tau_s=0.02)
    assert m.gain == pytest.approx(4.0830, rel=1e-4)
    L = linear_response([50.0], 1.0, 0.0, 1.0, loop_hz=100.0, tau_s=0.02)[0]
    assert L.real == pytest.approx(-1 / 4.0830, rel=1e-4) and abs(L.imag) < 1e-9


def test_integral_action_lowers_the_phase_margin():
    stiff = linear_margins(0.5, 1.0, 3.3)
    quick = linear_margins(0.5, 40.0, 3.3)
    assert stiff.stable and quick.stable and quick.phase_deg < stiff.phase_deg - 20


def test_plant_slope_of_a_straight_line_and_a_bouc_wen_wing():
    assert plant_slope(LinearPlant(2.5, 1.0, 3.0), 0.0, 4.0, w_lo=0.0, w_hi=20.0) == pytest.approx(2.5, rel=1e-9)
    from warpbridge.sitl.wing import default_plant

    # the paper's model on its unloading branch near 10 deg: du/dw = 2 a1 w + a2 with z saturated,
    # 2 (-0.0205) 10 + 0.712 = 0.302 mm/deg, i.e. at most 1 / 0.302 = 3.31 deg/mm
    k = plant_slope(default_plant(), -0.5, 7.5, w_lo=2.0, w_hi=10.0)
    assert k == pytest.approx(1 / 0.302, rel=0.02)


def test_measured_response_follows_the_linear_analysis_at_low_frequency_and_finds_instability():
    fast = dict(settle_s=1.0, measure_s=4.0, bands=(LOW_TONES,))
    m = measure_loop(0.5, 10.0, 3.3, **fast)
    assert not m.diverged
    lin = linear_response(m.f_hz, 0.5, 10.0, 3.3)
    low = (m.f_hz >= 1.0) & (m.f_hz <= 10.0)
    # the lock-step loop cycles on the ticks and on every servo message (twice the analysis' rate), so
    # only the low tones, where the PI and the slope dominate, are compared
    np.testing.assert_allclose(np.abs(m.L[low]), np.abs(lin[low]), rtol=0.35)
    assert m.margins.stable
    wild = measure_loop(7.0, 1.0, 3.3, **fast)  # the paper's numbers taken as mm/deg
    assert wild.diverged or not wild.margins.stable
