"""Corrupt and hostile MAVLink on the FC link: the running bridge (in-process, lock-step clock) fed
through real loopback UDP by a raw socket. Never crashes (no exception logged), never commands a
pulse outside the configured limits, follows valid traffic again within 0.5 s.

``WB_FUZZ_EXAMPLES`` scales the hypothesis run (default 150 examples, a few seconds);
``WB_FUZZ_STATS=file`` appends each test's link counters to ``file`` as a JSON line (for the figures
in docs/security.md)."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import select
import socket
import struct
from pathlib import Path

import pytest
from helpers import ManualClock, drain_mavlink, free_udp_port
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from warpbridge.bridge.app import Bridge
from warpbridge.bridge.config import load_config
from warpbridge.bridge.mavlink_env import mavlink
from warpbridge.hw.loop import LoopBackend

LIMITS = {0: (1100.0, 1900.0), 1: (1200.0, 1800.0)}  # servo channel -> configured pulse range
DT = 0.01  # 100 Hz loop
RECOVERY_S = 0.5
FUZZ_EXAMPLES = int(os.environ.get("WB_FUZZ_EXAMPLES", "150"))


CONFIG = """
[link]
connection = "udpin:127.0.0.1:{port}"
source_system = 1
servo_rate_hz = 50
gcs_sysid_allow = [200]
{signing}
[loop]
rate_hz = 100
failsafe_timeout_s = 0.3
log = "cycles.csv"
[params]
file = "params.json"
[servo]
backend = "loop:"
[sensor]
backend = "none"
[wing.left]
source_channel = 1
servo_channel = 0
bias_deg = 1.0
max_warp_deg = 8.0
[wing.left.servo]
pulse_min_us = 1100
pulse_max_us = 1900
pulse_zero_us = 1300
[wing.right]
source_channel = 1
reverse = true
servo_channel = 1
bias_deg = 1.0
max_warp_deg = 8.0
[wing.right.servo]
pulse_min_us = 1200
pulse_max_us = 1800
pulse_zero_us = 1300
"""


class Rig:
    """The bridge in lock-step: ``send`` bytes from the 'FC' socket, ``tick`` advances 10 ms."""

    def __init__(self, tmp_path: Path, signing: bool = False) -> None:
        port = free_udp_port()
        cfg = tmp_path / "wb.toml"
        extra = ""
        if signing:
            (tmp_path / "key").write_text("fuzzing passphrase\n")
            extra = 'signing_key_file = "key"'
        cfg.write_text(CONFIG.format(port=port, signing=extra))
        self.clock = ManualClock(100.0)
        self.servo = LoopBackend(clock=self.clock)
        self.bridge = Bridge(load_config(cfg), servo=self.servo, clock=self.clock)
        assert self.bridge.link.open()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect(("127.0.0.1", port))
        self.sock.setblocking(False)
        self.enc = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.rx = mavlink.MAVLink(None)
        self.rx.robust_parsing = True
        self.rx.signing.allow_unsigned_callback = lambda mav, msgid: True
        self.received: list = []  # everything the bridge sent back
        self.checked = 0
        self.sent_frames = 0
        self.hostile = 0  # hostile datagrams sent
        self.pwm = 1500
        self._next_servo = 0.0
        self._next_hb = 0.0
        self._unread = False

    def frame(self, msg, src=(1, 1)) -> bytes:
        self.enc.srcSystem, self.enc.srcComponent = src
        return msg.pack(self.enc)

    def send(self, data: bytes) -> None:
        try:
            self.sock.send(data)
        except ConnectionRefusedError:  # an ICMP error from a datagram sent while the link was closed
            self.sock.send(data)
        self.sent_frames += 1
        self._unread = True

    def valid_traffic(self) -> None:
        """The FC's normal stream: heartbeat 1 Hz, SERVO_OUTPUT_RAW 50 Hz with ``self.pwm`` on output 1."""
        now = self.clock.t
        if now >= self._next_hb:
            self._next_hb = now + 1.0
            self.send(self.frame(mavlink.MAVLink_heartbeat_message(
                mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                mavlink.MAV_MODE_FLAG_SAFETY_ARMED, 0, mavlink.MAV_STATE_ACTIVE, 3)))
        if now >= self._next_servo:
            self._next_servo = now + 0.02
            self.send(self.frame(mavlink.MAVLink_servo_output_raw_message(
                int(now * 1e6) & 0xFFFFFFFF, 0, self.pwm, 1500, 1100, 1500, 0, 0, 0, 0)))

    @property
    def all_read(self) -> bool:
        """The bridge has read every datagram sent (loopback delivery may lag under bursts)."""
        return self.bridge.link.counters.datagrams >= self.sent_frames

    def tick(self, n: int = 1, traffic: bool = False) -> None:
        for _ in range(n):
            if traffic:
                self.valid_traffic()
            fd = self.bridge.link.mav.port.fileno() if self.bridge.link.mav is not None else None
            if fd is not None and self._unread:
                select.select([fd], [], [], 0.05)  # what was sent is there to be read
            self._unread = False
            self.clock.t += DT
            self.bridge.tick()
            self.check_pulses()
            self.drain()

    def drain(self) -> None:
        self.received.extend(drain_mavlink(self.sock, self.rx))

    def check_pulses(self) -> None:
        for _, ch, pulse in self.servo.history[self.checked:]:
            lo, hi = LIMITS[ch]
            assert math.isfinite(pulse) and lo <= pulse <= hi, (ch, pulse)
        self.checked = len(self.servo.history)

    def expected(self, pwm: int) -> dict[str, float]:
        return self.bridge.mixer.setpoints({1: float(pwm)})

    def following(self, pwm: int) -> bool:
        want = self.expected(pwm)
        return not self.bridge.failsafe and all(
            math.isclose(self.bridge.wings[w].setpoint, want[w], abs_tol=1e-9) for w in want)

    def recovery_time(self, pwm: int, limit_s: float = 2.0) -> float:
        """Valid traffic with aileron ``pwm`` from now: simulated seconds until the wings follow it."""
        self.pwm = pwm
        self._next_servo = self._next_hb = self.clock.t
        t0 = self.clock.t
        while self.clock.t - t0 < limit_s:
            self.tick(traffic=True)
            if self.following(pwm):
                return self.clock.t - t0
        return math.inf

    def statustexts(self) -> list[str]:
        return [m.text for m in self.received if m.get_type() == "STATUSTEXT"]

    def close(self) -> None:
        self.bridge.close()
        self.sock.close()


