"""Lock-step SITL: scenarios, the mode ordering of the paper, gust robustness, determinism."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from warpbridge.sitl.lockstep import rig_config, run_lockstep
from warpbridge.sitl.mock_autopilot import CsvRoll
from warpbridge.sitl.scenarios import SCENARIO_NAMES, Rig, make_scenario

DURATION = 8.0


@pytest.fixture(scope="module")
def calm():
    sc = make_scenario("random", DURATION, seed=0)
    return {m: run_lockstep(sc, mode=m)[0].rms for m in ("open", "pi", "ff", "ff+pi")}


def test_random_reference_spans_four_degrees_about_the_bias():
    sc = make_scenario("random", 30.0, seed=2)
    t = np.arange(0, 30.0, 0.01)
    ref = sc.reference(t)
    for wing in ("left", "right"):
        dev = ref[wing] - Rig().bias_deg
        assert np.max(np.abs(dev)) == pytest.approx(4.0, abs=0.05)
    np.testing.assert_allclose(ref["left"] - 6.0, 6.0 - ref["right"], atol=1e-9)  # one aileron, mirrored


@pytest.mark.parametrize("name", SCENARIO_NAMES)
def test_every_scenario_builds_within_the_pwm_range(name, tmp_path):
    sc = make_scenario(name, 5.0)
    pwm = sc.pwm(np.linspace(0, 5.0, 1001))
    assert np.all((pwm >= 1100) & (pwm <= 1900)) and np.ptp(pwm) > 50
    roll = CsvRoll(sc.write_csv(tmp_path / "roll.csv"))  # the mock autopilot reads it back
    assert roll(2.5)[1] == pytest.approx(sc.pwm_at(2.5)[1], abs=2.0)
    assert roll.airspeed(1.0) == sc.airspeed_ms
    assert (sc.gust is not None) == name.startswith("gust")


def test_feed_forward_and_pi_beat_open_loop_on_the_paper_plant(calm):
    # the controller knows this plant exactly (an upper bound): feed-forward + PI far ahead, as on the
    # paper's bench (0.285 deg against 1.727 open loop)
    mean = {m: 0.5 * (r["left"] + r["right"]) for m, r in calm.items()}
    assert mean["ff+pi"] <= 0.15  # the target on the paper's plant and reference
    assert mean["ff+pi"] < mean["ff"] < mean["open"] and mean["ff+pi"] < mean["pi"] < mean["open"]
    assert mean["open"] > 5 * mean["ff+pi"] and mean["open"] > 0.5


def test_named_gain_sets_in_mm_per_degree():
    rig = Rig()  # a 10 mm horn
    # the paper's Kp = 7, Ki = 1 as degrees of horn: 7 deg of a 10 mm horn is an arc of 1.2217 mm
    # (7 * 10 * 3.14159265 / 180, by hand), 1 deg of it 0.17453 mm
    assert rig.gains("paper-horn") == pytest.approx((1.2217305, 0.1745329), abs=1e-7)
    assert rig.gains("paper-mm") == (7.0, 1.0)
    assert rig.gains("default") == (0.5, 10.0)
    with pytest.raises(ValueError, match="gain set"):
        rig.gains("horn")
    cfg = rig_config(rig, "pi")  # no gains given: the bridge's defaults
    assert (cfg.wings["left"].control.kp, cfg.wings["right"].control.ki) == (0.5, 10.0)
    cfg = rig_config(rig, "pi", 1.25, 0.5)
    assert (cfg.wings["right"].control.kp, cfg.wings["left"].control.ki) == (1.25, 0.5)


def test_gusts_leave_ff_pi_controllable_while_open_loop_degrades(calm):
    sc = make_scenario("gust12", DURATION, seed=0)
    gust = {m: run_lockstep(sc, mode=m)[0].rms for m in ("open", "ff+pi")}
    for wing in ("left", "right"):
        assert gust["ff+pi"][wing] <= 2.0 * calm["ff+pi"][wing]
        assert gust["open"][wing] > calm["open"][wing] + 0.1


def test_lockstep_is_deterministic_and_uses_the_configured_gains():
    sc = make_scenario("doublet", 4.0, seed=1)
    a, _ = run_lockstep(sc, mode="ff+pi", seed=3)
    b, _ = run_lockstep(sc, mode="ff+pi", seed=3)
    np.testing.assert_array_equal(a.warp["left"], b.warp["left"])
    soft, _ = run_lockstep(sc, mode="pi", config=rig_config(sc.rig, "pi", kp=0.2, ki=0.5), seed=3)
    hard, _ = run_lockstep(sc, mode="pi", config=rig_config(sc.rig, "pi", kp=2.0, ki=5.0), seed=3)
    assert soft.rms["left"] > 2 * hard.rms["left"]  # a soft PI alone cannot follow doublets


def test_a_wing_unlike_the_model_is_worse_in_feed_forward_only():
    from warpbridge.model.effects import Effects
    from warpbridge.sitl.wing import WingSpec

    sc = make_scenario("random", 6.0)
    nominal, _ = run_lockstep(sc, mode="ff")
    changed, _ = run_lockstep(sc, mode="ff", spec=WingSpec().with_effects(Effects(backlash_mm=0.4)))
    assert changed.rms["left"] > nominal.rms["left"] + 0.05


def test_lockstep_runs_the_bridge_cycle_on_ticks_and_on_each_servo_message():
    from warpbridge.sitl.lockstep import Schedule

    sc = make_scenario("random", 3.0, seed=0)
    woken, _ = run_lockstep(sc)
    ticks_only, _ = run_lockstep(sc, schedule=Schedule(wake_on_message=False))
    assert woken.t.size == pytest.approx(2 * ticks_only.t.size, rel=0.02)  # 100 Hz ticks + 100 Hz messages
    assert np.all(np.diff(ticks_only.t) == pytest.approx(0.01))
    assert np.all(woken.flying[woken.t > 0.01]) and not woken.flying[0]  # failsafe until the first message


def test_lockstep_replays_given_cycle_times():
    from warpbridge.sitl.lockstep import Schedule

    sc = make_scenario("random", 2.0, seed=0)
    times = tuple(np.cumsum(np.r_[0.0, np.full(150, 0.01), 0.03, np.full(30, 0.004)]))  # with a 30 ms gap
    res, _ = run_lockstep(sc, schedule=Schedule(cycle_times=times))
    np.testing.assert_allclose(res.t, times)


def test_a_neutral_hold_puts_the_scenario_off_without_a_step():
    sc = make_scenario("random", 6.0, seed=0, hold_s=1.0)
    plain = make_scenario("random", 5.0, seed=0)
    t = np.arange(0.0, 6.0, 0.005)
    a = sc.aileron(t)
    assert np.all(a[t <= 1.0] == 0.0)
    start = (t > 0.9) & (t < 1.2)
    assert np.max(np.abs(np.diff(a[start]))) < 1e-3  # starts from neutral smoothly (a ramp, not a step)
    np.testing.assert_allclose(sc.aileron(t[t >= 1.0]), plain.aileron(t[t >= 1.0] - 1.0), atol=1e-9)


def test_compare_scores_each_window_over_each_seed():
    from warpbridge.sitl.lockstep import compare

    rows = compare(("random",), ("open", "ff+pi"), duration_s=4.0, windows=((1.0, 4.0), (2.5, 4.0)), seeds=(0, 1))
    assert [(r.window, r.mode) for r in rows] == [((1.0, 4.0), "open"), ((1.0, 4.0), "ff+pi"),
                                                 ((2.5, 4.0), "open"), ((2.5, 4.0), "ff+pi")]
    assert all(len(r.rms) == 2 and r.rms[0] != r.rms[1] for r in rows)  # two seeds: two references
    assert rows[0].paper == 1.727 and rows[1].paper == 0.285  # the paper's bench figures beside them
    for o, f in ((rows[0], rows[1]), (rows[2], rows[3])):
        assert all(b < 0.5 * a for a, b in zip(o.rms, f.rms, strict=True))
    assert rows[0].rms_min <= rows[0].rms_mean <= rows[0].rms_max


def test_the_lockstep_runs_bridges_log_errors_only_unless_verbose(caplog):
    """A dozen simulated bridges starting up (the failsafe before the FC's first output, the output check) would
    bury the lock-step table: while the runs go, the bridge's loggers pass errors only; the runs' own progress
    passes, and -v (debug on the root logger) passes everything."""
    from warpbridge.sitl.cmd_sitl import simulated_bridges_quiet

    bridge, sitl = logging.getLogger("warpbridge.bridge.telemetry"), logging.getLogger("warpbridge.sitl.lockstep")
    root = logging.getLogger()
    with caplog.at_level(logging.INFO):
        with simulated_bridges_quiet():
            bridge.warning("WB failsafe: no servo outputs yet")
            bridge.error("WB servo lost")
            sitl.info("random open seed 0: RMS 1.3 deg")
        bridge.warning("after the runs")
    assert [r.getMessage() for r in caplog.records] == ["WB servo lost", "random open seed 0: RMS 1.3 deg",
                                                        "after the runs"]
    caplog.clear()
    level = root.level
    root.setLevel(logging.DEBUG)
    try:
        with simulated_bridges_quiet():
            bridge.warning("verbose: kept")
    finally:
        root.setLevel(level)
    assert [r.getMessage() for r in caplog.records] == ["verbose: kept"]


def test_parameters_set_in_a_run_are_told_from_the_adaptations_own(tmp_path):
    """The real-time run's table is compared with a lock-step replay of the configuration: a parameter set from a
    ground station (or a calibration) makes them unlike, the adaptation's own estimates do not."""
    import json

    from warpbridge.sitl.cmd_sitl import params_set_in_run

    path = tmp_path / "params.json"
    assert params_set_in_run(path) == []
    estimates = {"WB_ADL_GAIN": 0.99, "WB_ADL_OFF": -0.03, "WB_ADR_GAIN": 0.99, "WB_ADR_OFF": -0.04,
                 "WB_ADR_DRFT": 0.01}
    path.write_text(json.dumps({"format": "warpbridge-params/1", "params": estimates}))
    assert params_set_in_run(path) == []
    path.write_text(json.dumps({"format": "warpbridge-params/1",
                                "params": estimates | {"WB_KP": 0.7, "WB_CAL_SEC": 10.0}}))
    assert params_set_in_run(path) == ["WB_CAL_SEC", "WB_KP"]
