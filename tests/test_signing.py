"""MAVLink 2 signing: the key file, and the running bridge (lock-step clock, real loopback UDP) against
peers that sign with the right key, a wrong key, or not at all."""

from __future__ import annotations

import hashlib
import math
import select
import socket
from pathlib import Path

import pytest
from helpers import LOOP_SERVO_WINGS, ManualClock, drain_mavlink, free_udp_port

from warpbridge.bridge.app import Bridge
from warpbridge.bridge.config import load_config
from warpbridge.bridge.errors import UserError
from warpbridge.bridge.mavlink_env import mavlink
from warpbridge.bridge.signing import Signer, key_from_passphrase, load_key, now_timestamp, parse_key
from warpbridge.hw.loop import LoopBackend

KEY = key_from_passphrase("correct horse battery staple")
WRONG = key_from_passphrase("incorrect horse battery staple")
FC, GCS, OTHER_GCS = (1, 1), (255, 190), (200, 190)


# ---------------------------------------------------------------------------- the key file


def test_passphrase_key_is_sha256_as_mavproxy_derives_it(tmp_path):
    f = tmp_path / "k"
    f.write_text("# the aircraft's key\n\ncorrect horse battery staple\n")
    assert load_key(f) == hashlib.sha256(b"correct horse battery staple").digest() == KEY


def test_hex_key_file(tmp_path):
    f = tmp_path / "k"
    f.write_text(KEY.hex().upper() + "\n")
    assert load_key(f) == KEY


@pytest.mark.parametrize("content, reason", [
    (b"", "no key"), (b"# only a comment\n", "no key"), (b"short\n", "shorter than 8"),
    ((b"00" * 32) + b"\n", "all-zero"), (b"\xff\xfe\x00binary", "not text"),
])
def test_bad_key_files_are_one_line_user_errors(tmp_path, content, reason):
    f = tmp_path / "k"
    f.write_bytes(content)
    with pytest.raises(UserError, match=reason) as e:
        load_key(f)
    assert "\n" not in str(e.value)
    with pytest.raises(UserError, match="cannot read"):
        load_key(tmp_path / "missing")


def test_parse_key_rejects_all_zero_hex():
    with pytest.raises(ValueError):
        parse_key("0" * 64)


# ---------------------------------------------------------------------------- the running bridge

CONFIG = """
[link]
connection = "udpin:127.0.0.1:{port}"
source_system = 1
gcs_sysid_allow = {allow}
signing_key_file = "signing.key"
signing_accept_unsigned_from_fc = {accept}
[loop]
rate_hz = 100
failsafe_timeout_s = 0.3
[params]
file = "params.json"
""" + LOOP_SERVO_WINGS


class Peer:
    """Packs frames as one sender, signing with ``key`` (None: unsigned)."""

    def __init__(self, src: tuple[int, int], key: bytes | None, link_id: int = 1) -> None:
        self.enc = mavlink.MAVLink(None, srcSystem=src[0], srcComponent=src[1])
        if key is not None:
            self.enc.signing.secret_key = key
            self.enc.signing.sign_outgoing = True
            self.enc.signing.link_id = link_id
            self.enc.signing.timestamp = now_timestamp()

    def pack(self, msg) -> bytes:
        return msg.pack(self.enc)


