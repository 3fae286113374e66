"""Cycle log CSV and the fixed-rate loop timer (with an injected clock, no real sleeps)."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from warpbridge.bridge.cyclelog import COLUMNS, CycleLog
from warpbridge.bridge.loop_timer import LoopTimer


class FakeClock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        assert s > 0
        self.t += s + 0.0001  # the OS always wakes a little late


def test_cycle_log_header_rows_and_buffering(tmp_path):
    clock = FakeClock()
    log = CycleLog(tmp_path / "sub" / "log-{time}.csv", flush_s=0.5, clock=clock)
    assert "{time}" not in log.path.name and log.path.parent == tmp_path / "sub"
    wing = {"setpoint": 4.0, "ff": 3.1, "pi": 0.2, "u": 3.3, "warp": None, "pulse": 1665.0}
    for k in range(10):
        clock.t += 0.01
        log.write(k * 0.01, "ff+pi", 12.5, {"left": wing, "right": {"setpoint": 1.0}})
    assert log.pending == 10  # not yet 0.5 s: nothing written
    clock.t += 0.5
    log.write(0.6, "ff", None, {"left": wing, "right": wing})
    assert log.pending == 0 and log.rows_written == 11
    log.write(0.61, "failsafe", None, {})
    log.close()
    log.close()
    with open(log.path) as f:
        rows = list(csv.DictReader(f))
    assert tuple(rows[0]) == COLUMNS
    assert len(rows) == 12  # nothing lost on close
    assert rows[0]["left_u"] == "3.3" and rows[0]["left_warp"] == "nan" and rows[0]["right_ff"] == "nan"
    assert rows[0]["airspeed"] == "12.5" and rows[-1]["mode"] == "failsafe"
    assert float(rows[5]["t"]) == pytest.approx(0.05)


def test_loop_timer_uses_absolute_deadlines_and_does_not_drift():
    clock = FakeClock()
    timer = LoopTimer(100.0, clock=clock, sleep=clock.sleep)
    start = clock.t
    for _ in range(1000):
        clock.t += 0.003  # the work of one cycle
        assert timer.wait() == 0
    # 1000 ticks later we are at deadline 1000 (plus one wake-up latency), not 1000 latencies later
    assert clock.t == pytest.approx(start + 10.0 + 0.0001, abs=1e-6)
    s = timer.stats()
    assert s.ticks == 1000 and s.overruns == 0
    assert s.late_mean_s == pytest.approx(0.0001, abs=1e-6) and s.late_max_s < 0.0002


def test_loop_timer_skips_missed_ticks_and_counts_overruns():
    clock = FakeClock()
    timer = LoopTimer(100.0, clock=clock, sleep=clock.sleep)
    start = timer.start
    timer.wait()
    clock.t += 0.035  # a 35 ms hiccup: ticks 2..4 are missed
    skipped = timer.wait()
    assert skipped == 3 and timer.overruns == 3
    assert timer.k == 5 and clock.t == pytest.approx(start + 0.05 + 0.0001, abs=1e-9)
    clock.t += 0.012  # 2.1 ms past tick 6: late by less than a period, runs at once, nothing skipped
    assert timer.wait() == 0 and timer.k == 6
    assert timer.stats().late_max_s == pytest.approx(0.0021, abs=1e-6)


def test_loop_timer_rejects_bad_rate():
    with pytest.raises(ValueError):
        LoopTimer(0)


def test_the_send_times_go_in_the_last_columns_and_come_back_as_the_logs_u_sent(tmp_path):
    from warpbridge.bridge.commands.logfile import read_log

    clock = FakeClock()
    log = CycleLog(tmp_path / "c.csv", clock=clock)
    for k in range(60):
        sent = None if k == 7 else 0.001 * (k % 4)  # a row whose command did not go out (servo down)
        log.write(0.01 * k, "ff+pi", None, {"left": {"u": 3.0 + 0.01 * k, "warp": 4.0, "u_sent": sent},
                                            "right": {"u": 2.0, "warp": 3.0, "u_sent": 0.002}})
    log.close()
    header = log.path.read_text().splitlines()[0].split(",")
    assert header[-5:] == ["fc_t", "left_u_sent", "right_u_sent", "left_read", "right_read"]  # older ones in place
    left = read_log(log.path, wing="left")
    assert left.u_sent is not None and left.u_sent[3] == pytest.approx(0.003)
    assert left.u_sent[7] == 0.0 and any("send time" in n for n in left.notes)
    assert read_log(log.path, wing="right").u_sent == pytest.approx(0.002)
    plain = tmp_path / "plain.csv"
    plain.write_text("t,u,warp\n" + "".join(f"{0.01 * k},{3 + 0.01 * k},4\n" for k in range(60)))
    assert read_log(plain).u_sent is None  # a log without them: each command held from its row's time


def test_each_wings_rows_move_to_its_sensor_reads_and_its_send_times_with_them(tmp_path):
    from warpbridge.bridge.commands.logfile import read_log

    log = CycleLog(tmp_path / "c.csv", clock=FakeClock())
    for k in range(60):  # the right wing is read after the left wing's whole step
        log.write(0.01 * k, "ff+pi", None,
                  {"left": {"u": 3.0, "warp": 4.0, "u_sent": 0.0008, "read": 0.0002},
                   "right": {"u": 2.0, "warp": 3.0, "u_sent": 0.003, "read": None if k == 5 else 0.0021}})
    log.close()
    left, right = read_log(log.path, wing="left"), read_log(log.path, wing="right")
    k = np.arange(60)
    assert left.t == pytest.approx(0.01 * k + 0.0002) and left.read_shifted
    assert left.u_sent == pytest.approx(0.0006)  # still counted from the row's (moved) time
    assert right.t[5] == pytest.approx(0.05) and right.t[6] == pytest.approx(0.0621)  # a row without a read stays
    assert right.u_sent[6] == pytest.approx(0.0009)
    jumbled = tmp_path / "jumbled.csv"  # reads that would reorder rows: the rows keep their logged times
    jumbled.write_text("t,u,warp,read\n" + "".join(f"{0.01 * k},{3 + 0.01 * k},4,{0.02 if k == 3 else 0}\n"
                                                  for k in range(60)))
    data = read_log(jumbled)
    assert data.t == pytest.approx(0.01 * k) and not data.read_shifted
    assert any("out of order" in n for n in data.notes)
