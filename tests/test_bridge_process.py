"""The bridge as a process, as it flies: ``warpbridge run --config ...`` in a subprocess.

The flight controller is the mock autopilot (pymavlink on loopback UDP, ArduPilot-like,
routing like ArduPilot), the ground station a pymavlink peer on the mock's GCS port,
and the tendon servos plus flex sensors a Maestro emulator on a real pty, so the bytes
the bridge writes go through pyserial exactly as to ``/dev/ttyACM0``. The helpers here
(``Rig``, ``Gcs``) are shared with the MAVProxy and MAVSDK tests.
"""

from __future__ import annotations

import csv
import math
import os
import random
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import helpers
import pytest
from helpers import free_udp_port, run_to_end, wait_while_working

from warpbridge.bridge.mavlink_env import mavlink, mavutil
from warpbridge.sitl.maestro_emu import MaestroEmulator
from warpbridge.sitl.mock_autopilot import MockAutopilot

PULSE_ZERO, MM_PER_US = 1200.0, 0.02
COUNTS, DEG = (100.0, 1000.0), (0.0, 15.0)
SENSOR_CH = {"left": 2, "right": 3}
SERVO_CH = {"left": 0, "right": 1}
LOOP_HZ = 100.0  # [loop] rate_hz of config_text
EMULATED_BOARD_TIMEOUT_S = 0.5  # how long the bridge waits for the Maestro emulator's answer
REPO = Path(__file__).resolve().parents[1]


def wait_for(cond: Callable[[], Any], timeout: float = 10.0, step: float = 0.02) -> Any:
    return helpers.wait_for(cond, timeout, step)


def counts_for_deg(w: float) -> float:
    return COUNTS[0] + (w - DEG[0]) * (COUNTS[1] - COUNTS[0]) / (DEG[1] - DEG[0])


def warpbridge_command() -> list[str]:
    """The installed console script next to this interpreter, else the module."""
    script = Path(sys.executable).with_name("warpbridge")
    return [str(script)] if script.exists() else [sys.executable, "-m", "warpbridge.bridge.cli"]


def config_text(fc_port: int, maestro: Path, *, mode: str = "ff+pi", kp: float = 7.0, ki: float = 1.0,
                jitter_us: float = 2.0, servo_backend: str | None = None, sensor_backend: str = "maestro:",
                failsafe_s: float = 0.3, frozen_s: float = 0.4) -> str:
    # the emulated board answers once this test process gets the CPU, which on a busy machine takes far
    # longer than a real board's millisecond: the driver waits for it instead of running without a reading
    servo_backend = servo_backend or f"maestro:{maestro},timeout={EMULATED_BOARD_TIMEOUT_S:g}"
    wings = []
    for name in ("left", "right"):
        wings.append(f"""
[wing.{name}]
source_channel = 1
reverse = {"true" if name == "right" else "false"}
pwm_min = 1100
pwm_trim = 1500
pwm_max = 1900
max_warp_deg = 8.0
bias_deg = 2.0
servo_channel = {SERVO_CH[name]}
sensor_channel = {SENSOR_CH[name]}
[wing.{name}.servo]
pulse_min_us = 1000
pulse_max_us = 2000
pulse_zero_us = {PULSE_ZERO:g}
mm_per_us = {MM_PER_US:g}
[wing.{name}.sensor]
counts = [{COUNTS[0]:g}, {COUNTS[1]:g}]
deg = [{DEG[0]:g}, {DEG[1]:g}]
[wing.{name}.control]
mode = "{mode}"
kp = {kp:g}
ki = {ki:g}
""")
    return f"""
[link]
connection = "udpin:127.0.0.1:{fc_port}"
servo_rate_hz = 50
rerequest_s = 0.5
pwm_jitter_us = {jitter_us:g}
[loop]
rate_hz = 100
failsafe_timeout_s = {failsafe_s:g}
sensor_frozen_s = {frozen_s:g}
log = "run-{{time}}.csv"
[telemetry]
rate_hz = 20
[params]
file = "params.json"
[servo]
backend = "{servo_backend}"
[sensor]
backend = "{sensor_backend}"
[model]
file = "paper"
""" + "".join(wings)


