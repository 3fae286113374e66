"""Faults, each injected into the running bridge (lock-step clock; FC on real loopback UDP or a real pty;
servo board on the Maestro emulator's pty or the ``loop:`` backend): it degrades as the bridge defines,
reports once (no STATUSTEXT storm) and recovers without a restart."""

from __future__ import annotations

import math
import os
import random
import select
import socket
import tty
from pathlib import Path

import pytest
from helpers import ManualClock, free_udp_port

from warpbridge.bridge.app import Bridge
from warpbridge.bridge.config import load_config
from warpbridge.bridge.mavlink_env import mavlink
from warpbridge.hw.loop import LoopBackend
from warpbridge.sitl.maestro_emu import MaestroEmulator

DT = 0.01
LIMITS_US = (1100.0, 1900.0)


CONFIG = """
[link]
connection = "{connection}"
source_system = 1
rerequest_s = 1
[loop]
rate_hz = 100
failsafe_timeout_s = 0.3
sensor_frozen_s = 0.5
log = "cycles.csv"
[params]
file = "params.json"
[servo]
backend = "{servo}"
[sensor]
backend = "{sensor}"
[wing.left]
source_channel = 1
servo_channel = 0
{left_sensor}
[wing.left.servo]
pulse_min_us = 1100
pulse_max_us = 1900
[wing.left.sensor]
counts = [100, 900]
deg = [0, 20]
[wing.left.control]
kp = 7.0  # the gains these fault tests were written for: a slow integrator that the sensor-fault test
ki = 1.0  # watches move, rather than one that sits at its limit
[wing.right]
source_channel = 1
reverse = true
servo_channel = 1
[wing.right.servo]
pulse_min_us = 1100
pulse_max_us = 1900
"""


class UdpFc:
    def __init__(self) -> None:
        self.port = free_udp_port()
        self.connection = f"udpin:127.0.0.1:{self.port}"
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect(("127.0.0.1", self.port))
        self.sock.setblocking(False)

    def write(self, data: bytes) -> None:
        try:
            self.sock.send(data)
        except ConnectionRefusedError:
            pass

    def read(self) -> bytes:
        try:
            return self.sock.recv(65536)
        except (BlockingIOError, ConnectionRefusedError):
            return b""

    def close(self) -> None:
        self.sock.close()


