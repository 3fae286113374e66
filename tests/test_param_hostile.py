"""Hostile PARAM_SET and a hostile parameter file.

Every kind of bad PARAM_SET leaves the stored and the live values unchanged and is answered as the
protocol expects (known name: PARAM_VALUE with the unchanged value + STATUSTEXT; unknown name:
STATUSTEXT; addressed elsewhere or broadcast-unknown: nothing). The persisted file survives a kill at
every statement of a write, and a corrupt file at start-up falls back to defaults, is kept aside and
reported."""

from __future__ import annotations

import json
import math
import os
import select
import signal
import socket
import struct
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from helpers import LOOP_SERVO_WINGS, ManualClock, free_udp_port
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from warpbridge.bridge.app import Bridge
from warpbridge.bridge.config import load_config
from warpbridge.bridge.mavlink_env import mavlink
from warpbridge.bridge.param_server import ParamServer, param_name
from warpbridge.bridge.params import FORMAT, ParamSpec, ParamStore
from warpbridge.hw.loop import LoopBackend

REPO = Path(__file__).resolve().parents[1]
REAL32 = mavlink.MAV_PARAM_TYPE_REAL32


CONFIG = """
[link]
connection = "udpin:127.0.0.1:{port}"
source_system = 1
[loop]
rate_hz = 100
[params]
file = "params.json"
""" + LOOP_SERVO_WINGS


class Rig:
    """The bridge in lock-step with a ground station (255/190) on real loopback UDP."""

    def __init__(self, tmp_path: Path) -> None:
        port = free_udp_port()
        cfg = tmp_path / "wb.toml"
        cfg.write_text(CONFIG.format(port=port))
        self.clock = ManualClock(10.0)
        self.bridge = Bridge(load_config(cfg), servo=LoopBackend(), clock=self.clock)
        assert self.bridge.link.open()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect(("127.0.0.1", port))
        self.sock.setblocking(False)
        self.gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        self.fc = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.rx = mavlink.MAVLink(None)
        self.rx.robust_parsing = True
        self.received: list = []
        self.sent = 0
        self.send(mavlink.MAVLink_heartbeat_message(1, 3, 0, 0, 4, 3).pack(self.fc))
        self.tick(5)

    def send(self, data: bytes) -> None:
        self.sock.send(data)
        self.sent += 1

    def send_set(self, name: bytes, value: float, ptype: int = REAL32, target=(1, 191)) -> None:
        self.send(mavlink.MAVLink_param_set_message(target[0], target[1], name, value, ptype).pack(self.gcs))

    def tick(self, n: int = 1) -> None:
        link = self.bridge.link
        for _ in range(n):
            for _ in range(20):  # until the bridge has read all that was sent (bounded)
                if link.counters.datagrams >= self.sent:
                    break
                select.select([link.mav.port.fileno()], [], [], 0.005)
                self.bridge.params.poll(link.poll())
            self.clock.t += 0.01
            self.bridge.tick()
            while True:
                try:
                    data = self.sock.recv(65536)
                except (BlockingIOError, ConnectionRefusedError):
                    break
                self.received.extend(self.rx.parse_buffer(data) or [])

    def take(self, mtype: str) -> list:
        got = [m for m in self.received if m.get_type() == mtype]
        self.received = [m for m in self.received if m.get_type() != mtype]
        return got

    def live(self) -> dict:
        """The values in use by the running parts, beside the stored ones."""
        b = self.bridge
        ctl = b.wings["left"].ctl
        return {"mode": ctl.mode, "kp": ctl.kp, "ki": ctl.ki, "i_max": ctl.i_max,
                "max_warp": b.mixer.wings["left"].max_warp_deg, "fs": b.fs_timeout,
                "tlm": b.telemetry.rate_hz, "srv_hz": b.link.servo_rate_hz, "model": b.model}

    def close(self) -> None:
        self.bridge.close()
        self.sock.close()


@pytest.fixture
def rig(tmp_path):
    r = Rig(tmp_path)
    yield r
    r.close()


def bytewise_int(n: int) -> float:
    """An INT32 value encoded byte-wise into the float field, as PX4 and QGroundControl do."""
    return struct.unpack("<f", struct.pack("<i", n))[0]