class Gcs:
    """A pymavlink ground station on the mock's GCS port; collects what the bridge sends."""

    def __init__(self, port: int, sysid: int = 255) -> None:
        self.mav = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=sysid,
                                              source_component=mavlink.MAV_COMP_ID_MISSIONPLANNER)
        self.lock = threading.Lock()
        self.floats: list[tuple[float, str, float]] = []  # (time, name, value) from component 191
        self.texts: list[str] = []
        self.params: dict[str, float] = {}
        self.param_msgs: list[Any] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        next_hb = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_hb:  # the mock learns the route to us from what we send
                next_hb = now + 0.5
                self.mav.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            self.mav.select(0.05)
            while (m := self.mav.recv_msg()) is not None:
                if m.get_srcComponent() != 191:
                    continue
                t = m.get_type()
                with self.lock:
                    if t == "NAMED_VALUE_FLOAT":
                        self.floats.append((time.monotonic(), m.name, m.value))
                    elif t == "STATUSTEXT":
                        self.texts.append(m.text)
                    elif t == "PARAM_VALUE":
                        self.params[m.param_id] = m.param_value
                        self.param_msgs.append(m)

    def latest(self, name: str, since: float = 0.0) -> float | None:
        with self.lock:
            vals = [v for t, n, v in self.floats if n == name and t >= since]
        return vals[-1] if vals else None

    def values(self, name: str, since: float) -> list[float]:
        with self.lock:
            return [v for t, n, v in self.floats if n == name and t >= since]

    def has_text(self, fragment: str) -> bool:
        with self.lock:
            return any(fragment in t for t in self.texts)

    def count_text(self, fragment: str) -> int:
        with self.lock:
            return sum(fragment in t for t in self.texts)

    def param_set(self, name: str, value: float) -> None:
        self.mav.mav.param_set_send(1, 191, name.encode(), value, mavlink.MAV_PARAM_TYPE_REAL32)

    def param_read(self, name: str) -> None:
        self.mav.mav.param_request_read_send(1, 191, name.encode(), -1)

    def param_list(self) -> None:
        self.mav.mav.param_request_list_send(1, 191)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.mav.close()


