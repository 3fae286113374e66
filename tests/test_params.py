"""ParamStore validation and persistence, and ParamServer driven by a pymavlink ground station."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import free_udp_port

from warpbridge.bridge.link import FcLink
from warpbridge.bridge.mavlink_env import mavlink, mavutil
from warpbridge.bridge.param_server import ParamServer, param_name
from warpbridge.bridge.params import ParamError, ParamSpec, ParamStore

REPO = Path(__file__).resolve().parents[1]


def specs(applied: list | None = None) -> list[ParamSpec]:
    def on_kp(name: str, value: float) -> None:
        if applied is not None:
            applied.append((name, value))

    def on_lim(name: str, value: float) -> None:
        if value == 13.0:
            raise RuntimeError("servo board refused the limit")

    return [
        ParamSpec("WB_KP", 7.0, 0.0, 50.0, "PI proportional gain, mm/deg", on_set=on_kp),
        ParamSpec("WB_KI", 1.0, 0.0, 10.0, "PI integral gain, mm/(deg s)"),
        ParamSpec("WB_MODE", 3, 0, 3, "0 open, 1 pi, 2 ff, 3 ff+pi", integer=True),
        ParamSpec("WB_DEADBAND", 0.08, 0.0, 0.1, "PI dead band, deg"),
        ParamSpec("WB_LIM_TENDON_MM", 15.0, 0.0, 30.0, "tendon travel limit, mm", on_set=on_lim),
    ]


# ---------------------------------------------------------------------- store


def test_spec_rejects_bad_definitions():
    with pytest.raises(ValueError):
        ParamSpec("WB_THIS_NAME_IS_TOO_LONG", 0, 0, 1, "x")
    with pytest.raises(ValueError):
        ParamSpec("WB_X", 5, 0, 1, "default outside range")
    with pytest.raises(ValueError):
        ParamSpec("WB_X", 0.5, 0, 1, "integer with fraction", integer=True)
    with pytest.raises(ValueError, match="float32"):
        ParamSpec("WB_X", 0.5, 0, 1e39, "a bound MAVLink cannot carry")


def test_set_validates_and_applies_live():
    applied: list = []
    store = ParamStore(specs(applied), None)
    seen: list = []
    store.add_listener(lambda n, v: seen.append((n, v)))
    assert store.set("WB_KP", 9.5) == 9.5 and store.get("WB_KP") == 9.5
    assert applied == [("WB_KP", 9.5)] and seen == [("WB_KP", 9.5)]
    assert store.set("WB_MODE", 2.0) == 2.0
    refusals = {
        ("WB_NOPE", 1.0): "unknown",
        ("WB_KP", float("nan")): "finite",
        ("WB_KP", float("inf")): "finite",
        ("WB_KP", 51.0): "above max",
        ("WB_KP", -0.5): "below min",
        ("WB_KP", "7"): "not a number",
        ("WB_KP", True): "not a number",
        ("WB_MODE", 2.5): "whole number",
        ("WB_LIM_TENDON_MM", 13.0): "not applied",
    }
    for (name, value), why in refusals.items():
        with pytest.raises(ParamError, match=why):
            store.set(name, value)
    assert store.get("WB_KP") == 9.5 and store.get("WB_MODE") == 2.0 and store.get("WB_LIM_TENDON_MM") == 15.0
    assert len(seen) == 2


def test_float32_value_at_a_bound_is_accepted():
    store = ParamStore(specs(), None)
    f32 = float(np.float32(0.1))  # what arrives over MAVLink for 0.1
    assert f32 > 0.1
    assert store.set("WB_DEADBAND", f32) == 0.1


def test_a_value_is_held_at_what_mavlink_carries_of_it(tmp_path):
    """Defaults and bounds that are no short decimal (a model's parameter): the default sent back as float32
    is the default, a value at a bound stays inside the range, and a value set with full precision from
    inside the bridge is not changed by a ground station echoing its float32."""
    default, top = 0.7153734786, 0.9071234567
    path = tmp_path / "p.json"
    store = ParamStore([ParamSpec("WB_BW_A2", default, 0.0, top, "a model parameter")], path)
    assert store.set("WB_BW_A2", float(np.float32(default))) == default
    assert store.get("WB_BW_A2") == default
    assert store.set("WB_BW_A2", float(np.float32(top))) == top  # float32 of the bound: the bound, not above
    assert store.set("WB_BW_A2", float(np.float32(0.7))) == 0.7  # a value a ground station typed, as typed
    inside = store.set("WB_BW_A2", 0.31234567891234)  # from inside the bridge: float32's precision
    assert inside == pytest.approx(0.31234567891234, rel=1e-7)
    assert store.set("WB_BW_A2", float(np.float32(0.31234567891234))) == inside
    store.set("WB_BW_A2", float(np.float32(default)))
    assert store.flush()
    assert json.loads(path.read_text())["params"] == {}  # back at the default: nothing stored
    store.close()


def test_values_persist_across_instances(tmp_path):
    path = tmp_path / "params.json"
    store = ParamStore(specs(), path)
    store.set("WB_KP", 12.0)
    store.set("WB_MODE", 1)
    store.close()
    doc = json.loads(path.read_text())
    assert doc["format"] == "warpbridge-params/1"
    assert doc["params"] == {"WB_KP": 12.0, "WB_MODE": 1.0}  # only what differs from the default
    again = ParamStore(specs(), path)
    assert again.load_report is None
    assert again.get("WB_KP") == 12.0 and again.get("WB_MODE") == 1.0 and again.get("WB_KI") == 1.0
    again.close()


def test_corrupt_file_falls_back_to_defaults_and_is_kept_aside(tmp_path):
    path = tmp_path / "params.json"
    path.write_text('{"format": "warpbridge-params/1", "params": {"WB_KP": 1')  # truncated
    store = ParamStore(specs(), path)
    assert store.get("WB_KP") == 7.0
    assert store.load_report is not None and "corrupt" in store.load_report
    aside = list(tmp_path.glob("params.json.corrupt-*"))
    assert len(aside) == 1 and aside[0].read_text().endswith('"WB_KP": 1')
    assert aside[0].name in store.load_report
    assert not path.exists()
    store.set("WB_KP", 8.0)
    store.close()
    assert ParamStore(specs(), path, background=False).get("WB_KP") == 8.0


def test_invalid_value_in_file_keeps_default(tmp_path):
    path = tmp_path / "params.json"
    path.write_text(json.dumps({"format": "warpbridge-params/1", "params": {"WB_KP": 99.0, "WB_KI": 2.0, "OLD": 1}}))
    store = ParamStore(specs(), path, background=False)
    assert store.get("WB_KP") == 7.0 and store.get("WB_KI") == 2.0
    assert "WB_KP" in store.load_report


WRITER = textwrap.dedent(
    """
    import sys
    from warpbridge.bridge.params import ParamSpec, ParamStore
    specs = [ParamSpec("A", 0, 0, 1000, "a", integer=True), ParamSpec("B", 0, 0, 1000, "b", integer=True)]
    store = ParamStore(specs, sys.argv[1], background=False)
    store.set("A", 1)
    store.set("B", 1)
    print("ready", flush=True)  # writing is under way (on a busy machine the first may come late)
    k = 1
    while True:
        k = k % 999 + 1
        store.set("A", k)
        store.set("B", k)
    """
)


def test_kill_during_writes_never_corrupts(tmp_path):
    path = tmp_path / "params.json"
    rng = random.Random(1)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    kills = 0
    for _ in range(8):
        proc = subprocess.Popen(
            [sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE, env=env, cwd=str(tmp_path)
        )
        assert proc.stdout.readline().strip() == b"ready"
        time.sleep(rng.uniform(0.01, 0.12))
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        kills += 1
        doc = json.loads(path.read_text())  # must always parse
        params = doc["params"]
        a, b = params.get("A", 0.0), params.get("B", 0.0)
        # B is set right after A: a snapshot has B == A or B one step behind
        assert a == b or b == (a - 2) % 999 + 1, (a, b)
        store = ParamStore(
            [ParamSpec("A", 0, 0, 1000, "a", integer=True), ParamSpec("B", 0, 0, 1000, "b", integer=True)],
            path,
            background=False,
        )
        assert store.load_report is None
        assert not list(tmp_path.glob(".params.json.tmp-*"))  # stale temp files cleaned up
    assert kills == 8


# ---------------------------------------------------------------------- server over MAVLink


class Bridge:
    """FcLink + ParamServer run by a thread, as the bridge's loop does."""

    def __init__(self, store: ParamStore, allowed_gcs=None) -> None:
        self.port = free_udp_port()
        self.link = FcLink(f"udpin:127.0.0.1:{self.port}", source_system=1)
        assert self.link.open()
        self.server = ParamServer(store, self.link, allowed_gcs=allowed_gcs)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            self.server.poll(self.link.poll())
            time.sleep(0.002)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.link.close()


@pytest.fixture
def setup(tmp_path):
    store = ParamStore(specs(), tmp_path / "p.json")
    bridge = Bridge(store)
    gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{bridge.port}", source_system=255, source_component=190)
    gcs.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    yield store, bridge, gcs
    gcs.close()
    bridge.close()
    store.close()


def recv(gcs, types, timeout: float = 3.0, cond=None):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        m = gcs.recv_match(type=types, blocking=True, timeout=0.05)
        if m is not None and (cond is None or cond(m)):
            return m
    return None


def test_list_sends_every_parameter_with_count_and_index(setup):
    store, _, gcs = setup
    gcs.mav.param_request_list_send(1, 191)
    got = {}
    deadline = time.monotonic() + 5
    while len(got) < len(store) and time.monotonic() < deadline:
        m = recv(gcs, "PARAM_VALUE", timeout=0.5)
        if m is not None:
            assert m.param_index not in got
            got[m.param_index] = m
    assert sorted(got) == list(range(len(store)))
    for i, m in got.items():
        assert m.param_count == len(store)
        integer = store.specs[store.names[i]].integer  # WB_MODE: announced as an integer, as ArduPilot does
        assert m.param_type == (mavlink.MAV_PARAM_TYPE_INT32 if integer else mavlink.MAV_PARAM_TYPE_REAL32)
        assert (m.get_srcSystem(), m.get_srcComponent()) == (1, 191)
        assert m.param_id == store.names[i]
        assert m.param_value == pytest.approx(store.get(store.names[i]))
    assert "WB_LIM_TENDON_MM" in {m.param_id for m in got.values()}  # 16 chars, no NUL on the wire


def test_read_by_name_and_by_index(setup):
    store, _, gcs = setup
    gcs.mav.param_request_read_send(1, 191, b"WB_KI", -1)
    m = recv(gcs, "PARAM_VALUE")
    assert m.param_id == "WB_KI" and m.param_value == pytest.approx(1.0) and m.param_index == 1
    gcs.mav.param_request_read_send(1, 191, b"ignored", 2)  # index wins over the name
    m = recv(gcs, "PARAM_VALUE")
    assert m.param_id == "WB_MODE" and m.param_index == 2
    gcs.mav.param_request_read_send(1, 191, b"WB_LIM_TENDON_MM", -1)  # 16 chars, no terminator
    m = recv(gcs, "PARAM_VALUE")
    assert m.param_id == "WB_LIM_TENDON_MM" and m.param_value == pytest.approx(15.0)


def test_set_is_applied_echoed_and_persisted(setup, tmp_path):
    store, _, gcs = setup
    gcs.mav.param_set_send(1, 191, b"WB_KP", 9.5, mavlink.MAV_PARAM_TYPE_REAL32)
    m = recv(gcs, "PARAM_VALUE", cond=lambda m: m.param_id == "WB_KP")
    assert m.param_value == pytest.approx(9.5) and m.param_count == len(store) and m.param_index == 0
    assert store.get("WB_KP") == 9.5
    gcs.mav.param_set_send(1, 0, b"WB_KI", 2.3, mavlink.MAV_PARAM_TYPE_REAL32)  # MAV_COMP_ID_ALL
    m = recv(gcs, "PARAM_VALUE", cond=lambda m: m.param_id == "WB_KI")
    assert m.param_value == pytest.approx(2.3)
    gcs.mav.param_set_send(1, 191, b"WB_DEADBAND", 0.08, mavlink.MAV_PARAM_TYPE_REAL32)  # the default again
    recv(gcs, "PARAM_VALUE", cond=lambda m: m.param_id == "WB_DEADBAND")
    assert store.flush()
    # stored as typed, not as float32 read back (2.299999952316284), and the default is not stored
    assert json.loads((tmp_path / "p.json").read_text())["params"] == {"WB_KP": 9.5, "WB_KI": 2.3}


def echo_and_text(gcs, name: str):
    """The PARAM_VALUE echo for ``name`` and the STATUSTEXT, in whichever order they come."""
    echo = text = None
    deadline = time.monotonic() + 3
    while (echo is None or text is None) and time.monotonic() < deadline:
        m = gcs.recv_match(type=["PARAM_VALUE", "STATUSTEXT"], blocking=True, timeout=0.05)
        if m is None:
            continue
        if m.get_type() == "STATUSTEXT":
            text = m
        elif m.param_id == name:
            echo = m
    return echo, text


def test_refused_set_echoes_old_value_and_says_why(setup):
    store, _, gcs = setup
    gcs.mav.param_set_send(1, 191, b"WB_KP", 999.0, mavlink.MAV_PARAM_TYPE_REAL32)
    echo, text = echo_and_text(gcs, "WB_KP")
    assert echo.param_value == pytest.approx(7.0)
    assert "WB_KP" in text.text and "max" in text.text
    assert text.severity == mavlink.MAV_SEVERITY_WARNING

    gcs.mav.param_set_send(1, 191, b"WB_MODE", 2.5, mavlink.MAV_PARAM_TYPE_REAL32)
    echo, text = echo_and_text(gcs, "WB_MODE")
    assert echo.param_value == pytest.approx(3.0)
    assert "whole number" in text.text

    gcs.mav.param_set_send(1, 191, b"WB_NOPE", 1.0, mavlink.MAV_PARAM_TYPE_REAL32)
    assert "unknown" in recv(gcs, "STATUSTEXT").text
    assert store.get("WB_KP") == 7.0 and store.get("WB_MODE") == 3.0


def test_sets_addressed_elsewhere_are_ignored(setup):
    store, _, gcs = setup
    gcs.mav.param_set_send(1, 1, b"WB_KP", 20.0, mavlink.MAV_PARAM_TYPE_REAL32)  # to the autopilot
    gcs.mav.param_set_send(2, 191, b"WB_KP", 21.0, mavlink.MAV_PARAM_TYPE_REAL32)  # another vehicle
    gcs.mav.param_request_read_send(1, 191, b"WB_KP", -1)
    m = recv(gcs, "PARAM_VALUE")
    assert m.param_id == "WB_KP" and m.param_value == pytest.approx(7.0)
    assert store.get("WB_KP") == 7.0


def test_allow_list_refuses_other_ground_stations(tmp_path):
    store = ParamStore(specs(), None)
    bridge = Bridge(store, allowed_gcs=[200])
    gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{bridge.port}", source_system=255, source_component=190)
    try:
        gcs.mav.param_set_send(1, 191, b"WB_KP", 9.0, mavlink.MAV_PARAM_TYPE_REAL32)
        echo, text = echo_and_text(gcs, "WB_KP")
        assert echo.param_value == pytest.approx(7.0) and store.get("WB_KP") == 7.0
        assert "255" in text.text
    finally:
        gcs.close()
        bridge.close()


def test_param_name_with_and_without_terminator():
    assert param_name(b"WB_KP\x00\x00junk") == "WB_KP"
    assert param_name("WB_LIM_TENDON_MM") == "WB_LIM_TENDON_MM"
    assert param_name(b"ABCDEFGHIJKLMNOP") == "ABCDEFGHIJKLMNOP"


# ---------------------------------------------------------------------- types and repeated refusals, server level


class FakeLink:
    """What ParamServer needs of FcLink; ``autopilot`` is the FC's firmware as the link saw it."""

    system_id, component_id = 1, 191

    def __init__(self, autopilot: str | None) -> None:
        self.autopilot = autopilot
        self.sent: list = []
        self.texts: list[str] = []

    def send(self, msg) -> bool:
        self.sent.append(msg)
        return True

    def send_statustext(self, severity: int, text: str) -> bool:
        self.texts.append(text)
        return True

    def values(self) -> list:
        out = [m for m in self.sent if m.get_type() == "PARAM_VALUE"]
        self.sent.clear()
        return out


def wire(msg, src=(255, 190)):
    """``msg`` packed by a ground station and parsed back, as it arrives at the bridge."""
    frame = msg.pack(mavlink.MAVLink(None, srcSystem=src[0], srcComponent=src[1]))
    return mavlink.MAVLink(None).parse_buffer(frame)[0]


def f32_bits(x: float) -> bytes:
    return np.float32(x).tobytes()


def int_bits(n: int) -> bytes:
    return np.int32(n).tobytes()


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4", None])
def test_integer_parameters_travel_as_int32_encoded_as_the_flight_controller_does(autopilot):
    store = ParamStore(specs(), None)
    store.set("WB_MODE", 2)
    link = FakeLink(autopilot)
    server = ParamServer(store, link, clock=lambda: 0.0)
    server.poll([wire(mavlink.MAVLink_param_request_list_message(1, 191))])
    got = {param_name(m.param_id): m for m in wire_all(link.values())}
    mode, kp = got["WB_MODE"], got["WB_KP"]
    assert kp.param_type == mavlink.MAV_PARAM_TYPE_REAL32 and kp.param_value == pytest.approx(7.0)
    assert mode.param_type == mavlink.MAV_PARAM_TYPE_INT32
    if autopilot == "px4":  # PX4: the int32's bytes in the float field (a denormal float)
        assert f32_bits(mode.param_value) == int_bits(2)
    else:  # ArduPilot (and an FC not yet seen): the value cast to float
        assert mode.param_value == 2.0


def wire_all(msgs: list) -> list:
    return [wire(m, src=(1, 191)) for m in msgs]


@pytest.mark.parametrize("autopilot, raw, ptype, expect", [
    ("ardupilot", 1.0, mavlink.MAV_PARAM_TYPE_INT32, 1.0),  # MAVSDK / QGC to an ArduPilot: cast
    ("ardupilot", 0.0, mavlink.MAV_PARAM_TYPE_INT8, 0.0),
    ("ardupilot", 2.0, mavlink.MAV_PARAM_TYPE_REAL32, 2.0),  # MAVProxy sends REAL32 on ArduPilot
    ("ardupilot", np.frombuffer(int_bits(1), np.float32)[0], mavlink.MAV_PARAM_TYPE_INT32, None),  # not whole
    ("px4", np.frombuffer(int_bits(1), np.float32)[0], mavlink.MAV_PARAM_TYPE_INT32, 1.0),  # byte-wise
    ("px4", np.frombuffer(bytes([2, 0, 0, 0]), np.float32)[0], mavlink.MAV_PARAM_TYPE_UINT8, 2.0),
    ("px4", 2.0, mavlink.MAV_PARAM_TYPE_REAL32, 2.0),
    ("px4", 2.0, mavlink.MAV_PARAM_TYPE_REAL64, None),  # a type the float field cannot carry
    ("ardupilot", 2.0, 0, None),  # not a MAV_PARAM_TYPE
])
def test_param_set_of_an_integer_is_read_as_the_flight_controller_encodes_it(autopilot, raw, ptype, expect):
    store = ParamStore(specs(), None)
    link = FakeLink(autopilot)
    server = ParamServer(store, link, clock=lambda: 0.0)
    server.poll([wire(mavlink.MAVLink_param_set_message(1, 191, b"WB_MODE", float(raw), ptype))])
    echo = wire_all(link.values())
    assert [param_name(m.param_id) for m in echo] == ["WB_MODE"]
    if expect is None:
        assert store.get("WB_MODE") == 3.0 and len(link.texts) == 1
    else:
        assert store.get("WB_MODE") == expect and link.texts == []


def test_a_refused_set_retried_by_the_client_is_reported_once():
    store = ParamStore(specs(), None)
    link = FakeLink("ardupilot")
    clock = [0.0]
    server = ParamServer(store, link, clock=lambda: clock[0])
    bad = wire(mavlink.MAVLink_param_set_message(1, 191, b"WB_KP", 500.0, mavlink.MAV_PARAM_TYPE_REAL32))
    for _ in range(3):  # MAVProxy and MAVSDK re-send a set whose echo differs, about once a second
        server.poll([bad])
        clock[0] += 1.0
    assert len(link.texts) == 1 and "WB_KP" in link.texts[0]
    assert len(link.values()) == 3  # every retry is still answered with the unchanged value
    assert server.refused == 3 and server.repeats == 2
    other = wire(mavlink.MAVLink_param_set_message(1, 191, b"WB_KP", 600.0, mavlink.MAV_PARAM_TYPE_REAL32))
    server.poll([other])  # another value: a new refusal
    assert len(link.texts) == 2
    server.poll([wire(mavlink.MAVLink_param_set_message(1, 191, b"WB_NOPE", 1.0, mavlink.MAV_PARAM_TYPE_REAL32))])
    server.poll([wire(mavlink.MAVLink_param_set_message(1, 191, b"WB_NOPE", 1.0, mavlink.MAV_PARAM_TYPE_REAL32))])
    assert len(link.texts) == 3 and "unknown" in link.texts[-1]
    clock[0] += 10.0  # much later the same set again: the user tried again, say so again
    server.poll([bad])
    assert len(link.texts) == 4
    # another ground station sending the same bad value is told too
    server.poll([wire(mavlink.MAVLink_param_set_message(1, 191, b"WB_KP", 500.0, mavlink.MAV_PARAM_TYPE_REAL32),
                      src=(254, 190))])
    assert len(link.texts) == 5