# (what, name, value, param_type, target, reply): reply "echo" = PARAM_VALUE (unchanged) + STATUSTEXT,
# "text" = STATUSTEXT only, "none" = no answer at all
BAD_SETS = [
    ("unknown id", b"WB_NOPE", 1.0, REAL32, (1, 191), "text"),
    ("16-char unknown id, no NUL", b"WB_KPXXXXXXXXXXX", 1.0, REAL32, (1, 191), "text"),
    ("non-ASCII id", b"WB_\xff\x01\n\x1b[2J", 1.0, REAL32, (1, 191), "text"),
    ("INT32 byte-wise to an ArduPilot", b"WB_MODE", bytewise_int(1), mavlink.MAV_PARAM_TYPE_INT32, (1, 191), "echo"),
    ("type 0", b"WB_KP", 9.0, 0, (1, 191), "echo"),
    ("REAL64", b"WB_KP", 9.0, mavlink.MAV_PARAM_TYPE_REAL64, (1, 191), "echo"),
    ("UINT8, not whole", b"WB_MODE", 1.5, mavlink.MAV_PARAM_TYPE_UINT8, (1, 191), "echo"),
    ("NaN", b"WB_KP", math.nan, REAL32, (1, 191), "echo"),
    ("+inf", b"WB_KI", math.inf, REAL32, (1, 191), "echo"),
    ("-inf", b"WB_I_MAX", -math.inf, REAL32, (1, 191), "echo"),
    ("above max", b"WB_KP", 51.0, REAL32, (1, 191), "echo"),
    ("below min", b"WB_FS_TMO", 0.0, REAL32, (1, 191), "echo"),
    ("float32 max", b"WB_SRV_HZ", 3.4028234663852886e38, REAL32, (1, 191), "echo"),
    ("not whole", b"WB_MODE", 2.5, REAL32, (1, 191), "echo"),
    ("to the autopilot", b"WB_KP", 9.0, REAL32, (1, 1), "none"),
    ("to another system", b"WB_KP", 9.0, REAL32, (2, 191), "none"),
    ("to system 0", b"WB_KP", 9.0, REAL32, (0, 191), "none"),
    ("broadcast, unknown id", b"RLL2SRV_P", 0.5, REAL32, (1, 0), "none"),
]


@pytest.mark.parametrize("what, name, value, ptype, target, reply", BAD_SETS, ids=[c[0] for c in BAD_SETS])
def test_bad_param_set_changes_nothing_and_is_answered_as_the_protocol_expects(
        rig, what, name, value, ptype, target, reply):
    stored, live = rig.bridge.store.values(), rig.live()
    rig.take("PARAM_VALUE"), rig.take("STATUSTEXT")
    rig.send_set(name, value, ptype, target)
    rig.tick(10)
    assert rig.bridge.store.values() == stored
    assert rig.live() == live
    values, texts = rig.take("PARAM_VALUE"), rig.take("STATUSTEXT")
    if reply == "echo":
        pname = name.decode()
        ptype_out = mavlink.MAV_PARAM_TYPE_INT32 if rig.bridge.store.specs[pname].integer else REAL32
        assert [(m.param_id, m.param_type) for m in values] == [(pname, ptype_out)]
        assert values[0].param_value == pytest.approx(stored[pname])
        assert values[0].param_index == rig.bridge.store.index(pname)
        assert values[0].param_count == len(rig.bridge.store)
        assert len(texts) == 1 and pname in texts[0].text
    elif reply == "text":
        assert values == [] and len(texts) == 1 and "unknown" in texts[0].text
        assert all(" " <= c <= "~" for c in texts[0].text)  # no control characters relayed
    else:
        assert values == [] and texts == []
    assert rig.bridge.store.flush()
    path = rig.bridge.config.params_file
    assert not path.exists() or json.loads(path.read_text())["params"] == {}


def test_a_good_set_still_works_after_the_bad_ones(rig):
    for _what, name, value, ptype, target, _ in BAD_SETS:
        rig.send_set(name, value, ptype, target)
    rig.send_set(b"WB_KP", 9.5)
    rig.tick(20)
    assert rig.bridge.store.get("WB_KP") == 9.5 and rig.live()["kp"] == 9.5
    assert any(m.param_id == "WB_KP" and m.param_value == pytest.approx(9.5) for m in rig.take("PARAM_VALUE"))


def test_a_flood_of_bad_sets_does_not_flood_the_radio(rig):
    for k in range(300):  # 3000 a second for 0.1 s
        rig.send_set(b"WB_KP", 1000.0 + k)
        if k % 30 == 29:
            rig.tick()
    rig.tick(90)
    texts = [m for m in rig.take("STATUSTEXT") if m.text.startswith("param ")]  # not the start-up messages
    assert 1 <= len(texts) <= 7  # burst of 5, then 1/s
    assert rig.bridge.params.refused == 300
    assert len(rig.take("PARAM_VALUE")) <= 60  # echoes paced (and deduplicated)
    assert rig.bridge.store.get("WB_KP") == 0.5  # the default, unchanged


# ---------------------------------------------------------------------------- property, server level


class FakeLink:
    system_id, component_id = 1, 191
    autopilot = "ardupilot"  # integers cast into the float field

    def __init__(self) -> None:
        self.sent: list = []
        self.texts: list[str] = []

    def send(self, msg) -> bool:
        self.sent.append(msg)
        return True

    def send_statustext(self, severity: int, text: str) -> bool:
        self.texts.append(text)
        return True