class Rig:
    """Mock FC + Maestro emulator (with flex sensors) + GCS, and the bridge process."""

    def __init__(self, tmp_path: Path, **config: Any) -> None:
        self.tmp = tmp_path
        self.fc_port, self.gcs_port = free_udp_port(), free_udp_port()
        self.aileron = 1500.0  # FC output 1, us (0 = output disabled)
        self.aileron_sampled = 0.0  # when the mock last took it for a message (monotonic)
        self.sensor: dict[int, Callable[[], float | None]] = {}
        self.targets: list[tuple[float, int, float]] = []  # (time, channel, pulse us) as written
        self._tlock = threading.Lock()
        self.emu = MaestroEmulator(on_target=self._on_target, read_analog=self._analog, link=tmp_path / "maestro")
        self.emu.start()
        self.config_path = tmp_path / "wb.toml"
        self.write_config(**config)
        self.mock = MockAutopilot(self.fc_port, self.gcs_port, autopilot="ardupilot", jitter_us=0,
                                  roll_source=self._roll).start()
        self.gcs = Gcs(self.gcs_port)
        self.proc: subprocess.Popen | None = None
        self.stderr_path = tmp_path / "bridge.stderr"

    def _roll(self, t: float) -> dict[int, float]:
        self.aileron_sampled = time.monotonic()  # the mock is about to send this aileron
        return {1: self.aileron, 2: 1500.0}

    def write_config(self, **config: Any) -> None:
        self.config_path.write_text(config_text(self.fc_port, self.tmp / "maestro", **config))

    def _on_target(self, channel: int, quarter_us: int) -> None:
        with self._tlock:
            self.targets.append((time.monotonic(), channel, quarter_us / 4.0))

    def _analog(self, channel: int) -> int | None:
        fn = self.sensor.get(channel)
        if fn is None:
            return None  # a servo channel: answers its target
        v = fn()
        return None if v is None else int(round(v))

    def pulses(self, channel: int, since: float) -> list[float]:
        with self._tlock:
            return [p for t, ch, p in self.targets if ch == channel and t >= since]

    def run_for(self, seconds: float, channel: int = SERVO_CH["left"]) -> None:
        """Let the bridge run ``seconds``: that long, and at least as many control cycles as it runs in
        that time at 100 Hz (counted by its servo writes). On a busy machine the bridge's cycles come
        late and the values under test settle over cycles, not over the test's clock."""
        t0 = time.monotonic()
        time.sleep(seconds)
        assert self.proc is not None
        cycles = math.ceil(LOOP_HZ * seconds)
        assert wait_while_working(lambda: len(self.pulses(channel, t0)) >= cycles or self.proc.poll() is not None,
                                  self.proc.pid), f"{len(self.pulses(channel, t0))} of {cycles} cycles"

    def settled_pulse(self, channel: int, hold: float = 0.6) -> float:
        """The pulse written on ``channel`` after the mock has sent the current aileron and the bridge
        has then run ``hold`` seconds (``run_for``)."""
        t0 = time.monotonic()
        assert self.proc is not None
        assert wait_while_working(lambda: self.aileron_sampled > t0, self.proc.pid), "the mock sent nothing"
        t1 = time.monotonic()
        self.run_for(hold, channel)
        return self.pulses(channel, t1)[-1]

    # ------------------------------------------------------------------ the process

    def start(self, *extra: str) -> None:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
        self._stderr = open(self.stderr_path, "ab")
        t0 = time.monotonic()
        self.proc = subprocess.Popen([*warpbridge_command(), "run", "--config", str(self.config_path), *extra],
                                     cwd=self.tmp, env=env, stdout=subprocess.DEVNULL, stderr=self._stderr)
        # start-up (imports, compiled kernels) takes longer on a busy machine: wait while the process works
        assert wait_while_working(lambda: self.gcs.latest("WB_mode", t0) is not None or self.proc.poll() is not None,
                                  self.proc.pid)
        assert self.proc.poll() is None, self.stderr()

    def stop(self) -> int:
        assert self.proc is not None
        self.proc.send_signal(signal.SIGTERM)
        try:
            rc = self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            rc = self.proc.wait(5)
        self._stderr.close()
        self.proc = None
        return rc

    def cycle_rows(self) -> list[dict[str, str]]:
        """The rows of the bridge's cycle log written so far (it is flushed every half second)."""
        logs = sorted(self.tmp.glob("run-*.csv"))
        if not logs:
            return []
        text = logs[-1].read_text()
        lines = text.splitlines()[: None if text.endswith("\n") else -1]  # not a row being written
        return [r for r in csv.DictReader(lines) if r.get("left_pulse")]

    def stderr(self) -> str:
        return self.stderr_path.read_text(errors="replace") if self.stderr_path.exists() else ""

    def close(self) -> None:
        if self.proc is not None:
            self.stop()
        self.gcs.close()
        self.mock.stop()
        self.emu.stop()


@pytest.fixture
def make_rig(tmp_path):
    rigs: list[Rig] = []

    def make(**config: Any) -> Rig:
        rig = Rig(tmp_path, **config)
        rigs.append(rig)
        return rig

    yield make
    for rig in rigs:
        rig.close()
    for rig in rigs:
        assert "Traceback" not in rig.stderr(), rig.stderr()


def open_loop_pulse(setpoint: float) -> float:
    """What ``open`` mode must write for a setpoint (no play): the model's line, then the calibration. The
    line through the paper model's settled loop over 0..8 deg, u = 0.58019 w + 0.92153 mm, comes from an
    independent plain integration of the model (``test_controller.plain_inverse``), not ``straight_line``."""
    pulse = PULSE_ZERO + (0.58019 * setpoint + 0.92153) / MM_PER_US
    return round(min(2000.0, max(1000.0, pulse)) * 4) / 4


def noisy(deg: float) -> Callable[[], float]:
    """A live flex sensor at ``deg``: +-1 count of noise."""
    base = counts_for_deg(deg)
    rng = random.Random(1)
    return lambda: base + rng.choice((-1, 0, 1))


# ---------------------------------------------------------------------- tests