@pytest.fixture(params=[False, True], ids=["unsigned", "signing"])
def rig(request, tmp_path, caplog):
    caplog.set_level(logging.WARNING)
    r = Rig(tmp_path, signing=request.param)
    assert r.recovery_time(1500) < RECOVERY_S  # linked up and following
    yield r
    r.close()
    if os.environ.get("WB_FUZZ_STATS"):
        with open(os.environ["WB_FUZZ_STATS"], "a") as f:
            stats = dataclasses.asdict(r.bridge.link.counters) | {
                "test": os.environ.get("PYTEST_CURRENT_TEST", ""), "datagrams_sent": r.sent_frames,
                "hostile_datagrams": r.hostile, "cycles": r.bridge.cycles}
            f.write(json.dumps(stats) + "\n")
    errors = [rec for rec in caplog.records if rec.levelno >= logging.ERROR]
    assert not errors, [rec.getMessage() for rec in errors]  # nothing crashed inside the loop


# ---------------------------------------------------------------------------- strategies

u8 = st.integers(0, 255)
u16 = st.integers(0, 0xFFFF)
u32 = st.integers(0, 0xFFFFFFFF)
f32 = st.floats(width=32, allow_nan=True, allow_infinity=True)
sender = st.one_of(st.just((1, 1)), st.tuples(u8, u8).filter(lambda s: s[0] != 200))


def _servo(draw) -> object:
    vals = draw(st.lists(st.one_of(st.sampled_from([0, 1, 499, 500, 2600, 2601, 65535]), u16),
                         min_size=16, max_size=16))
    return mavlink.MAVLink_servo_output_raw_message(draw(u32), draw(u8), *vals)


def _actuator(draw) -> object:
    vals = draw(st.lists(st.one_of(f32, st.floats(900, 2100, width=32)), min_size=32, max_size=32))
    active = draw(st.one_of(st.just(0), u32, st.integers(0, 40)))
    return mavlink.MAVLink_actuator_output_status_message(draw(st.integers(0, 2**63)), active, vals)


def _vfr(draw) -> object:
    return mavlink.MAVLink_vfr_hud_message(draw(f32), draw(f32), draw(st.integers(-32768, 32767)),
                                           draw(u16), draw(f32), draw(f32))


def _heartbeat(draw) -> object:
    return mavlink.MAVLink_heartbeat_message(draw(u8), draw(u8), draw(u8), draw(u32), draw(u8), 3)


