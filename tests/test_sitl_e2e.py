"""End to end: ``warpbridge sitl`` over real UDP and a real pty, three processes, a few seconds."""

from __future__ import annotations

import csv
import json
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from warpbridge.bridge.commands.effects_spec import parse_effects
from warpbridge.sitl.cmd_sitl import join_reads
from warpbridge.sitl.lockstep import run_lockstep
from warpbridge.sitl.scenarios import make_scenario


@pytest.mark.slow
def test_sitl_runs_the_three_processes_and_agrees_with_lockstep(tmp_path):
    out = tmp_path / "run"
    # the default gains keep margin (benchmarks/bench_margins.py): a scheduling gap on a busy machine does not
    # set the loop ringing, which no second run would reproduce exactly
    proc = subprocess.run(
        [sys.executable, "-m", "warpbridge.bridge.cli", "sitl", "--duration", "6",
         "--out", str(out), "--no-gcs"],  # no ground-station output: nothing sent to this machine's 14550
        capture_output=True, text=True, timeout=180,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    t_from, t_to = summary["stretch_s"]
    assert t_to - t_from >= 4.0  # the bridge followed the FC over (nearly) the whole run after the ramp-in
    assert summary["cycles"] == summary["cycles_lockstep"]  # the replay ran the real-time run's cycles
    ticks, woken = cycle_kinds(out / "bridge-cycles.csv", 100.0, summary["scenario_offset_s"], t_from, t_to)
    assert ticks > 0 and woken > 0  # fixed ticks and cycles woken by the FC's messages (how many: the load's)
    open_loop, _ = run_lockstep(make_scenario("random", t_to + 0.1, hold_s=1.0), mode="open")
    open_loop.compute_rms(t_from=t_from, t_to=t_to)
    rms = summary["rms_deg"]
    rt, ls, ideal = rms["realtime"], rms["lockstep"], rms["lockstep_ideal_timing"]
    for wing in ("left", "right"):
        # The real-time chain did what the bridge's cycle does at the cycles, I/O instants and answers
        # that actually happened (however late a busy machine made them), and at the nominal timing
        # that cycle tracks: ff+pi through the whole chain, whatever else runs on the machine.
        assert rt[wing] > 0
        assert rt[wing] == pytest.approx(ls[wing], rel=0.2)
        assert ideal[wing] < 0.3 * open_loop.rms[wing]
    assert "real time" in proc.stdout and "lock-step" in proc.stdout and "agree" in proc.stdout
    assert (out / "sitl.png").stat().st_size > 10_000
    cycles = (out / "bridge-cycles.csv").read_text().splitlines()
    assert cycles[0].startswith("t,mode")
    modes = [set(row.split(",")[1].split("/")) for row in cycles[1:]]  # "ff+pi/ff": the wings differ
    # following the FC (not failsafe) at the end, on ff+pi (ff alone in a cycle whose sensor read timed out)
    assert all(m <= {"ff+pi", "ff"} for m in modes[-100:]) and any("ff+pi" in m for m in modes)
    assert "real time" in (out / "bridge.log").read_text()  # bridge.realtime said what it applied or was refused


def cycle_kinds(log: Path, loop_hz: float, tau: float, t_from: float, t_to: float) -> tuple[int, int]:
    """Cycles in the scenario stretch [t_from, t_to] of a bridge cycle log (``tau``: scenario time at
    log time 0): (fixed ticks, cycles woken by a message). The first cycle in each period is its tick."""
    with log.open() as f:
        t = np.array([float(r["t"]) for r in csv.DictReader(f)])
    k = np.floor(t * loop_hz + 1e-9)
    first = np.ones(t.size, dtype=bool)
    first[1:] = k[1:] != k[:-1]
    inside = (t + tau >= t_from) & (t + tau <= t_to)
    return int(np.count_nonzero(first & inside)), int(np.count_nonzero(~first & inside))


def test_join_reads_skips_reads_the_bridge_never_logged():
    log_t = np.array([0.0, 0.01, 0.02, 0.03])
    deg = {100: 1.0, 101: 2.0, 102: 3.0, 103: 4.0}
    logged = np.array([1.0, 2.0, np.nan, 4.0])  # the third cycle's read timed out in the bridge
    reads = [(5.0003, 100, 0, 0, 0), (5.0102, 101, 0, 0, 0), (5.0211, 102, 0, 0, 0), (5.0305, 103, 0, 0, 0)]
    idx, offset = join_reads(log_t, logged, reads, lambda c: np.vectorize(deg.get)(c))
    assert offset == pytest.approx(5.0002, abs=1e-6)
    assert idx.tolist() == [0, 1, -1, 3]


def test_effects_option_parses_names_and_parameters():
    e = parse_effects("delay=0.03, backlash=0.2,pretension=0.3:1.1,aero_deg_per_kpa=2")
    assert (e.delay_s, e.backlash_mm, e.pretension_offset_mm, e.pretension_gain) == (0.03, 0.2, 0.3, 1.1)
    assert e.aero_deg_per_kpa == 2.0
    assert set(e.active()) == {"delay", "backlash", "pretension", "aero_load"}
    from warpbridge.bridge.errors import UserError

    for bad in ("warp=1", "delay", "delay=x", "delay=-1", "backlash=1:2"):
        with pytest.raises(UserError):
            parse_effects(bad)


# ---------------------------------------------------------------------- the replay of what happened


def test_join_reads_takes_the_j_th_read_for_the_j_th_row_however_late():
    log_t = np.arange(10) * 0.01
    counts = [100 + k for k in range(10)]
    reads = [(5.0 + 0.01 * k + (0.3 if k >= 4 else 0.0), c, 0, 0, 0) for k, c in enumerate(counts)]  # 0.3 s late
    logged = np.array(counts, dtype=float)
    idx, _ = join_reads(log_t, logged, reads, lambda c: np.asarray(c, dtype=float))
    assert idx.tolist() == list(range(10))
    logged[6] = 103.0  # that cycle took a late answer to an earlier query: no read of its own
    idx, _ = join_reads(log_t, logged, reads, lambda c: np.asarray(c, dtype=float))
    assert idx.tolist() == [0, 1, 2, 3, 4, 5, -1, 7, 8, 9]


def test_row_reads_place_the_reads_the_bridge_got_no_answer_to():
    from warpbridge.sitl.cmd_sitl import row_reads

    # rows 1, 2 and 4 got no answer; the rig took 4 reads: row 1's (timed out) and row 4's
    answered = np.array([0, -1, -1, 2, -1])
    no_targets = np.zeros(0)
    assert row_reads(answered, np.zeros(4), no_targets).tolist() == [0, 1, -1, 2, 3]
    assert row_reads(np.array([-1, 0, -1]), np.zeros(1), no_targets).tolist() == [-1, 0, -1]
    # with a target per row, the read between the targets of rows j - 1 and j is row j's, however late:
    # row 1's read came after row 0's target (0.10 s) and before its own (0.50 s)
    targets = np.array([0.10, 0.50, 0.52, 0.60, 0.70])
    reads = np.array([0.05, 0.45, 0.59, 0.65])
    assert row_reads(answered, reads, targets).tolist() == [0, 1, -1, 2, 3]
    assert row_reads(answered, np.array([0.05, 0.51, 0.59, 0.65]), targets).tolist() == [0, -1, 1, 2, 3]
    # the rig stopped before handling the last row's bytes: its read and target never happened
    assert row_reads(answered, reads[:3], targets[:4]).tolist() == [0, 1, -1, 2, -1]


def test_board_answers_and_fc_pwm_replay_what_the_bridge_got():
    from warpbridge.sitl.cmd_sitl import board_answers, fc_pwm_of
    from warpbridge.sitl.scenarios import Rig

    logged = {"left": np.array([5.0, np.nan, 7.0]), "right": np.array([1.0, 2.0, 3.0])}
    idx = {"left": np.array([0, -1, -1]), "right": np.array([0, 1, 2])}
    ans = board_answers(logged, idx, lambda d: 100.0 + 30.0 * np.asarray(d))
    assert ans[0] == (None, None) and ans[2] == (310.0, None)  # 7 deg: someone else's answer, 310 counts
    assert np.isnan(ans[1][0]) and ans[1][1] is None  # no answer in time
    rig = Rig()  # bias 6 deg, 12 deg at full aileron, PWM 1100 / 1500 / 1900
    assert (rig.bias_deg, rig.max_warp_deg, rig.pwm_min, rig.pwm_trim, rig.pwm_max) == (6, 12, 1100, 1500, 1900)
    sp = np.array([6.0, 12.0, 9.0, 3.0, 0.0, 9.0])
    pwm = fc_pwm_of(sp, np.array([True] * 5 + [False]), rig)
    assert pwm[:5] == (1500.0, 1900.0, 1700.0, 1300.0, 1100.0) and np.isnan(pwm[5])


def test_a_replay_feeds_the_bridge_the_fc_pwm_and_the_answers_it_had():
    from warpbridge.sitl.lockstep import Schedule

    sc = make_scenario("random", 1.0, seed=0)
    times = tuple(0.2 + 0.01 * k for k in range(50))
    answers = tuple((None, None) if k < 25 else (float("nan"), None) for k in range(50))
    sched = Schedule(cycle_times=times, fc_pwm=(1700.0,) * 50, answers=answers)
    res, _ = run_lockstep(sc, schedule=sched, mode="ff+pi")
    fly = res.flying
    # the mix of 1700 us on the rig: left 6 + 0.5 * 6 = 9 deg, right (reversed) 6 * (1 - 0.5) = 3 deg
    assert fly[-1] and np.allclose(res.setpoint["left"][fly], 9.0) and np.allclose(res.setpoint["right"][fly], 3.0)
    late = res.t >= 0.2 + 0.01 * 25 - 1e-9
    assert np.isfinite(res.measured["left"][~late]).all() and np.isnan(res.measured["left"][late]).all()
    assert np.isnan(res.warp["left"][late]).all()  # no read of its own: left out of the RMS, as in real time
    assert np.isfinite(res.measured["right"]).all()


def test_a_replayed_sensor_draws_the_noise_of_the_reads_it_does_not_make():
    from warpbridge.sitl.flex_sensor import FlexSensor, FlexSensorSpec

    a, b = FlexSensor(FlexSensorSpec(), seed=3), FlexSensor(FlexSensorSpec(), seed=3)
    run = [a.read(5.0) for _ in range(200)]
    assert len(set(run)) > 2  # noisy
    replay = [b.read(5.0) for _ in range(100)]
    b.skip(50)
    replay += [None] * 50 + [b.read(5.0) for _ in range(50)]
    assert replay[:100] == run[:100] and replay[150:] == run[150:]


def test_a_wing_on_a_sub_step_grid_integrates_the_same_however_often_it_is_advanced():
    """The real-time rig keeps its wings current between the bridge's calls, its replay does not."""
    from warpbridge.sitl.lockstep import make_wings
    from warpbridge.sitl.wing import WingSpec

    sc = make_scenario("random", 3.0, seed=0)
    often, seldom = (make_wings(sc, WingSpec(), w0_deg=6.0, grid=True, flow_shift_s=0.0123)["left"]
                     for _ in range(2))
    rng = np.random.default_rng(0)
    for t, pulse in zip(np.sort(rng.uniform(0.0, 2.0, 200)), rng.uniform(1200.0, 1600.0, 200), strict=True):
        for g in np.arange(often.t, t, 0.0007):  # in between, at times of its own (to the grid point before)
            often.advance(-0.0123 + 0.001 * np.floor((g + 0.0123) / 0.001))
        for wing in (often, seldom):
            wing.advance(t)
            wing.set_pulse(pulse)
    assert often.w_true == pytest.approx(seldom.w_true, abs=1e-12) and often.u_mm == pytest.approx(seldom.u_mm)
    assert seldom.w_true != pytest.approx(6.0, abs=0.5)  # it moved


@pytest.mark.slow
def test_ctrl_c_stops_the_run_and_compares_the_part_flown(tmp_path):
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "warpbridge.bridge.cli", "sitl", "--duration", "120", "--out", str(out), "--no-gcs",
         "--no-plot"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        for line in proc.stdout:  # "sitl: 5 / 121 s" once five seconds of the scenario are flown
            if line.startswith("sitl: 5 /"):
                break
        proc.send_signal(signal.SIGINT)
        rest, err = proc.communicate(timeout=180)
    finally:
        proc.kill()
    assert proc.returncode == 130, rest + err
    assert "stopped after" in rest and "real time vs lock-step" in rest, rest + err
    summary = json.loads((out / "summary.json").read_text())
    t_from, t_to = summary["stretch_s"]
    assert 5.0 <= summary["stopped_after_s"] < 60.0
    assert 2.0 <= t_to - t_from and t_to < 60.0  # the part flown, not the 121 s asked for
    assert summary["rms_deg"]["realtime"]["left"] == pytest.approx(summary["rms_deg"]["lockstep"]["left"], rel=0.2)
    assert "warpbridge.bridge.app" not in err  # the replays' simulated bridges keep quiet