def test_aileron_sweep_reaches_the_servo_bytes_with_the_right_pulses(make_rig):
    rig = make_rig(mode="open", jitter_us=0)
    rig.start()
    # aileron us -> (left setpoint, right setpoint): right wing reversed, bias 2, max 8, trim 1500 +-400
    for aileron, left_sp, right_sp in [(1500, 2.0, 2.0), (1900, 8.0, 0.0), (1700, 5.0, 1.0),
                                       (1300, 1.0, 5.0), (1100, 0.0, 8.0)]:
        rig.aileron = aileron
        t0 = time.monotonic()
        left = rig.settled_pulse(SERVO_CH["left"])
        right = rig.settled_pulse(SERVO_CH["right"], hold=0.1)
        assert left == pytest.approx(open_loop_pulse(left_sp), abs=0.25), aileron
        assert right == pytest.approx(open_loop_pulse(right_sp), abs=0.25), aileron
        # telemetry carries the same setpoints
        assert wait_for(lambda sp=left_sp, t0=t0: rig.gcs.latest("L_sp", t0 + 0.3) == pytest.approx(sp), 2.0)
        assert rig.gcs.latest("R_sp", t0 + 0.3) == pytest.approx(right_sp)
    assert rig.gcs.latest("WB_mode") == 0.0  # open
    assert rig.stop() == 0


def test_feed_forward_compensates_hysteresis_on_the_wire(make_rig):
    """In ff the same aileron gives a different pulse coming from above than from below: the model."""
    rig = make_rig(mode="ff", jitter_us=0, sensor_backend="none")
    rig.start()
    rig.aileron = 1100
    rig.settled_pulse(0, 0.3)
    rig.aileron = 1700
    from_below = rig.settled_pulse(0, 0.4)
    rig.aileron = 1900
    rig.settled_pulse(0, 0.3)
    rig.aileron = 1700
    from_above = rig.settled_pulse(0, 0.4)
    # us: sheath friction holds the warp when the tendon is let go, so reaching the same warp from above
    # takes a tendon released further: the inverse model puts the loop width (~1.5 mm) between the two
    assert from_below - from_above > 40.0
    assert rig.gcs.latest("L_warp") is None  # no sensor, no measured warp
    assert rig.gcs.latest("WB_mode") == 2.0


def test_parameters_list_set_refuse_and_persist_across_a_restart(make_rig):
    rig = make_rig()
    rig.start()
    gcs = rig.gcs
    gcs.param_list()
    assert wait_for(lambda: gcs.param_msgs and len(gcs.params) == gcs.param_msgs[-1].param_count, 10.0), \
        sorted(gcs.params)
    count = gcs.param_msgs[-1].param_count
    assert count >= 21
    assert count == len(gcs.params)
    assert {m.param_index for m in gcs.param_msgs} == set(range(count))
    assert gcs.params["WB_KP"] == pytest.approx(7.0) and gcs.params["WB_MODE"] == 3.0

    gcs.param_set("WB_KP", 5.0)
    assert wait_for(lambda: gcs.params["WB_KP"] == pytest.approx(5.0), 5.0)
    # refused: out of range, not a whole number; the echo carries the unchanged value, a STATUSTEXT says why
    n = len(gcs.param_msgs)
    gcs.param_set("WB_KP", 500.0)
    gcs.param_set("WB_MODE", 1.5)
    assert wait_for(lambda: gcs.has_text("WB_KP") and gcs.has_text("WB_MODE"), 5.0), gcs.texts
    assert wait_for(lambda: len(gcs.param_msgs) >= n + 2, 5.0)
    assert gcs.params["WB_KP"] == pytest.approx(5.0) and gcs.params["WB_MODE"] == 3.0
    assert rig.stop() == 0

    gcs.params.clear()
    rig.start()  # a new process reads the persisted value
    gcs.param_read("WB_KP")
    assert wait_for(lambda: "WB_KP" in gcs.params, 5.0)
    assert gcs.params["WB_KP"] == pytest.approx(5.0)