def _command(draw) -> object:
    return mavlink.MAVLink_command_long_message(draw(u8), draw(st.sampled_from([0, 191, 1])), draw(u16),
                                                draw(u8), *[draw(f32) for _ in range(7)])


def _param_set(draw) -> object:
    name = draw(st.one_of(st.sampled_from([b"WB_KP", b"WB_MODE", b"WB_FS_TMO", b"WB_MAXWARP"]),
                          st.binary(min_size=0, max_size=16)))
    return mavlink.MAVLink_param_set_message(draw(st.sampled_from([0, 1, 2])), draw(st.sampled_from([0, 191, 1])),
                                             name, draw(f32), draw(u8))


def _param_read(draw) -> object:
    if draw(st.booleans()):
        return mavlink.MAVLink_param_request_list_message(draw(st.sampled_from([0, 1])),
                                                          draw(st.sampled_from([0, 191])))
    return mavlink.MAVLink_param_request_read_message(1, 191, draw(st.binary(max_size=16)),
                                                      draw(st.integers(-32768, 32767)))


def _ack(draw) -> object:
    return mavlink.MAVLink_command_ack_message(draw(u16), draw(u8), draw(u8), draw(st.integers(-2**31, 2**31 - 1)),
                                              draw(u8), draw(u8))


MESSAGES = [_servo, _actuator, _vfr, _heartbeat, _command, _param_set, _param_read, _ack]


