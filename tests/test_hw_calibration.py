"""Calibrations: round trips, clamping, quantisation, and the validation of config tables."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from warpbridge.hw.calibration import SensorCalibration, ServoCalibration

SERVO = {"pulse_min_us": 1000.0, "pulse_max_us": 2000.0, "pulse_zero_us": 1100.0, "mm_per_us": 0.02}


def test_servo_pulse_for_mm_and_back():
    cal = ServoCalibration.from_dict(SERVO)
    assert cal.pulse_for_mm(0.0) == 1100.0
    assert cal.pulse_for_mm(10.0) == 1600.0
    assert cal.mm_for_pulse(1600.0) == pytest.approx(10.0)
    assert cal.mm_range == pytest.approx((-2.0, 18.0))


def test_servo_clamps_and_quantises_to_quarter_microseconds():
    cal = ServoCalibration(1000.1, 1999.9, 1100.0, 0.02)
    assert cal.pulse_for_mm(100.0) == 1999.75  # clamped, and on the 0.25 us grid inside the range
    assert cal.pulse_for_mm(-100.0) == 1000.25
    assert cal.pulse_for_mm(0.0031) == 1100.25  # 1100.155 us -> nearest quarter
    assert ServoCalibration(1000, 2000, 1100, 0.02, quantum_us=0).pulse_for_mm(0.0031) == pytest.approx(1100.155)
    with pytest.raises(ValueError):
        cal.pulse_for_mm(math.nan)


def test_reversed_servo():
    cal = ServoCalibration(1000, 2000, 1900, -0.02)
    assert cal.pulse_for_mm(10.0) == 1400.0
    assert cal.mm_range == pytest.approx((-2.0, 18.0))


@given(st.floats(min_value=-2.0, max_value=18.0))
def test_servo_round_trip_within_half_a_quantum(u):
    cal = ServoCalibration.from_dict(SERVO)
    pulse = cal.pulse_for_mm(u)
    assert pulse * 4 == round(pulse * 4)
    assert abs(cal.mm_for_pulse(pulse) - u) <= 0.125 * abs(cal.mm_per_us) + 1e-12


def test_servo_from_horn():
    cal = ServoCalibration.from_dict(
        {"pulse_min_us": 1000, "pulse_max_us": 2000, "pulse_zero_us": 1500, "horn_radius_mm": 10.0, "deg_per_us": 0.09}
    )
    assert cal.mm_per_us == pytest.approx(10.0 * math.radians(0.09))
    assert ServoCalibration.from_dict(cal.to_dict()) == cal


def test_servo_dict_round_trip():
    cal = ServoCalibration.from_dict({**SERVO, "quantum_us": 0.5})
    assert cal.to_dict() == {**SERVO, "quantum_us": 0.5}
    assert ServoCalibration.from_dict(cal.to_dict()) == cal


@pytest.mark.parametrize(
    "change, message",
    [
        ({"pulse_min_us": 2100.0}, "pulse_min_us < pulse_max_us"),
        ({"pulse_max_us": 5000.0}, "pulse_max_us <= 3000"),
        ({"pulse_zero_us": 900.0}, "pulse_zero_us 900 outside"),
        ({"mm_per_us": 0.0}, "mm_per_us must not be 0"),
        ({"mm_per_us": math.inf}, "mm_per_us must be finite"),
        ({"mm_per_us": "0.02"}, "mm_per_us must be a number"),
        ({"quantum_us": -0.25}, "quantum_us must be >= 0"),
        ({"pulse_maxus": 1.0}, "unknown key"),
    ],
)
def test_servo_validation_errors(change, message):
    with pytest.raises(ValueError, match=message):
        ServoCalibration.from_dict({**SERVO, **change})


def test_servo_missing_keys():
    with pytest.raises(ValueError, match="missing key 'pulse_zero_us'"):
        ServoCalibration.from_dict({k: v for k, v in SERVO.items() if k != "pulse_zero_us"})
    with pytest.raises(ValueError, match="horn_radius_mm and deg_per_us"):
        ServoCalibration.from_dict({k: v for k, v in SERVO.items() if k != "mm_per_us"})
    with pytest.raises(ValueError, match="missing key 'deg_per_us'"):
        ServoCalibration.from_dict({**{k: v for k, v in SERVO.items() if k != "mm_per_us"}, "horn_radius_mm": 9})
    with pytest.raises(ValueError, match="horn_radius_mm must be > 0"):
        ServoCalibration.from_horn(0.0, 0.09, 1500, 1000, 2000)


TABLE = {"counts": [200, 400, 700, 900], "deg": [0.0, 2.0, 5.0, 8.0]}


def test_sensor_table_interpolates_and_clamps():
    cal = SensorCalibration.from_dict(TABLE)
    assert cal.deg_for_counts(300) == pytest.approx(1.0)
    assert cal.deg_for_counts(800) == pytest.approx(6.5)
    assert cal.deg_for_counts(0) == 0.0
    assert cal.deg_for_counts(1023) == 8.0
    assert cal.counts_for_deg(3.5) == pytest.approx(550.0)
    assert cal.counts_for_deg(-4.0) == 200.0
    assert cal.deg_range == (0.0, 8.0)


def test_sensor_table_may_decrease():
    cal = SensorCalibration(counts=[900, 500, 100], deg=[0.0, 4.0, 8.0])
    assert cal.deg_for_counts(700) == pytest.approx(2.0)
    assert cal.deg_for_counts(1000) == 0.0
    assert cal.counts_for_deg(6.0) == pytest.approx(300.0)


@given(st.floats(min_value=0.0, max_value=8.0))
def test_sensor_round_trip(w):
    cal = SensorCalibration.from_dict(TABLE)
    assert cal.deg_for_counts(cal.counts_for_deg(w)) == pytest.approx(w, abs=1e-9)


def test_sensor_dict_round_trip():
    cal = SensorCalibration.from_dict(TABLE)
    assert cal.to_dict() == {"counts": [200.0, 400.0, 700.0, 900.0], "deg": [0.0, 2.0, 5.0, 8.0]}
    assert SensorCalibration.from_dict(cal.to_dict()) == cal


@pytest.mark.parametrize(
    "table, message",
    [
        ({"counts": [200, 400, 400, 900], "deg": [0, 2, 5, 8]}, r"counts must be strictly .* entries 1 and 2"),
        ({"counts": [200, 400, 700, 900], "deg": [0, 2, 1, 8]}, r"deg must be strictly .* entries 1 and 2"),
        ({"counts": [200, 400], "deg": [0, 2, 5]}, "counts has 2 entries but deg has 3"),
        ({"counts": [200], "deg": [0]}, "at least 2 points"),
        ({"counts": [200, math.nan], "deg": [0, 2]}, "counts must be finite"),
        ({"counts": [200, 400]}, "missing key 'deg'"),
        ({"counts": "200,400", "deg": [0, 2]}, "counts must be a list of numbers"),
        ({"counts": [200, True], "deg": [0, 2]}, "counts must be a list of numbers"),
        ({"counts": [200, 400], "deg": [0, 2], "offset": 1}, "unknown key"),
    ],
)
def test_sensor_validation_errors(table, message):
    with pytest.raises(ValueError, match=message):
        SensorCalibration.from_dict(table)


@given(st.lists(st.floats(-1e4, 1e4), min_size=2, max_size=12, unique=True),
       st.floats(-2e4, 2e4), st.booleans())
def test_sensor_table_interpolates_as_numpy_does(xs, x, falling):
    """The table is read without numpy (the bridge commands neutral before numpy loads): same answers."""
    counts = sorted(xs)
    deg = [0.5 * i * i + i for i in range(len(counts))]  # strictly increasing
    if falling:
        deg = deg[::-1]
    cal = SensorCalibration(counts, deg)
    order = np.argsort(counts)
    expect = float(np.interp(x, np.array(counts)[order], np.array(deg)[order]))
    assert cal.deg_for_counts(x) == pytest.approx(expect, rel=1e-12, abs=1e-9)
    d_sorted = np.argsort(deg)
    back = float(np.interp(cal.deg_for_counts(x), np.array(deg)[d_sorted], np.array(counts)[d_sorted]))
    assert cal.counts_for_deg(cal.deg_for_counts(x)) == pytest.approx(back, rel=1e-12, abs=1e-9)