@pytest.mark.slow
def test_live_mode_and_gain_changes_over_mavlink_change_what_the_servo_gets(make_rig):
    rig = make_rig(mode="ff+pi", ki=0.0, jitter_us=0)
    rig.aileron = 1700  # left setpoint 5 deg, measured 4: e = 1 deg
    rig.sensor = {SENSOR_CH["left"]: noisy(4.0), SENSOR_CH["right"]: noisy(1.0)}
    rig.start()
    gcs = rig.gcs
    rig.run_for(1.0)
    t0 = time.monotonic()
    rig.run_for(0.5)
    assert sum(gcs.values("L_pi", t0)) / len(gcs.values("L_pi", t0)) == pytest.approx(7.0, abs=0.3)  # kp e

    gcs.param_set("WB_KP", 2.0)
    assert wait_for(lambda: gcs.params.get("WB_KP") == pytest.approx(2.0), 5.0)
    rig.run_for(2.0)  # bumpless: the old command fades into the new law over ~0.5 s
    t1 = time.monotonic()
    rig.run_for(0.5)
    assert sum(gcs.values("L_pi", t1)) / len(gcs.values("L_pi", t1)) == pytest.approx(2.0, abs=0.2)

    gcs.param_set("WB_MODE", 0)  # open loop: the straight line, whatever the sensor says
    assert wait_for(lambda: gcs.has_text("WB mode open"), 5.0)
    rig.run_for(2.0)  # the transfer offset has decayed to < 0.03 mm by now
    assert rig.settled_pulse(SERVO_CH["left"]) == pytest.approx(open_loop_pulse(5.0), abs=1.5)
    assert gcs.latest("WB_mode") == 0.0


@pytest.mark.slow
def test_each_failsafe_triggers_and_recovers(make_rig):
    rig = make_rig(mode="ff+pi")
    rig.sensor = {SENSOR_CH["left"]: noisy(3.0), SENSOR_CH["right"]: noisy(1.5)}
    rig.aileron = 1700
    rig.start()
    gcs = rig.gcs
    active = rig.settled_pulse(0)
    neutral_open = open_loop_pulse(2.0)
    assert wait_for(lambda: gcs.latest("L_warp") is not None, 3.0)

    # 1. the FC stops streaming servo outputs: both wings to neutral (bias), then follow again
    rig.mock.pause_streams(1.0)
    assert wait_for(lambda: gcs.has_text("WB failsafe: no servo outputs, wings neutral"), 3.0), gcs.texts
    t_fs = time.monotonic()
    assert wait_for(lambda: gcs.latest("WB_mode", t_fs) == -1.0, 2.0)
    assert wait_for(lambda: gcs.has_text("WB servo outputs back"), 3.0)
    # what the servo got at the end of the failsafe, from the bridge's cycle log (however late this
    # test process saw it happen on a busy machine)
    held = wait_for(lambda: [float(r["left_pulse"]) for r in rig.cycle_rows() if r["mode"] == "failsafe"][-1:])
    assert held and abs(held[-1] - neutral_open) < abs(active - neutral_open)  # moved towards neutral
    assert rig.settled_pulse(0, 1.5) == pytest.approx(active, abs=6.0)

    # 2. the wing's output goes invalid (0 = disabled): that wing to neutral, back when valid
    rig.aileron = 0
    assert wait_for(lambda: gcs.latest("L_sp") == pytest.approx(2.0), 3.0)
    rig.aileron = 1700
    assert wait_for(lambda: gcs.latest("L_sp") == pytest.approx(5.0), 3.0)

    # 3. the left flex sensor reads outside its calibration table: ff only, then back
    rig.sensor[SENSOR_CH["left"]] = lambda: 1020
    assert wait_for(lambda: gcs.has_text("WB left sensor reading 1020 out of range: ff only"), 3.0), gcs.texts
    t0 = time.monotonic()
    rig.run_for(2.5)
    pis = [abs(p) for p in gcs.values("L_pi", t0)]
    # feed-forward only: what was PI fades out smoothly (bumpless, 0.5 s) and nothing new is added
    assert pis[0] > 1.0 and pis[-1] < 0.03 * pis[0], pis
    assert all(b <= a + 1e-6 for a, b in zip(pis, pis[1:], strict=False)), pis
    rig.sensor[SENSOR_CH["left"]] = noisy(3.0)
    assert wait_for(lambda: gcs.has_text("WB left sensor back"), 3.0)

    # 4. the right flex sensor freezes while the command moves: ff only, then back when it moves
    rig.sensor[SENSOR_CH["right"]] = lambda: counts_for_deg(1.5)
    for a in (1300, 1100, 1300, 1100):  # right wing: setpoints 5 and 8 deg, command moves mm
        rig.aileron = a
        rig.run_for(0.3)
    assert wait_for(lambda: gcs.has_text("WB right sensor frozen: ff only"), 3.0), gcs.texts
    rig.sensor[SENSOR_CH["right"]] = noisy(1.5)
    assert wait_for(lambda: gcs.has_text("WB right sensor back"), 3.0)

    # 5. the Maestro reports an error: one STATUSTEXT, and one "cleared" when the board is clean again
    rig.emu.errors = 0x0002
    assert wait_for(lambda: gcs.has_text("WB servo board error"), 3.0), gcs.texts
    assert wait_for(lambda: gcs.has_text("WB servo board error cleared"), 3.0)
    assert gcs.count_text("WB servo board error:") == 1

    # 6. the Maestro is unplugged: the bridge keeps running, reopens it with back-off when it returns
    rig.emu.close_port()
    assert wait_for(lambda: gcs.has_text("WB servo lost"), 3.0), gcs.texts
    time.sleep(0.5)
    rig.emu.reopen_port()
    assert wait_for(lambda: gcs.has_text("WB servo output back"), 10.0), gcs.texts
    t1 = time.monotonic()
    assert wait_for(lambda: rig.pulses(0, t1), 3.0)
    assert rig.stop() == 0


