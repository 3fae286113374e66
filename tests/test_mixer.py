"""Mixer: PWM -> normalised aileron -> one-sided warp per wing."""

from __future__ import annotations

import pytest

from warpbridge.bridge.mixer import Mixer, WingMix


def wing(ch: int, reverse: bool, bias: float = 0.0, mx: float = 8.0, lo=1100, trim=1500, hi=1900) -> WingMix:
    return WingMix(source_channel=ch, reverse=reverse, pwm_min=lo, pwm_trim=trim, pwm_max=hi,
                   max_warp_deg=mx, bias_deg=bias)


def test_shared_channel_one_reversed_roll_right_lifts_left_wing():
    m = Mixer({"left": wing(1, False), "right": wing(1, True)})
    assert m.setpoints({1: 1500}) == {"left": 0.0, "right": 0.0}
    assert m.setpoints({1: 1900}) == {"left": 8.0, "right": 0.0}  # roll right: left gains lift
    assert m.setpoints({1: 1100}) == {"left": 0.0, "right": 8.0}
    assert m.setpoints({1: 1700}) == {"left": pytest.approx(4.0), "right": 0.0}


def test_two_channels_and_asymmetric_scaling_about_trim():
    m = Mixer({"left": wing(1, False, lo=1000, trim=1400, hi=2000), "right": wing(2, False)})
    sp = m.setpoints({1: 1700, 2: 1300})
    assert sp["left"] == pytest.approx(4.0)  # 300 of 600 us above trim
    assert sp["right"] == 0.0
    assert m.aileron({1: 1200, 2: 1300}) == {"left": pytest.approx(-0.5), "right": pytest.approx(-0.5)}


def test_bias_prewarp_lets_both_wings_move_both_ways():
    m = Mixer({"left": wing(1, False, bias=2.0), "right": wing(1, True, bias=2.0)})
    assert m.setpoints({1: 1500}) == {"left": 2.0, "right": 2.0}
    assert m.neutral() == {"left": 2.0, "right": 2.0}
    sp = m.setpoints({1: 1700})  # half roll right
    assert sp["left"] == pytest.approx(5.0)  # 2 + 0.5 * (8 - 2)
    assert sp["right"] == pytest.approx(1.0)  # 2 * (1 - 0.5)
    assert m.setpoints({1: 1900}) == {"left": 8.0, "right": 0.0}


def test_pwm_beyond_endpoints_is_clamped():
    m = Mixer({"left": wing(1, False, bias=1.0), "right": wing(1, True, bias=1.0)})
    assert m.setpoints({1: 2050}) == {"left": 8.0, "right": 0.0}
    assert m.setpoints({1: 950}) == {"left": 0.0, "right": 8.0}


@pytest.mark.parametrize("pwm", [0, 65535, 850, 2150, float("nan"), None])
def test_invalid_pwm_gives_none(pwm):
    m = Mixer({"left": wing(1, False), "right": wing(2, True)})
    sp = m.setpoints({1: pwm, 2: 1500})
    assert sp["left"] is None
    assert sp["right"] == 0.0


def test_missing_channel_gives_none():
    m = Mixer({"left": wing(3, False), "right": wing(3, True)})
    assert m.setpoints({1: 1500}) == {"left": None, "right": None}


def test_retune_changes_range_and_caps_bias():
    m = Mixer({"left": wing(1, False, bias=2.0), "right": wing(1, True, bias=2.0)})
    m.retune(max_warp_deg=4.0)
    assert m.setpoints({1: 1900})["left"] == 4.0
    m.retune(bias_deg=6.0)
    assert m.neutral() == {"left": 4.0, "right": 4.0}
