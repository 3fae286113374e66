"""Every effect switch changes the simulated wing the way its definition says."""

from __future__ import annotations

import numpy as np
import pytest

from warpbridge.model.boucwen import BoucWenParams
from warpbridge.model.effects import Effects
from warpbridge.model.plant import Plant
from warpbridge.sitl.flex_sensor import FlexSensorSpec
from warpbridge.sitl.wing import SimWing, SteadyFlow, WingSpec

W0 = 6.0
H = 0.001


def wing(effects: Effects | None = None, airspeed: float = 0.0) -> SimWing:
    spec = WingSpec(plant=Plant(BoucWenParams.paper(), effects or Effects()), sensor=FlexSensorSpec(noise_deg=0.0))
    return SimWing(spec, SteadyFlow(airspeed), w0_deg=W0)


def fly(w: SimWing, pulse_of_t, duration: float) -> dict[str, np.ndarray]:
    """Command pulse_of_t(t) every millisecond; returns t, w_true, w_meas, u."""
    n = int(round(duration / H))
    out = {k: np.empty(n) for k in ("t", "w_true", "w_meas", "u")}
    for k in range(n):
        t = (k + 1) * H
        w.set_pulse(pulse_of_t(t))
        w.advance(t)
        out["t"][k], out["w_true"][k], out["w_meas"][k], out["u"][k] = t, w.w_true, w.w_meas, w.u_mm
    return out


def step_pulse(w: SimWing, at: float = 0.2, by_us: float = 150.0):
    p0 = w.pulse_us
    return lambda t: p0 + (by_us if t >= at else 0.0)


def sine_pulse(w: SimWing, amp_us: float = 200.0, f: float = 0.5):
    p0 = w.pulse_us + amp_us
    return lambda t: p0 - amp_us * np.cos(2 * np.pi * f * t)


def loop_area(u: np.ndarray, w: np.ndarray) -> float:
    """Area enclosed by the (u, w) trajectory (shoelace), over whole cycles."""
    return 0.5 * abs(float(np.sum(u[:-1] * w[1:] - u[1:] * w[:-1])))


def first_move(r: dict[str, np.ndarray], w_start: float, tol: float = 0.02) -> float:
    moved = np.abs(r["w_true"] - w_start) > tol
    return float(r["t"][np.argmax(moved)])


def test_neutral_effects_leave_the_wing_alone():
    a = fly(wing(), sine_pulse(wing()), 2.0)
    b = fly(wing(Effects(friction_scale=1.0, pretension_gain=1.0)), sine_pulse(wing()), 2.0)
    np.testing.assert_array_equal(a["w_true"], b["w_true"])
    np.testing.assert_array_equal(a["w_true"], a["w_meas"])


def test_delay_shifts_the_response_in_time():
    base = wing()
    r0 = fly(base, step_pulse(base), 0.6)
    d = wing(Effects(delay_s=0.05))
    r1 = fly(d, step_pulse(d), 0.6)
    t0, t1 = first_move(r0, W0), first_move(r1, W0)
    assert t1 - t0 == pytest.approx(0.05, abs=0.003)
    # same response, only later: compare the shifted curves
    k = 50
    np.testing.assert_allclose(r1["w_true"][k:], r0["w_true"][:-k], atol=1e-6)


def test_rate_limit_caps_the_tendon_slew():
    base = wing()
    r0 = fly(base, step_pulse(base, by_us=200.0), 0.8)
    lim = wing(Effects(rate_mm_s=10.0))
    r1 = fly(lim, step_pulse(lim, by_us=200.0), 0.8)
    du = 200.0 * lim.spec.servo.mm_per_us  # 3.1 mm: at 10 mm/s it takes 0.31 s
    final = r0["w_true"][-1]
    i = int(round((0.2 + 0.1) / H)) - 1
    assert abs(r0["w_true"][i] - final) < 0.05 * abs(final - W0)  # the free servo is there after 0.1 s
    assert abs(r1["w_true"][i] - W0) < 0.5 * abs(final - W0)  # the limited one is not half-way
    assert r1["w_true"][-1] == pytest.approx(final, abs=0.02)  # but gets there
    # the sheath's tendon needs du / rate to travel: before that the warp is still short of its end
    j = int(round((0.2 + 0.9 * du / 10.0) / H)) - 1
    assert final - r1["w_true"][j] > 0.05