def run_check(rig: Rig) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    return run_to_end([*warpbridge_command(), "run", "--config", str(rig.config_path), "--check"],
                      cwd=rig.tmp, env=env)


def test_check_reports_every_part_and_fails_clearly(make_rig):
    rig = make_rig()
    rig.sensor = {SENSOR_CH["left"]: noisy(3.0), SENSOR_CH["right"]: noisy(1.0)}
    ok = run_check(rig)
    assert ok.returncode == 0, ok.stdout + ok.stderr
    out = ok.stdout
    assert "config: OK" in out and "servo: maestro:" in out and "opened" in out
    reading = re.search(rf"sensor: left channel {SENSOR_CH['left']}: ([0-9.]+) counts", out)
    assert reading and abs(float(reading.group(1)) - counts_for_deg(3.0)) <= 1.5, out
    assert "link: FC system 1 (ardupilot)" in out
    assert "link: servo outputs 1: 1500" in out
    assert out.strip().endswith("check: OK")

    rig.sensor = {SENSOR_CH["left"]: lambda: 5}  # below the table; the right sensor is missing
    rig.emu.close_port()  # and then the Maestro is not there at all, nor the FC's serial port
    missing_fc = rig.tmp / "ttyFC"
    text = rig.config_path.read_text()
    rig.config_path.write_text(re.sub(r'connection = "[^"]*"', f'connection = "{missing_fc},921600"', text))
    bad = run_check(rig)
    assert bad.returncode == 2
    lines = {line.split(":")[0]: line for line in bad.stdout.splitlines()}
    # each part names its own cause, once: the missing device, not a protocol symptom or another part's spec
    assert "FAILED" in lines["servo"] and lines["servo"].endswith("No such file or directory"), bad.stdout
    assert "[Errno" not in bad.stdout
    assert "FAILED" in lines["sensor"] and "on the servo's Maestro, which did not open" in lines["sensor"]
    assert f"link: FAILED: cannot open {missing_fc},921600: No such file or directory" in bad.stdout
    assert "heartbeat" not in bad.stdout
    assert bad.stdout.strip().endswith("check: FAILED")


def test_config_errors_stop_the_process_with_one_line(tmp_path):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(config_text(free_udp_port(), tmp_path / "maestro").replace("kp = 7", "kp = -7", 1))
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    r = run_to_end([*warpbridge_command(), "run", "--config", str(cfg)], env=env)
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "kp" in r.stderr and "Traceback" not in r.stderr

