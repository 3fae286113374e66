"""The bridge in-process against a pymavlink 'FC' on loopback UDP, with the ``loop:`` servo backend."""

from __future__ import annotations

import csv
import threading
import time
from pathlib import Path

import pytest
from helpers import free_udp_port

from warpbridge.bridge.app import run_bridge
from warpbridge.bridge.config import load_config
from warpbridge.bridge.mavlink_env import mavlink, mavutil
from warpbridge.hw.loop import LoopBackend


def write_config(tmp_path: Path, port: int) -> Path:
    p = tmp_path / "wb.toml"
    p.write_text(f"""
[link]
connection = "udpin:127.0.0.1:{port}"
servo_rate_hz = 50
[loop]
rate_hz = 50
failsafe_timeout_s = 0.3
log = "run-{{time}}.csv"
[params]
file = "params.json"
[servo]
backend = "loop:"
[sensor]
backend = "none"
[model]
file = "paper"
[wing.left]
source_channel = 1
servo_channel = 0
bias_deg = 2.0
max_warp_deg = 8.0
[wing.right]
source_channel = 1
reverse = true
servo_channel = 1
bias_deg = 2.0
max_warp_deg = 8.0
""")
    return p


class FakeFc:
    """An ArduPilot-like FC: heartbeats and SERVO_OUTPUT_RAW with a given aileron PWM on output 1."""

    def __init__(self, port: int) -> None:
        self.mav = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1)
        self.texts: list[str] = []
        self._hb = 0.0
        self.armed = True

    def send(self, aileron_us: int | None) -> None:
        now = time.monotonic()
        if now - self._hb > 0.2:
            self._hb = now
            self.mav.mav.heartbeat_send(mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                        mavlink.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0, 0,
                                        mavlink.MAV_STATE_ACTIVE)
        if aileron_us is not None:
            self.mav.mav.servo_output_raw_send(int(now * 1e6) & 0xFFFFFFFF, 0, aileron_us, 1500, 1100, 1500,
                                               0, 0, 0, 0)
        while (m := self.mav.recv_match(blocking=False)) is not None:
            if m.get_type() == "STATUSTEXT":
                self.texts.append(m.text)

    def run_until(self, aileron_us: int, done, limit_s: float = 120.0) -> None:
        """Stream until ``done()`` (the bridge's start-up takes longer on a busy machine)."""
        end = time.monotonic() + limit_s
        while not done() and time.monotonic() < end:
            self.send(aileron_us)
            time.sleep(0.02)
        assert done()

    def run(self, aileron_us: int | None, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.send(aileron_us)
            time.sleep(0.02)


def following(tmp_path: Path) -> bool:
    """Whether the bridge's cycle log (flushed every half second) shows it following the FC."""
    logs = list(tmp_path.glob("run-*.csv"))
    return bool(logs) and any(",ff," in line for line in logs[0].read_text().splitlines())


def read_log(tmp_path: Path) -> list[dict[str, str]]:
    logs = list(tmp_path.glob("run-*.csv"))
    assert len(logs) == 1
    with open(logs[0]) as f:
        return list(csv.DictReader(f))


def test_pulses_follow_aileron_failsafe_neutralises_and_recovers(tmp_path):
    port = free_udp_port()
    config = load_config(write_config(tmp_path, port))
    servo = LoopBackend()
    stop = threading.Event()
    result = {}
    bridge = threading.Thread(target=lambda: result.update(r=run_bridge(config, stop_event=stop, servo=servo)))
    bridge.start()
    try:
        fc = FakeFc(port)
        fc.run_until(1500, lambda: following(tmp_path))
        fc.run(1500, 0.8)  # neutral
        fc.run(1800, 0.8)  # roll right: left wing gains lift
        fc.run(None, 0.8)  # FC silent (heartbeats only): failsafe
        fc.run(1300, 0.8)  # back, roll left
    finally:
        stop.set()
        bridge.join(10)
    assert not bridge.is_alive()
    rows = read_log(tmp_path)
    assert result["r"].cycles == len(rows)  # a clean stop loses no row
    # each wing's command left within its cycle: after the read, before the next cycle's
    t = [float(r["t"]) for r in rows]
    for w in ("left", "right"):
        sent = [float(r[f"{w}_u_sent"]) for r in rows]
        assert all(s >= 0 for s in sent)
        assert all(s <= b - a for s, a, b in zip(sent, t, t[1:], strict=False))
    phase = []  # the sequence of distinct (mode, left setpoint, right setpoint)
    for r in rows:
        key = (r["mode"], r["left_setpoint"], r["right_setpoint"])
        if not phase or phase[-1] != key:
            phase.append(key)
    # neutral -> roll right -> failsafe at bias -> roll left, in this order
    want = [("ff", "2", "2"), ("ff", "6.5", "0.5"), ("failsafe", "2", "2"), ("ff", "1", "5")]  # no sensor: ff
    steps = [k for k in phase if k[0] == "failsafe" or k in want]
    compact = [k for i, k in enumerate(steps) if i == 0 or steps[i - 1] != k]
    assert [k for k in compact if k in want][-3:] == want[1:]
    assert want[0] in compact or compact[0][0] == "failsafe"  # may start in failsafe until the first message

    by_phase = {k: [r for r in rows if (r["mode"], r["left_setpoint"], r["right_setpoint"]) == k] for k in want}
    left_pulse = {k: float(v[-1]["left_pulse"]) for k, v in by_phase.items() if v}
    right_pulse = {k: float(v[-1]["right_pulse"]) for k, v in by_phase.items() if v}
    # more warp needs more tendon: the pulses order like the setpoints (mm_per_us > 0)
    assert left_pulse[want[1]] > left_pulse[want[2]] > left_pulse[want[3]]
    assert right_pulse[want[3]] > right_pulse[want[2]] > right_pulse[want[1]]
    # what the servo got is what the log says
    assert servo.pulse(0) == pytest.approx(float(rows[-1]["left_pulse"]))
    assert servo.pulse(1) == pytest.approx(float(rows[-1]["right_pulse"]))
    assert {ch for _, ch, _ in servo.history} == {0, 1}
    assert any("failsafe" in t for t in fc.texts)
    assert result["r"].failsafe_entries >= 1


def bridge_rows_have_neutral(tmp_path: Path) -> bool:
    rows = read_log(tmp_path)
    return rows[-1]["mode"] != "failsafe" and rows[-1]["left_setpoint"] == "2"


def test_servo_loss_does_not_stop_the_loop(tmp_path):
    port = free_udp_port()
    config = load_config(write_config(tmp_path, port))
    servo = LoopBackend()
    stop = threading.Event()
    result = {}
    t = threading.Thread(target=lambda: result.update(r=run_bridge(config, stop_event=stop, servo=servo)))
    t.start()
    try:
        fc = FakeFc(port)
        fc.run(1800, 0.8)
        servo.broken = True  # USB unplugged
        fc.run(1800, 0.5)
        n_before = len(servo.history)
        servo.broken = False  # plugged back in: the back-off retry reopens it
        fc.run(1500, 1.5)
    finally:
        stop.set()
        t.join(10)
    assert result["r"].cycles > 10
    assert servo.reopen_count >= 1
    assert len(servo.history) > n_before  # driving again after the reopen
    assert bridge_rows_have_neutral(tmp_path)
    assert any("servo lost" in x for x in fc.texts)


def test_a_disarmed_output_below_its_range_holds_the_wings_neutral(tmp_path):
    """PX4 sends its disarmed value (900 us) on every output until it arms: not full aileron. A disarmed FC
    whose aileron moves within its range (ArduPilot, PX4 with COM_PREARM_MODE 2) is followed; armed, a low
    output is a command again."""
    port = free_udp_port()
    config = load_config(write_config(tmp_path, port))
    stop = threading.Event()
    bridge = threading.Thread(target=lambda: run_bridge(config, stop_event=stop, servo=LoopBackend()))
    bridge.start()
    try:
        fc = FakeFc(port)
        fc.armed = False
        fc.run_until(900, lambda: following(tmp_path))
        fc.run(900, 0.8)
        fc.run(1800, 0.8)  # disarmed, surfaces live: followed
        fc.run(900, 0.8)
        fc.armed = True
        fc.run(900, 1.2)  # armed: full left aileron
    finally:
        stop.set()
        bridge.join(10)
    seen = []
    for r in read_log(tmp_path):
        key = (r["mode"], r["left_setpoint"], r["right_setpoint"])
        if r["mode"] != "failsafe" and (not seen or seen[-1] != key):
            seen.append(key)
    assert seen[0] == ("ff", "2", "2")  # parked at neutral, not (0, 8)
    assert ("ff", "6.5", "0.5") in seen
    assert seen.index(("ff", "6.5", "0.5")) < seen.index(("ff", "2", "2"), 1)  # parked again after
    assert seen[-1] == ("ff", "0", "8")  # armed: the low output is a command


def test_the_start_says_when_a_wing_flies_its_calibration(tmp_path, caplog):
    """A calibration persisted beside the parameter store is what the wing flies after a restart: the start-up
    line names it, not the configured model alone."""
    import logging

    from warpbridge.bridge.calibrate import CalStore, WingCal, cal_path
    from warpbridge.model.transform import Transform

    config = load_config(write_config(tmp_path, free_udp_port()))
    with caplog.at_level(logging.INFO, logger="warpbridge.bridge.app"):
        run_bridge(config, servo=LoopBackend(), duration=0.05)
    line = next(r.getMessage() for r in caplog.records if r.getMessage().startswith("bridge running"))
    assert "calibration" not in line
    CalStore(cal_path(config.params_file)).push("left", WingCal(Transform(offset=0.5, gain=1.05)))
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="warpbridge.bridge.app"):
        run_bridge(config, servo=LoopBackend(), duration=0.05)
    line = next(r.getMessage() for r in caplog.records if r.getMessage().startswith("bridge running"))
    assert f"with the left wing's calibration from {cal_path(config.params_file)}" in line