SPECS = [
    ParamSpec("WB_KP", 7.0, 0.0, 50.0, "gain"),
    ParamSpec("WB_MODE", 3, 0, 3, "mode", integer=True),
    ParamSpec("WB_LIM_TENDON_MM", 15.0, 0.0, 30.0, "16 characters, sent without a NUL"),
]


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(name=st.one_of(st.sampled_from([b"WB_KP", b"WB_MODE", b"WB_LIM_TENDON_MM", b"WB_LIM_TENDON_M",
                                       b"WB_KP\x00junk"]), st.binary(max_size=16)),
       value=st.floats(width=32), ptype=st.one_of(st.just(REAL32), st.integers(0, 255)),
       ts=st.sampled_from([0, 1, 2, 255]), tc=st.sampled_from([0, 1, 191, 190]), src=st.integers(1, 255))
def test_any_param_set_changes_a_value_only_when_valid(name, value, ptype, ts, tc, src):
    store = ParamStore(SPECS, None)
    link = FakeLink()
    server = ParamServer(store, link, clock=lambda: 0.0)
    enc = mavlink.MAVLink(None, srcSystem=src, srcComponent=190)
    frame = mavlink.MAVLink_param_set_message(ts, tc, name, value, ptype).pack(enc)
    msg = mavlink.MAVLink(None).parse_buffer(frame)[0]  # the bytes as they arrive
    before = store.values()
    server.poll([msg])
    pname = name.split(b"\x00")[0].decode("ascii", "replace")
    ours = ts == 1 and tc in (0, 191)
    spec = store.specs.get(pname)
    wire = msg.param_value
    # REAL32 and the integer types 1..6, cast as ArduPilot does; an integer's bytes (a denormal) refused
    readable = ptype == REAL32 or (1 <= ptype <= 6 and not (wire != 0 and abs(wire) < 1.1754943508222875e-38))
    valid = (spec is not None and readable and math.isfinite(wire)
             and spec.min - 1e-6 * max(1, abs(spec.min)) <= wire <= spec.max + 1e-6 * max(1, abs(spec.max))
             and (not spec.integer or abs(wire - round(wire)) < 1e-6 * max(1, abs(wire))))
    after = store.values()
    if ours and valid:
        assert after[pname] == spec.validate(wire)
        assert {k: v for k, v in after.items() if k != pname} == {k: v for k, v in before.items() if k != pname}
    else:
        assert after == before
    echoes = [m for m in link.sent if m.get_type() == "PARAM_VALUE"]
    if ours and spec is not None:
        assert len(echoes) == 1 and param_name(echoes[0].param_id) == pname
        assert echoes[0].param_value == after[pname]
        assert echoes[0].param_type == (mavlink.MAV_PARAM_TYPE_INT32 if spec.integer else REAL32)
    else:
        assert echoes == []
    if not ours or (spec is None and tc == 0):
        assert link.texts == []
    elif not valid:
        assert len(link.texts) == 1


# ---------------------------------------------------------------------------- the file: kills


KILLER = textwrap.dedent(
    """
    import os, signal, sys
    from warpbridge.bridge import params
    from warpbridge.bridge.params import ParamSpec, ParamStore
    path, kill_at = sys.argv[1], int(sys.argv[2])
    specs = [ParamSpec("A", 0, 0, 1000, "a", integer=True), ParamSpec("B", 0, 0, 1000, "b")]
    store = ParamStore(specs, path, background=False)
    old = store.get("A")
    store.set("A", 1 if old != 1 else 2)  # persisted first: the 'old' state of the next write
    lines = 0
    def tracer(frame, event, arg):
        global lines
        if frame.f_code.co_filename != params.__file__:
            return None
        if event == "line":
            lines += 1
            if lines == kill_at:
                os.kill(os.getpid(), signal.SIGKILL)
        return tracer
    sys.settrace(tracer)
    store.set("B", 123.5)
    sys.settrace(None)
    print("finished", lines, flush=True)
    """
)