class Rig:
    def __init__(self, tmp_path: Path, *, accept_unsigned_from_fc: bool = True, allow: str = "[]",
                 fc_key: bytes | None = None) -> None:
        port = free_udp_port()
        (tmp_path / "signing.key").write_text("correct horse battery staple\n")
        (tmp_path / "signing.key").chmod(0o600)
        cfg = tmp_path / "wb.toml"
        cfg.write_text(CONFIG.format(port=port, accept=str(accept_unsigned_from_fc).lower(), allow=allow))
        self.clock = ManualClock(50.0)
        self.servo = LoopBackend(clock=self.clock)
        self.bridge = Bridge(load_config(cfg), servo=self.servo, clock=self.clock)
        assert self.bridge.link.open()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect(("127.0.0.1", port))
        self.sock.setblocking(False)
        self.fc = Peer(FC, fc_key)
        self.rx = mavlink.MAVLink(None)  # checks the bridge's signatures with the key
        self.rx.robust_parsing = True
        self.rx.signing.secret_key = KEY
        self.rx.signing.allow_unsigned_callback = lambda mav, msgid: True
        self.received: list = []
        self.sent = 0

    def send(self, data: bytes) -> None:
        self.sock.send(data)
        self.sent += 1

    def tick(self, n: int = 1, pwm: int | None = None) -> None:
        for i in range(n):
            if pwm is not None:
                if i % 50 == 0:
                    self.send(self.fc.pack(mavlink.MAVLink_heartbeat_message(
                        mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3)))
                if i % 2 == 0:
                    self.send(self.fc.pack(mavlink.MAVLink_servo_output_raw_message(
                        i, 0, pwm, 1500, 0, 0, 0, 0, 0, 0)))
            for _ in range(100):  # wait (bounded) until the bridge can read all that was sent
                if self.bridge.link.counters.datagrams >= self.sent:
                    break
                select.select([self.bridge.link.mav.port.fileno()], [], [], 0.01)
                self.bridge.params.poll(self.bridge.link.poll())
            self.clock.t += 0.01
            self.bridge.tick()
            self.drain()

    def drain(self) -> None:
        self.received.extend(drain_mavlink(self.sock, self.rx))

    def following(self, pwm: int) -> bool:
        want = self.bridge.mixer.setpoints({1: float(pwm)})
        return not self.bridge.failsafe and all(
            math.isclose(self.bridge.wings[w].setpoint, want[w]) for w in want)

    def param_values(self, name: str) -> list[float]:
        return [m.param_value for m in self.received if m.get_type() == "PARAM_VALUE" and m.param_id == name]

    def close(self) -> None:
        self.bridge.close()
        self.sock.close()


@pytest.fixture
def rig(tmp_path):
    r = Rig(tmp_path)
    yield r
    r.close()


def param_set(name: bytes, value: float):
    return mavlink.MAVLink_param_set_message(1, 191, name, value, mavlink.MAV_PARAM_TYPE_REAL32)


def test_signed_set_accepted_unsigned_and_wrongly_signed_refused_and_counted(rig):
    link, store = rig.bridge.link, rig.bridge.store
    rig.tick(20, pwm=1700)
    assert rig.following(1700)  # the FC's unsigned stream keeps working (accepted by the policy)

    rig.send(Peer(GCS, None).pack(param_set(b"WB_KP", 11.0)))
    rig.send(Peer(GCS, WRONG).pack(param_set(b"WB_KP", 12.0)))
    rig.send(Peer(GCS, None).pack(mavlink.MAVLink_command_long_message(1, 191, 246, 0, 1, 0, 0, 0, 0, 0, 0)))
    rig.send(Peer(GCS, WRONG).pack(mavlink.MAVLink_command_long_message(1, 191, 246, 0, 1, 0, 0, 0, 0, 0, 0)))
    rig.tick(10, pwm=1700)
    assert store.get("WB_KP") == 0.5 and all(w.ctl.kp == 0.5 for w in rig.bridge.wings.values())  # the default
    assert link.counters.unsigned_refused == 2 and link.counters.bad_signature == 2
    assert link.counters.refused == {"PARAM_SET": 2, "COMMAND_LONG": 2}
    assert not rig.param_values("WB_KP")  # refused frames never reach the parameter server
    texts = [m.text for m in rig.received if m.get_type() == "STATUSTEXT"]
    assert sum("refused" in t for t in texts) == 1  # reported, not stormed

    good = Peer(GCS, KEY)
    frame = good.pack(param_set(b"WB_KP", 9.5))
    rig.send(frame)
    rig.tick(10, pwm=1700)
    assert store.get("WB_KP") == 9.5 and all(w.ctl.kp == 9.5 for w in rig.bridge.wings.values())
    assert rig.param_values("WB_KP")[-1] == pytest.approx(9.5)

    rig.send(good.pack(param_set(b"WB_KP", 8.0)))
    rig.send(frame)  # replay of the 9.5 set: its timestamp is old now
    rig.tick(10, pwm=1700)
    assert store.get("WB_KP") == 8.0
    assert link.counters.bad_signature == 3
    assert rig.following(1700)