def test_backlash_adds_a_dead_band_at_reversals():
    def reversal(w):
        p0 = w.pulse_us
        return lambda t: p0 + (150.0 * min(t, 0.5) / 0.5 if t < 0.6 else 150.0 - 150.0 * min(t - 0.6, 0.5) / 0.5)

    base, bl = wing(), wing(Effects(backlash_mm=0.5))
    r0, r1 = fly(base, reversal(base), 1.2), fly(bl, reversal(bl), 1.2)
    # after the reversal the slack must be taken up: 0.5 mm of tendon (~32 us of pulse, 0.106 s of the
    # 300 us/s ramp) before the release reaches the sheath, on top of the sheath's own dead zone
    t_slack = 0.5 / bl.spec.servo.mm_per_us / 300.0

    def release_time(r):
        after = r["t"] > 0.6
        peak = r["w_true"][after][0]
        return float(r["t"][after][np.argmax(r["w_true"][after] < peak - 0.3)]) - 0.6

    assert release_time(r1) - release_time(r0) == pytest.approx(t_slack, rel=0.25)
    # on the way up, the slack is taken up once at the start, then the wing follows as before, shifted
    assert r1["w_true"][int(0.55 / H)] < r0["w_true"][int(0.55 / H)]


def test_friction_widens_the_loop():
    areas = {}
    for s in (1.0, 1.6):
        w = wing(Effects(friction_scale=s))
        r = fly(w, sine_pulse(w), 4.0)
        keep = r["t"] >= 2.0  # second cycle
        areas[s] = loop_area(r["u"][keep], r["w_true"][keep])
    assert areas[1.6] > 1.3 * areas[1.0]


def test_pretension_shifts_and_scales_the_loop():
    base = wing()
    p_hold = base.pulse_us + 100.0
    r0 = fly(base, lambda t: p_hold, 0.5)
    off = wing(Effects(pretension_offset_mm=0.5))
    r1 = fly(off, lambda t: p_hold, 0.5)
    assert r1["w_true"][-1] < r0["w_true"][-1] - 0.3  # offset: less warp for the same pull
    g = wing(Effects(pretension_gain=1.2))
    rg = fly(g, lambda t: p_hold, 0.5)
    assert rg["w_true"][-1] > r0["w_true"][-1] + 0.3  # gain: more warp for the same pull


def test_sensor_lag_lags_the_measurement_only():
    base = wing()
    r0 = fly(base, step_pulse(base), 0.6)
    lag = wing(Effects(sensor_tau_s=0.05))
    r1 = fly(lag, step_pulse(lag), 0.6)
    np.testing.assert_array_equal(r1["w_true"], r0["w_true"])
    # the measurement is the first-order lag (tau 50 ms) of the true warp, exactly
    a = np.exp(-H / 0.05)
    y = np.empty_like(r1["w_true"])
    prev = y[0] = r1["w_meas"][0]
    for k in range(1, y.size):
        prev = a * prev + (1 - a) * r1["w_true"][k]
        y[k] = prev
    np.testing.assert_allclose(r1["w_meas"], y, atol=0.002)
    assert np.max(np.abs(r1["w_meas"] - r1["w_true"])) > 1.0  # and it visibly lags the step


def test_drift_ramps_the_measured_zero():
    base = wing()
    r0 = fly(base, sine_pulse(base), 2.0)
    dr = wing(Effects(drift_deg_s=0.2))
    r1 = fly(dr, sine_pulse(dr), 2.0)
    np.testing.assert_array_equal(r1["w_true"], r0["w_true"])
    np.testing.assert_allclose(r1["w_meas"] - r1["w_true"], 0.2 * r1["t"], atol=1e-9)


def test_aero_load_loses_warp_growing_with_airspeed():
    eff = Effects(aero_gain_per_kpa=0.5, aero_deg_per_kpa=1.0)
    base = wing()
    p_hold = base.pulse_us + 50.0
    w_still = fly(base, lambda t: p_hold, 0.3)["w_true"][-1]
    loss = {}
    for v in (0.0, 7.0, 12.0):
        w = wing(eff, airspeed=v)
        loss[v] = w_still - fly(w, lambda t: p_hold, 0.3)["w_true"][-1]
    assert loss[0.0] == pytest.approx(0.0, abs=1e-9)
    assert 0 < loss[7.0] < loss[12.0]
    assert loss[12.0] / loss[7.0] == pytest.approx((12.0 / 7.0) ** 2, rel=0.01)  # dynamic pressure