@pytest.mark.slow
def test_kill_at_every_statement_of_a_write_leaves_old_or_new(tmp_path):
    """SIGKILL at each line executed in bridge.params during a set + save, one run per line."""
    path = tmp_path / "params.json"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    specs = [ParamSpec("A", 0, 0, 1000, "a", integer=True), ParamSpec("B", 0, 0, 1000, "b")]
    kill_at, killed, saw_old, saw_new = 1, 0, 0, 0
    while True:
        proc = subprocess.run([sys.executable, "-c", KILLER, str(path), str(kill_at)], env=env,
                              capture_output=True, text=True, timeout=60)
        store = ParamStore(specs, path, background=False)
        assert store.load_report is None, (kill_at, store.load_report)
        assert store.get("A") in (1.0, 2.0)
        assert store.get("B") in (0.0, 123.5)  # old or new, nothing else
        assert not list(tmp_path.glob(".params.json.tmp-*"))  # stale temporary files removed
        if proc.returncode == -signal.SIGKILL:
            killed += 1
            saw_new += store.get("B") == 123.5
            saw_old += store.get("B") == 0.0
            path.write_text(json.dumps({"format": FORMAT, "params": {"A": store.get("A")}}))  # reset B
            kill_at += 1
            continue
        assert proc.returncode == 0 and proc.stdout.startswith("finished"), proc.stderr
        assert store.get("B") == 123.5
        break
    assert killed >= 15 and saw_old and saw_new  # killed before and after the file was replaced


# ---------------------------------------------------------------------------- the file: corrupt


VALID = json.dumps({"format": FORMAT, "params": {"WB_KP": 9.0, "WB_MODE": 1}}, indent=1) + "\n"


def corruptions():
    b = VALID.encode()
    return st.one_of(
        st.integers(0, len(b) - 1).map(lambda n: b[:n]),  # truncated (power cut on a bad filesystem)
        st.tuples(st.integers(0, len(b) - 1), st.integers(1, 255)).map(
            lambda t: b[:t[0]] + bytes([b[t[0]] ^ t[1]]) + b[t[0] + 1:]),  # a byte flipped
        st.binary(max_size=200),  # garbage
        st.just(b"\xff\xfe" + b"\x00" * 10),  # not UTF-8
        st.just(b"[" * 100000),  # nested past the recursion limit
        st.just(json.dumps({"format": FORMAT, "params": []}).encode()),
        st.just(json.dumps({"format": "warpbridge-params/99", "params": {}}).encode()),
        st.just(b'{"format": "warpbridge-params/1", "params": {"WB_KP": 1e999, "WB_KI": NaN}}'),
        st.just(b'{"format": "warpbridge-params/1", "params": {"WB_KP": 1' + b"0" * 400 + b"}}"),
        st.just(b'{"format": "warpbridge-params/1", "params": {"WB_KP": "9", "WB_MODE": true, "WB_KI": null}}'),
    )


SPECS_FILE = [ParamSpec("WB_KP", 7.0, 0.0, 50.0, "gain"), ParamSpec("WB_KI", 1.0, 0.0, 50.0, "gain"),
              ParamSpec("WB_MODE", 3, 0, 3, "mode", integer=True)]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(content=corruptions())
def test_any_corrupt_file_falls_back_kept_aside_and_reported(tmp_path_factory, content):
    folder = tmp_path_factory.mktemp("p")
    path = folder / "params.json"
    path.write_bytes(content)
    store = ParamStore(SPECS_FILE, path, background=False)  # never raises
    vals = store.values()
    for name, spec in store.specs.items():
        assert math.isfinite(vals[name]) and spec.min <= vals[name] <= spec.max
    aside = list(folder.glob("params.json.corrupt-*"))
    if path.exists():  # it parsed: kept in place; each value the file's or the default, bad ones reported
        assert aside == []
        # a flipped byte can leave a valid file with other values (9 -> 1): each value is the file's or
        # the default, and a value the file gives but the store refused is reported
        given = json.loads(content.decode())["params"]
        default = {"WB_KP": 7.0, "WB_KI": 1.0, "WB_MODE": 3.0}
        for k, v in vals.items():
            g = given.get(k)
            from_file = isinstance(g, (int, float)) and not isinstance(g, bool) and abs(g) < 1e300 and float(g) == v
            assert from_file or v == default[k]
            if k in given and not from_file:
                assert store.load_report is not None
    else:
        assert vals == {"WB_KP": 7.0, "WB_KI": 1.0, "WB_MODE": 3.0}
        assert len(aside) == 1 and aside[0].read_bytes() == content  # the bad file kept, byte for byte
        assert "corrupt" in store.load_report and aside[0].name in store.load_report
        assert "\n" not in store.load_report
    store.set("WB_KP", 8.0)  # and it can be written again
    assert ParamStore(SPECS_FILE, path, background=False).get("WB_KP") == 8.0


def test_bridge_reports_a_corrupt_file_at_start_up(tmp_path):
    (tmp_path / "params.json").write_bytes(b'{"format": "warpbridge-params/1", "params": {"WB_KP": 9')
    r = Rig(tmp_path)
    try:
        texts = [m.text for m in r.take("STATUSTEXT")]
        assert any("corrupt" in t and "defaults" in t for t in texts), texts
        assert r.bridge.store.get("WB_KP") == 0.5 and r.live()["kp"] == 0.5  # the defaults
        assert len(list(tmp_path.glob("params.json.corrupt-*"))) == 1
    finally:
        r.close()
