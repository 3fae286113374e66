"""The simulated wing's parts: servo, flex sensor, gusts, and the wing stepping itself."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from warpbridge.hw.calibration import SensorCalibration
from warpbridge.sitl.flex_sensor import FlexSensor, FlexSensorSpec
from warpbridge.sitl.gust import Gust, GustSpec, shedding_hz
from warpbridge.sitl.servo_model import ServoModel, ServoSpec
from warpbridge.sitl.wing import SimWing, SteadyFlow, WingSpec


def test_servo_slews_no_faster_than_its_rating():
    spec = ServoSpec()
    s = ServoModel(spec, pulse0_us=1200.0)
    t, pos = 0.0, []
    for _ in range(400):
        t += 0.001
        s.step(t, 1800.0)
        pos.append(s.position_us)
    rate = np.max(np.diff(pos)) / 0.001
    assert rate == pytest.approx(spec.max_speed_us_s, rel=1e-6)  # 60 deg in 0.1 s
    assert spec.max_speed_mm_s == pytest.approx(104.72, abs=0.01)  # 600 deg/s on a 10 mm horn: 10 * 10.472 mm/s
    assert pos[-1] == pytest.approx(1800.0 - spec.deadband_us / 2, abs=0.05)


def test_servo_ignores_changes_within_its_deadband_and_quantises():
    s = ServoModel(ServoSpec(deadband_us=2.0, quantum_us=0.25), pulse0_us=1500.0)
    s.step(1.0, 1500.9)  # inside the deadband: no move
    assert s.position_us == 1500.0
    s.step(2.0, 1510.1)  # quantised to 1510.0, stops at the deadband's edge
    assert s.position_us == pytest.approx(1509.0, abs=1e-6)
    assert s.mm == pytest.approx(6.4246, abs=1e-4)  # 409 us above 1100 us at 0.09 deg/us on a 10 mm horn


def test_flex_sensor_counts_read_back_through_the_bridge_calibration():
    spec = FlexSensorSpec(noise_deg=0.0)
    cal = SensorCalibration(*spec.calibration_table())
    sensor = FlexSensor(spec)
    for w in np.linspace(-2.0, 20.0, 23):
        counts = sensor.read(float(w))
        assert isinstance(counts, int) and 0 <= counts <= 1023
        # one count is 1/28 deg: quantisation plus table interpolation stay within it
        assert cal.deg_for_counts(counts) == pytest.approx(w, abs=1.0 / spec.slope_counts_per_deg)


def test_flex_sensor_noise_has_its_rms():
    spec = FlexSensorSpec(noise_deg=0.1)
    cal = SensorCalibration(*spec.calibration_table())
    s = FlexSensor(spec, seed=3)
    readings = np.array([cal.deg_for_counts(s.read(8.0)) for _ in range(4000)])
    assert readings.std() == pytest.approx(0.1, rel=0.1)
    assert readings.mean() == pytest.approx(8.0, abs=0.02)


def test_gust_has_the_intensity_and_the_shedding_peak():
    g = Gust(GustSpec(mean_ms=7.0, intensity=0.3, seed=1))
    fs = 2000.0
    t = np.arange(0, 20.0, 1 / fs)
    v = g.wind(t)
    assert v.mean() == pytest.approx(7.0, rel=0.03)
    assert v.std() / v.mean() == pytest.approx(0.3, rel=0.1)
    f, p = signal.welch(v - v.mean(), fs=fs, nperseg=4096)
    band = (f > 20) & (f < 400)
    assert f[band][np.argmax(p[band])] == pytest.approx(shedding_hz(7.0), abs=10.0)  # ~110 Hz at 7 m/s
    assert shedding_hz(12.0) == pytest.approx(110.0 * 12 / 7)
    # the load follows less of the fast part (Sears), the same mean
    va = g.airspeed(t)
    assert va.mean() == pytest.approx(v.mean(), rel=0.01) and va.std() < 0.8 * v.std()
    b = g.buffet_deg(t)
    assert b.std() == pytest.approx(g.spec.buffet_deg_per_kpa * 0.5 * 1.225 * 49 / 1000, rel=0.1)


def test_gust_is_reproducible_and_seeded():
    t = np.linspace(0, 2, 500)
    a, b = Gust(GustSpec(12.0, seed=5)), Gust(GustSpec(12.0, seed=5))
    np.testing.assert_array_equal(a.airspeed(t), b.airspeed(t))
    assert not np.allclose(a.airspeed(t), Gust(GustSpec(12.0, seed=6)).airspeed(t))
    assert float(a.airspeed(0.7)) == pytest.approx(float(a.airspeed(np.array([0.7]))[0]))


def test_wing_advance_does_not_depend_on_how_time_is_chunked():
    def run(chunk: float) -> tuple[float, float]:
        w = SimWing(WingSpec(), Gust(GustSpec(12.0, seed=2)), w0_deg=6.0)
        t = 0.0
        while t < 1.0 - 1e-9:
            t = min(1.0, t + chunk)
            w.set_pulse(w.spec.rest_pulse(6.0) + (100.0 if t > 0.3 else 0.0))
            w.advance(t)
        return w.w_true, w.u_mm

    a, b = run(0.01), run(0.05)
    assert a[1] == pytest.approx(b[1], abs=1e-3)  # same servo end point
    assert abs(a[0] - b[0]) < 0.3  # buffeting differs only by when the sample is taken


def test_wing_holds_its_rest_warp_and_follows_a_pull():
    spec = WingSpec()
    w = SimWing(spec, SteadyFlow(0.0), w0_deg=6.0)
    assert w.w_true == pytest.approx(6.0, abs=0.02)
    w.advance(0.5)
    assert w.w_true == pytest.approx(6.0, abs=0.02)
    w.set_pulse(spec.rest_pulse(9.0) + 30.0)  # pulling past the loading branch
    w.advance(1.0)
    assert w.w_true > 8.0
    counts = w.read_counts()
    cal = SensorCalibration(*spec.sensor.calibration_table())
    assert cal.deg_for_counts(counts) == pytest.approx(w.w_meas, abs=0.2)


def test_sheath_wing_starts_where_asked_and_logs_a_bench_run_through_the_sensor():
    from warpbridge.sitl.sheath import rigged_sheath
    from warpbridge.sitl.wing import SheathWing, bench_log

    spec = WingSpec(plant=SheathWing(rigged_sheath()))
    wing = SimWing(spec, w0_deg=6.0)
    assert wing.w_true == pytest.approx(6.0, abs=0.02)  # pulled from slack to 6 deg (servo quantised)
    wing.advance(0.5)
    assert wing.w_true == pytest.approx(6.0, abs=0.02)  # and held there
    u0 = spec.plant.rest_tendon(6.0)
    log = bench_log(spec, u0 - 0.01, u0 + 0.01, seconds=4.0, rate_hz=100.0, seed=3)
    assert set(log) == {"t", "u", "warp"} and log["t"].size == 400
    # a wing held still (a 0.02 mm window is inside the sheath's dead zone) reads the sensor's noise,
    # 0.03 deg, through 10-bit counts of 1/28 deg: the log's scatter is that, and it comes in whole counts
    assert 0.02 < np.std(log["warp"]) < 0.05
    levels = np.unique(log["warp"])
    assert levels.size < 15 and np.allclose(np.diff(levels), 1 / 28, rtol=0.1)
    with pytest.raises(ValueError, match="Bouc-Wen"):
        from warpbridge.model.effects import Effects

        spec.with_effects(Effects(delay_s=0.01))