@pytest.mark.parametrize(("rate_mm_s", "deadband_us"), [(np.inf, 0.0), (60.0, 0.0), (np.inf, 2.0), (60.0, 4.0)])
def test_the_models_servo_is_the_simulated_servo_fed_the_same_held_commands(rate_mm_s, deadband_us):
    """``effects.servo_follow`` (what identify puts in front of the model) against the SITL's servo stepped in
    0.1 ms substeps with no quantum: each row's command held until the next, the travel read at each row
    before its command is set, a correction within half the dead band not made."""
    import math

    from warpbridge.model.effects import servo_follow
    from warpbridge.sitl.servo_model import ServoModel, ServoSpec

    speed = 1e6 if math.isinf(rate_mm_s) else rate_mm_s  # mm/s: no cap the commands reach
    base = ServoSpec(deadband_us=0.0, quantum_us=0.0, tau_s=0.02)
    spec = ServoSpec(deadband_us=deadband_us, quantum_us=0.0, tau_s=0.02,
                     s_per_60deg=60.0 / (speed / base.mm_per_us) / base.deg_per_us)
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.008, 0.012, 400))  # a 100 Hz loop's uneven cycles
    u = np.repeat(rng.uniform(1.0, 8.0, 40), 10) + 0.05 * rng.standard_normal(400)  # steps and jitter
    servo = ServoModel(spec, t0=t[0], pulse0_us=spec.pulse_of(u[0]))
    truth = [servo.mm]
    for k in range(1, t.size):
        for tk in np.linspace(t[k - 1], t[k], 101)[1:]:
            servo.step(tk, spec.pulse_of(u[k - 1]))
        truth.append(servo.mm)
    band = deadband_us * spec.mm_per_us
    x = servo_follow(t, u, 0.02, rate_mm_s, float(u[0]), band)
    assert np.max(np.abs(x - np.array(truth))) < 0.01  # mm, against jumps of up to 7 mm
    if band > 0:  # the band is seen: without it the model's servo is off by up to half of it after each step
        plain = servo_follow(t, u, 0.02, rate_mm_s, float(u[0]))
        assert np.max(np.abs(plain - np.array(truth))) > 0.4 * band
        assert np.sqrt(np.mean((x - np.array(truth)) ** 2)) < 0.2 * np.sqrt(np.mean((plain - np.array(truth)) ** 2))
    if math.isfinite(rate_mm_s):
        assert np.max(np.abs(np.diff(x)) / np.diff(t)) <= rate_mm_s * (1 + 1e-9)


@pytest.mark.parametrize(("rate_mm_s", "deadband_us"), [(np.inf, 0.0), (60.0, 2.0)])
def test_the_models_servo_holds_the_row_befores_command_until_the_logged_send(rate_mm_s, deadband_us):
    """``effects.servo_travel`` with the cycle log's send times against the SITL's servo stepped in 0.05 ms
    substeps, each row's command set ``sent`` after the row's read (0-4 ms, as a loaded loop's writes); without
    them the model's servo is off by what the servo moves in that time."""
    import math

    from warpbridge.model.effects import servo_travel
    from warpbridge.sitl.servo_model import ServoModel, ServoSpec

    speed = 1e6 if math.isinf(rate_mm_s) else rate_mm_s
    base = ServoSpec(deadband_us=0.0, quantum_us=0.0, tau_s=0.02)
    spec = ServoSpec(deadband_us=deadband_us, quantum_us=0.0, tau_s=0.02,
                     s_per_60deg=60.0 / (speed / base.mm_per_us) / base.deg_per_us)
    rng = np.random.default_rng(5)
    t = np.cumsum(rng.uniform(0.008, 0.012, 300))
    u = 4.5 + 2.5 * np.sin(2 * np.pi * 2.0 * (t - t[0])) + 0.05 * rng.standard_normal(t.size)  # fast motion
    sent = rng.uniform(0.0, 0.004, t.size)
    servo = ServoModel(spec, t0=t[0], pulse0_us=spec.pulse_of(u[0]))
    truth = [servo.mm]
    for k in range(1, t.size):
        for tk in np.linspace(t[k - 1], t[k - 1] + sent[k - 1], 41)[1:]:  # the row before's command still holds
            servo.step(tk, spec.pulse_of(u[k - 2] if k > 1 else u[0]))
        for tk in np.linspace(t[k - 1] + sent[k - 1], t[k], 201)[1:]:
            servo.step(tk, spec.pulse_of(u[k - 1]))
        truth.append(servo.mm)
    truth = np.array(truth)
    band = deadband_us * spec.mm_per_us
    x = servo_travel(t, u, 0.02, rate_mm_s, float(u[0]), band, sent)
    at_read = servo_travel(t, u, 0.02, rate_mm_s, float(u[0]), band)
    err, err_read = np.sqrt(np.mean((x - truth) ** 2)), np.sqrt(np.mean((at_read - truth) ** 2))
    assert np.max(np.abs(x - truth)) < 0.01  # mm
    assert err < 0.1 * err_read  # the send times are what the servo followed