def test_everything_the_bridge_sends_is_signed(rig):
    rig.tick(30, pwm=1500)
    rig.send(Peer(GCS, KEY).pack(mavlink.MAVLink_param_request_list_message(1, 191)))
    rig.tick(100, pwm=1500)
    types = {m.get_type() for m in rig.received}
    assert {"HEARTBEAT", "COMMAND_LONG", "PARAM_VALUE"} <= types
    assert rig.received and all(m._signed for m in rig.received)
    assert len(rig.param_values("WB_KP")) >= 1


def test_forged_future_timestamp_does_not_lock_out_the_ground_station(rig):
    """pymavlink records a stream's timestamp before checking the signature; the bridge does not."""
    rig.tick(5, pwm=1500)
    forger = Peer(GCS, WRONG)
    forger.enc.signing.timestamp = now_timestamp() + 100_000 * 3600 * 24 * 365
    rig.send(forger.pack(param_set(b"WB_KI", 3.0)))
    rig.send(Peer(GCS, KEY).pack(param_set(b"WB_KI", 2.0)))  # same stream (link id 1, 255/190), honest time
    rig.tick(10, pwm=1500)
    assert rig.bridge.store.get("WB_KI") == 2.0


def test_allow_list_applies_to_signed_sets_too(tmp_path):
    r = Rig(tmp_path, allow="[200]")
    try:
        r.tick(5, pwm=1500)
        r.send(Peer(GCS, KEY).pack(param_set(b"WB_KP", 9.0)))  # right key, sysid not allowed
        r.send(Peer(OTHER_GCS, KEY, link_id=2).pack(param_set(b"WB_KI", 2.5)))
        r.tick(10, pwm=1500)
        assert r.bridge.store.get("WB_KP") == 0.5 and r.bridge.store.get("WB_KI") == 2.5
        assert r.param_values("WB_KP")[-1] == pytest.approx(0.5)  # refused: echoed unchanged (the default)
    finally:
        r.close()


def test_fc_stream_must_be_signed_when_unsigned_is_not_accepted(tmp_path):
    r = Rig(tmp_path, accept_unsigned_from_fc=False)
    try:
        r.tick(50, pwm=1800)
        assert r.bridge.failsafe and not r.following(1800)
        assert r.bridge.link.counters.refused.get("SERVO_OUTPUT_RAW", 0) > 10
        r.fc = Peer(FC, KEY)
        r.tick(20, pwm=1800)
        assert r.following(1800)
    finally:
        r.close()


def test_unsigned_stream_from_anyone_but_the_fc_is_refused(rig):
    rig.tick(20, pwm=1300)
    spoof = Peer((1, 50), None)
    other = Peer((9, 1), None)
    for _ in range(20):
        rig.send(spoof.pack(mavlink.MAVLink_servo_output_raw_message(0, 0, 1900, 0, 0, 0, 0, 0, 0, 0)))
        rig.send(other.pack(mavlink.MAVLink_servo_output_raw_message(0, 0, 1900, 0, 0, 0, 0, 0, 0, 0)))
        rig.tick(1)
    assert rig.bridge.link.counters.refused["SERVO_OUTPUT_RAW"] >= 40
    assert rig.following(1300)


def test_signer_keeps_stream_state_across_reconnects():
    class Conn:
        def __init__(self) -> None:
            self.mav = mavlink.MAVLink(None)

        def setup_signing(self, key, sign_outgoing, allow_unsigned_callback, initial_timestamp, link_id):
            s = self.mav.signing
            s.secret_key, s.sign_outgoing, s.allow_unsigned_callback = key, sign_outgoing, allow_unsigned_callback
            s.timestamp, s.link_id = initial_timestamp, link_id

    signer = Signer(KEY)
    first = Conn()
    signer.install(first)
    gcs = Peer(GCS, KEY)
    frame = gcs.pack(param_set(b"WB_KP", 1.0))
    assert first.mav.parse_buffer(frame)[0]._signed
    second = Conn()  # the link was lost and reopened
    signer.install(second)
    assert second.mav.signing.timestamp >= first.mav.signing.timestamp
    assert not second.mav.parse_buffer(frame)[0]._signed  # the replay stays a replay