def _corrupt(draw, data: bytes) -> bytes:
    kind = draw(st.sampled_from(["none", "truncate", "flip", "crc", "length", "flags", "v1", "splice"]))
    b = bytearray(data)
    if kind == "truncate":
        return bytes(b[: draw(st.integers(0, max(0, len(b) - 1)))])
    if kind == "flip" and b:
        for _ in range(draw(st.integers(1, 4))):
            i = draw(st.integers(0, len(b) - 1))
            b[i] ^= 1 << draw(st.integers(0, 7))
    elif kind == "crc":
        b[-2] ^= 0xFF
    elif kind == "length":
        b[1] = draw(u8)
    elif kind == "flags":
        b[2] = draw(u8)  # incompat flags: e.g. "signed" with no signature
    elif kind == "v1":
        b[0] = 0xFE
    elif kind == "splice":
        b = b[: len(b) // 2] + bytearray(draw(st.binary(max_size=40)))
    return bytes(b)


@st.composite
def hostile_datagram(draw) -> bytes:
    """One UDP datagram: random bytes, or 1-4 frames (valid encodings of absurd values), maybe corrupted."""
    if draw(st.integers(0, 4)) == 0:
        return draw(st.binary(min_size=1, max_size=300))
    enc = mavlink.MAVLink(None)
    out = b""
    for _ in range(draw(st.integers(1, 4))):
        make = draw(st.sampled_from(MESSAGES))
        enc.srcSystem, enc.srcComponent = draw(sender)
        enc.seq = draw(u8)
        out += _corrupt(draw, make(draw).pack(enc))
    if draw(st.integers(0, 9)) == 0:  # an unknown message id with a valid-looking header
        msgid = draw(st.integers(0, 0xFFFFFF))
        payload = draw(st.binary(max_size=40))
        out += struct.pack("<BBBBBBBHB", 0xFD, len(payload), 0, 0, 0, 1, 1, msgid & 0xFFFF, msgid >> 16)
        out += payload + draw(st.binary(min_size=2, max_size=2))
    return out


# ---------------------------------------------------------------------------- tests


@settings(max_examples=FUZZ_EXAMPLES, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(batch=st.lists(hostile_datagram(), min_size=1, max_size=6), pwm=st.integers(1100, 1900))
def test_fuzzed_traffic_never_breaks_control(rig, batch, pwm):
    kp_before = rig.bridge.store.values()
    for data in batch:
        rig.send(data)
        rig.hostile += 1
        rig.tick()
    rig.tick(3)
    # only the allow-listed GCS (200, never generated) may change parameters
    assert rig.bridge.store.values() == kp_before
    assert rig.recovery_time(pwm) <= RECOVERY_S


@pytest.mark.parametrize("case", ["pwm0", "pwm65535", "nan_actuator", "empty_mask", "unknown_channels",
                                  "nan_airspeed"])
def test_absurd_values_keep_limits_and_recover(rig, case):
    link = rig.bridge.link
    rig.pwm = 1800
    assert rig.recovery_time(1800) < RECOVERY_S
    before = link.counters.invalid_values
    if case == "pwm0":
        msg = mavlink.MAVLink_servo_output_raw_message(0, 0, 0, 0, 0, 0, 0, 0, 0, 0)
    elif case == "pwm65535":
        msg = mavlink.MAVLink_servo_output_raw_message(0, 0, *([65535] * 8))
    elif case == "nan_actuator":
        msg = mavlink.MAVLink_actuator_output_status_message(0, 0xFF, [math.nan] * 4 + [math.inf] * 28)
    elif case == "empty_mask":
        msg = mavlink.MAVLink_actuator_output_status_message(0, 0, [1500.0] * 32)
    elif case == "unknown_channels":
        msg = mavlink.MAVLink_servo_output_raw_message(0, 255, *([1700] * 16))
    else:
        msg = mavlink.MAVLink_vfr_hud_message(math.nan, math.inf, 0, 0, 0, 0)
    for _ in range(100):  # 1 s of nothing but absurd values, at 100 Hz
        rig.send(rig.frame(msg))
        rig.tick()
    if case in ("pwm0", "pwm65535", "nan_actuator"):
        # output 1 invalid for longer than the failsafe time: both wings neutral
        assert link.servo_pwm.get(1) is None
        neutral = rig.bridge.mixer.neutral()
        assert all(rig.bridge.wings[w].setpoint == neutral[w] for w in neutral)
    if case == "unknown_channels":
        assert set(link.servo_pwm) >= {255 * 16 + 1}  # far-away outputs stored, not used
    if case in ("pwm65535", "nan_actuator", "empty_mask", "nan_airspeed"):
        assert link.counters.invalid_values > before  # counted as absurd (0 = disabled output, not absurd)
    if case == "nan_airspeed":
        assert link.airspeed is None or math.isfinite(link.airspeed)
    assert rig.recovery_time(1300) <= RECOVERY_S


def test_flood_of_garbage_at_ten_times_the_rate(rig):
    """400 Hz of valid servo messages with 3600 Hz of garbage around them: control goes on."""
    rng = __import__("random").Random(5)
    enc = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    sent = judged = 0
    for i in range(200):  # 2 s
        rig.pwm = 1200 + (i * 7) % 600
        for k in range(4):
            junk = [bytes(rng.getrandbits(8) for _ in range(rng.randint(5, 60))) for _ in range(9)]
            good = mavlink.MAVLink_servo_output_raw_message(i * 4 + k, 0, rig.pwm, 1500, 0, 0, 0, 0, 0, 0)
            good_bytes = good.pack(enc)
            for j in junk:
                rig.send(j)
            rig.send(good_bytes)
            sent += 10
        rig.tick()
        if rig.all_read:  # judge the cycles that had all their input delivered
            judged += 1
            assert rig.following(rig.pwm), i  # each cycle uses the latest valid output
    rig.tick(2)
    assert rig.all_read and rig.following(rig.pwm)
    assert judged >= 50  # loopback delivery lags at times under a burst; most cycles are judged
    assert rig.bridge.link.counters.bad_data > 0
    assert sent == 8000


def test_flood_of_valid_messages_at_ten_times_the_rate(rig):
    """4000 servo messages a second (10x the 400 Hz stream): every cycle uses the latest one."""
    judged = 0
    for i in range(100):
        for k in range(40):
            rig.pwm = 1100 + (i * 40 + k) % 800
            rig.send(rig.frame(mavlink.MAVLink_servo_output_raw_message(0, 0, rig.pwm, 0, 0, 0, 0, 0, 0, 0)))
        rig.tick()
        if rig.all_read:
            judged += 1
            assert rig.following(rig.pwm)
    rig.tick(2)
    assert rig.all_read and rig.following(rig.pwm)
    assert judged >= 25


def test_link_counters_stay_bounded_under_unknown_types_and_senders(rig):
    link = rig.bridge.link
    for msgid in range(20000, 20400):
        payload = bytes(8)
        frame = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 0, 0, msgid % 256, msgid % 256, 7,
                            msgid & 0xFFFF, msgid >> 16) + payload + b"\x00\x00"
        rig.send(frame)
        if msgid % 40 == 0:
            rig.tick()
    rig.tick(5)
    assert len(link.counters.by_type) <= 65
    assert not hasattr(link.mav, "sysid_state") or len(link.mav.sysid_state) <= 1
    assert rig.recovery_time(1700) <= RECOVERY_S