class PtyFc:
    """The FC on a serial port: a pty behind a stable symlink that is absent while 'unplugged'."""

    def __init__(self, folder: Path) -> None:
        self.link = folder / "fc-tty"
        self.connection = f"{self.link},115200"
        self.master = self.slave = None
        self.plug()

    def plug(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        tmp = self.link.with_name("fc-tty.tmp")
        os.symlink(os.ttyname(self.slave), tmp)
        os.replace(tmp, self.link)

    def unplug(self) -> None:
        self.link.unlink()
        os.close(self.master)
        os.close(self.slave)
        self.master = None

    def write(self, data: bytes) -> None:
        if self.master is not None:
            try:
                os.write(self.master, data)
            except OSError:
                pass

    def read(self) -> bytes:
        if self.master is None:
            return b""
        try:
            return os.read(self.master, 65536)
        except OSError:
            return b""

    def close(self) -> None:
        if self.master is not None:
            self.unplug()


class Rig:
    def __init__(self, tmp_path: Path, *, fc=None, servo: str = "loop:", sensor_counts=None,
                 sensor: str | None = None) -> None:
        self.fc = fc or UdpFc()
        has_sensor = sensor_counts is not None or sensor is not None
        sensor = sensor or ("loop:" if sensor_counts is not None else "none")
        cfg = tmp_path / "wb.toml"
        cfg.write_text(CONFIG.format(connection=self.fc.connection, servo=servo, sensor=sensor,
                                     left_sensor="sensor_channel = 5" if has_sensor else ""))
        self.clock = ManualClock(20.0)
        self.loop = LoopBackend(counts=sensor_counts, clock=self.clock) if servo == "loop:" else None
        self.bridge = Bridge(load_config(cfg), servo=self.loop, sensor=self.loop if sensor_counts else None,
                             clock=self.clock)
        self.bridge.link.open()
        self.enc = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.rx = mavlink.MAVLink(None)
        self.rx.robust_parsing = True
        self.texts: list[str] = []
        self.commands: list = []
        self.pwm = 1500
        self.streaming = True
        self.i = 0
        self.checked = 0

    def tick(self, n: int = 1) -> None:
        for _ in range(n):
            self.i += 1
            wrote = False
            if self.streaming:
                if self.i % 50 == 1:
                    self.fc.write(mavlink.MAVLink_heartbeat_message(
                        mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3).pack(self.enc))
                if self.i % 2 == 1:
                    self.fc.write(mavlink.MAVLink_servo_output_raw_message(
                        self.i, 0, self.pwm, 1500, 0, 0, 0, 0, 0, 0).pack(self.enc))
                    wrote = True
                mav = self.bridge.link.mav
                if mav is not None and wrote:
                    select.select([mav.fd if mav.fd is not None else mav.port.fileno()], [], [], 0.02)
            self.clock.t += DT
            self.bridge.tick()
            while data := self.fc.read():
                for m in self.rx.parse_buffer(data) or []:
                    if m.get_type() == "STATUSTEXT":
                        self.texts.append(m.text)
                    elif m.get_type() == "COMMAND_LONG":
                        self.commands.append(m)
            if self.loop is not None:
                for _, _, pulse in self.loop.history[self.checked:]:
                    assert LIMITS_US[0] <= pulse <= LIMITS_US[1]
                self.checked = len(self.loop.history)

    def following(self, pwm: int | None = None) -> bool:
        want = self.bridge.mixer.setpoints({1: float(self.pwm if pwm is None else pwm)})
        return not self.bridge.failsafe and all(
            math.isclose(self.bridge.wings[w].setpoint, want[w]) for w in want)

    def ticks_until(self, cond, limit_s: float) -> float:
        t0 = self.clock.t
        while self.clock.t - t0 < limit_s:
            self.tick()
            if cond():
                return self.clock.t - t0
        return math.inf

    def count(self, word: str) -> int:
        return sum(word in t for t in self.texts)

    def close(self) -> None:
        self.bridge.close()
        self.fc.close()


# ---------------------------------------------------------------------------- the FC link


def test_link_dropped_and_restored(tmp_path):
    r = Rig(tmp_path)
    try:
        r.pwm = 1800
        assert r.ticks_until(r.following, 1.0) < 0.5
        r.streaming = False  # the FC (or the cable) goes silent: nothing at all for 10 s
        r.tick(1000)
        neutral = r.bridge.mixer.neutral()
        assert r.bridge.failsafe and all(r.bridge.wings[w].last["setpoint"] == neutral[w] for w in neutral)
        asked = len(r.commands)
        assert asked >= 1  # the stream was asked for again while silent
        r.streaming, r.pwm = True, 1300
        assert r.ticks_until(r.following, 2.0) <= 0.5
        assert r.count("failsafe") == 1 and r.count("back") == 1  # once each, no storm
        assert r.bridge.failsafe_entries == 1
    finally:
        r.close()


def test_fc_serial_port_unplugged_and_back(tmp_path):
    r = Rig(tmp_path, fc=PtyFc(tmp_path))
    try:
        r.pwm = 1700
        assert r.ticks_until(r.following, 2.0) < 1.0
        r.fc.unplug()
        r.tick(300)  # 3 s unplugged: failsafe, the link retries with back-off
        assert r.bridge.failsafe and r.bridge.link.mav is None
        assert r.bridge.link.counters.reconnects == 1
        r.fc.plug()
        r.pwm = 1250
        t = r.ticks_until(r.following, 10.0)
        assert t <= 8.0 + 0.5  # at most one back-off period (capped at 8 s) and then 0.5 s
        assert r.bridge.link.counters.reconnects == 1  # reopened, not flapping
    finally:
        r.close()


# ---------------------------------------------------------------------------- the servo board


def test_servo_board_unplugged_and_back(tmp_path):
    targets: list[tuple[int, int]] = []
    emu = MaestroEmulator(on_target=lambda ch, q: targets.append((ch, q)), link=tmp_path / "maestro")
    emu.start()
    r = Rig(tmp_path, servo=f"maestro:{tmp_path / 'maestro'}")
    try:
        retries: list[float] = []
        real_reopen = r.bridge.servo.reopen

        def reopen(url=None):
            retries.append(r.clock.t)
            return real_reopen(url)

        r.bridge.servo.reopen = reopen
        r.pwm = 1700
        assert r.ticks_until(lambda: r.following() and len(targets) > 10, 2.0) < 1.0
        emu.close_port()
        cycles = r.bridge.cycles
        r.tick(1200)  # 12 s unplugged
        assert r.bridge.cycles == cycles + 1200  # kept running
        assert r.count("servo lost") == 1
        gaps = [b - a for a, b in zip(retries, retries[1:], strict=False)]
        assert len(retries) >= 4 and gaps == sorted(gaps) and max(gaps) <= 8.0 + 2 * DT  # back-off
        n = len(targets)
        emu.reopen_port()
        r.pwm = 1300
        assert r.ticks_until(lambda: len(targets) > n + 10, 10.0) <= 8.0 + 0.5
        assert r.count("servo output back") == 1
        assert r.following()
        lo, hi = (4 * x for x in LIMITS_US)
        assert all(lo <= q <= hi for _, q in targets)  # quarter-us, within the limits throughout
    finally:
        r.close()
        emu.stop()


def test_servo_board_absent_at_start_is_waited_for_with_the_sensor_on_it(tmp_path):
    """The companion computer boots before the Maestro is plugged in, and the warp sensor is read on that same
    board (``maestro:``): the bridge starts anyway, feed-forward only, and takes up servo and sensor once the
    board appears."""
    targets: list[tuple[int, int]] = []
    emu = MaestroEmulator(on_target=lambda ch, q: targets.append((ch, q)), read_analog=lambda ch: 500,
                          link=tmp_path / "maestro")
    r = Rig(tmp_path, servo=f"maestro:{tmp_path / 'maestro'}", sensor="maestro:")
    try:
        assert r.bridge.servo is None and r.bridge.sensor is None
        cycles = r.bridge.cycles
        r.tick(300)  # 3 s without the board
        assert r.bridge.cycles == cycles + 300
        assert r.count("servo lost") == 1
        emu.start()
        r.pwm = 1700
        assert r.ticks_until(lambda: len(targets) > 10, 10.0) <= 8.0 + 0.5  # within one back-off period
        assert r.count("servo output back") == 1
        assert r.bridge.sensor is r.bridge.servo  # one board: the sensor came back with the servo
        assert r.ticks_until(lambda: r.bridge.wings["left"].ctl.mode == "ff+pi", 2.0) < 2.0
    finally:
        r.close()
        emu.stop()


def test_a_sensor_on_its_own_device_stays_open_while_the_servo_board_comes_back(tmp_path):
    """The servo board absent at start, the sensor on another device (here the loop backend): when the board
    appears the servo is opened, and the sensor already open is kept, not opened a second time."""
    emu = MaestroEmulator(link=tmp_path / "maestro")
    r = Rig(tmp_path, servo=f"maestro:{tmp_path / 'maestro'}", sensor="loop:")
    try:
        sensor = r.bridge.sensor
        assert r.bridge.servo is None and sensor is not None
        r.tick(100)
        emu.start()
        assert r.ticks_until(lambda: r.bridge.servo is not None, 10.0) <= 8.0 + 0.5
        assert r.bridge.sensor is sensor
    finally:
        r.close()
        emu.stop()


def test_servo_board_error_reported_once_while_it_persists(tmp_path):
    r = Rig(tmp_path)
    try:
        r.tick(20)
        for _ in range(2000):  # 20 s of the board flagging a serial protocol error
            r.loop.errors = 1 << 4
            r.tick()
        assert r.count("servo board error") == 1
        assert r.following()
    finally:
        r.close()


# ---------------------------------------------------------------------------- the flex sensor


class Wing:
    """Left flex sensor: reads the setpoint's warp (deg) back as counts, or a fault."""

    def __init__(self) -> None:
        self.bridge = None
        self.fault: str | None = None
        self.frozen = 500.0
        self.rng = random.Random(3)

    def counts(self, channel: int) -> float | None:
        w = self.bridge.wings["left"].setpoint + 0.3  # a small steady error for the integrator
        good = 100 + 800 * w / 20 + self.rng.choice([-1, 0, 1])  # a live sensor jitters by a count
        if self.fault == "disconnected":
            return None
        if self.fault == "open-circuit":
            return 0.0  # below the calibration table
        if self.fault == "frozen":
            return self.frozen
        if self.fault == "noisy":
            return self.rng.choice([math.nan, -5.0, 5000.0, good])
        return good


@pytest.mark.parametrize("fault", ["disconnected", "open-circuit", "frozen", "noisy"])
def test_sensor_fault_runs_feed_forward_with_integrator_held_and_recovers(tmp_path, fault):
    wing = Wing()
    r = Rig(tmp_path, sensor_counts=wing.counts)
    wing.bridge = r.bridge
    ctl = r.bridge.wings["left"].ctl
    try:
        r.pwm = 1700
        r.tick(150)
        assert r.bridge.wings["left"].last["warp"] is not None
        wing.fault = fault
        bad_cycles = 0
        for k in range(1500):  # 15 s, with the aileron moving (a frozen reading must be noticed)
            r.pwm = 1500 + int(300 * math.sin(k / 50))
            i_before = ctl._i
            r.tick()
            row = r.bridge.wings["left"].last
            if row["warp"] is None:  # sensor judged bad this cycle: feed-forward only, integrator held
                bad_cycles += 1
                assert ctl._i == i_before
                assert "ff+pi" not in r.bridge.wings["left"].ctl._ran[1]
            assert math.isfinite(row["u"])
        assert bad_cycles > 100
        i_held = ctl._i
        problems = r.count("left sensor") - r.count("sensor back")
        kinds = 2 if fault == "noisy" else 1  # a noisy sensor gives no reading and readings out of range
        # each kind reported once (a flapping fault at most once per 10 s key hold-off), not once per flap
        assert 1 <= problems <= 2 * kinds, r.texts
        assert r.count("sensor back") <= problems, r.texts
        wing.fault = None
        r.tick(200)
        assert r.bridge.wings["left"].last["warp"] is not None  # back on the sensor, PI trimming again
        assert ctl._i != i_held
    finally:
        r.close()


def test_another_kind_of_sensor_fault_is_said_at_once_after_the_sensor_came_back(tmp_path):
    wing = Wing()
    r = Rig(tmp_path, sensor_counts=wing.counts)
    wing.bridge = r.bridge
    try:
        r.pwm = 1700
        wing.fault = "disconnected"  # no reading at start-up (a sensor still waking up)
        r.tick(20)
        wing.fault = None
        r.tick(50)
        assert r.count("left sensor no reading") == 1 and r.count("left sensor back") == 1, r.texts
        wing.fault = "open-circuit"  # a second of later, well inside the 10 s hold-off of a flapping fault
        r.tick(20)
        assert r.count("out of range: ff only") == 1, r.texts
        wing.fault = None
        r.tick(20)
        wing.fault = "open-circuit"  # the same fault again at once: flapping, held off
        r.tick(20)
        assert r.count("out of range: ff only") == 1, r.texts
    finally:
        r.close()


def test_the_cycle_log_says_when_each_wings_sensor_was_read(tmp_path):
    """A sensor that takes 2 ms to answer: the row says the wing was read 1 ms after the row's time (the middle of
    the round trip), its command sent after that; a wing with no sensor has no read."""
    wing = Wing()
    r = Rig(tmp_path, sensor_counts=wing.counts)
    wing.bridge = r.bridge

    def slow(channel: int) -> float | None:
        r.clock.t += 0.002
        return wing.counts(channel)

    r.loop.counts = slow
    try:
        r.tick(50)
        left, right = r.bridge.wings["left"].last, r.bridge.wings["right"].last
        assert left["warp"] is not None and left["read"] == pytest.approx(0.001)
        assert left["u_sent"] == pytest.approx(0.002)  # the clock moves only in the read here
        assert "read" not in right
    finally:
        r.close()


def test_a_bias_above_the_warp_range_is_capped_and_said(tmp_path):
    """WB_BIAS above WB_MAXWARP holds each wing at full warp at neutral aileron: taken, capped, and the ground
    station is told; one inside the range says nothing."""
    r = Rig(tmp_path)
    try:
        r.tick(20)
        r.bridge.store.set("WB_MAXWARP", 10.0)
        r.bridge.store.set("WB_BIAS", 6.0)
        r.tick(20)
        assert r.count("capped") == 0
        r.bridge.store.set("WB_BIAS", 12.0)
        r.tick(20)
        assert r.count("WB bias 12 capped at WB_MAXWARP 10 deg") == 1
        assert all(m.neutral_deg == 10.0 for m in r.bridge.mixer.wings.values())
    finally:
        r.close()
