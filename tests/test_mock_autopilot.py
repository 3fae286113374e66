"""The mock autopilot: streams on request, commands, ArduPilot-like routing between bridge and GCS."""

from __future__ import annotations

import os
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from helpers import free_udp_port

from warpbridge.bridge.link import FcLink
from warpbridge.bridge.mavlink_env import mavlink, mavutil
from warpbridge.bridge.param_server import ParamServer
from warpbridge.bridge.params import ParamSpec, ParamStore
from warpbridge.bridge.telemetry import Telemetry
from warpbridge.sitl.mock_autopilot import CsvRoll, MockAutopilot, SineRoll, load_scenario

REPO = Path(__file__).resolve().parents[1]


def recv(conn, types, timeout: float = 3.0, cond=None):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        m = conn.recv_match(type=types, blocking=True, timeout=0.05)
        if m is not None and (cond is None or cond(m)):
            return m
    return None


def endpoint(port: int, sysid: int, compid: int):
    return mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=sysid, source_component=compid)


@pytest.fixture
def ends():
    """(mock factory, bridge-side endpoint, gcs endpoint)."""
    fc_port, gcs_port = free_udp_port(), free_udp_port()
    bridge = endpoint(fc_port, 1, 191)
    gcs = endpoint(gcs_port, 255, 190)
    mocks = []

    def make(**kw):
        m = MockAutopilot(fc_port, gcs_port, **kw).start()
        mocks.append(m)
        return m

    yield make, bridge, gcs
    for m in mocks:
        m.stop()
    bridge.close()
    gcs.close()


def say_hello(conn, mav_type=mavlink.MAV_TYPE_GCS) -> None:
    """Wait for the mock's heartbeat, then send ours so the mock learns the route."""
    hb = recv(conn, "HEARTBEAT", cond=lambda m: m.get_srcComponent() == 1)
    assert hb is not None and hb.type == mavlink.MAV_TYPE_FIXED_WING
    conn.mav.heartbeat_send(mav_type, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)


def test_streams_requested_servo_output_with_quantised_jitter(ends):
    make, bridge, _ = ends
    make(autopilot="ardupilot", roll_source=lambda t: {1: 1234.4, 2: 1765.6, 3: float("nan")})
    hb = recv(bridge, "HEARTBEAT")
    assert hb.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA and (hb.get_srcSystem(), hb.get_srcComponent()) == (1, 1)
    bridge.mav.command_long_send(1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 36, 20000, 0, 0, 0, 0, 0)
    ack = recv(bridge, "COMMAND_ACK")
    assert ack.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL and ack.result == mavlink.MAV_RESULT_ACCEPTED
    assert (ack.target_system, ack.target_component) == (1, 191)
    ch1, ch2 = set(), set()
    for _ in range(40):
        m = recv(bridge, "SERVO_OUTPUT_RAW")
        assert m is not None and m.servo3_raw == 0  # NaN: output reported disabled
        ch1.add(m.servo1_raw)
        ch2.add(m.servo2_raw)
    assert ch1 <= {1233, 1234, 1235} and ch2 <= {1765, 1766, 1767}
    assert len(ch1) > 1  # the jitter is there
    bridge.mav.command_long_send(1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 375, 20000, 0, 0, 0, 0, 0)
    ack = recv(bridge, "COMMAND_ACK")
    assert ack.result == mavlink.MAV_RESULT_FAILED  # ArduPilot has no ACTUATOR_OUTPUT_STATUS stream


def test_px4_streams_actuator_output_status_with_output_count(ends):
    make, bridge, _ = ends
    make(autopilot="px4", roll_source=lambda t: {1: 1100.0, 2: 1900.0}, jitter_us=0)
    assert recv(bridge, "HEARTBEAT").autopilot == mavlink.MAV_AUTOPILOT_PX4
    bridge.mav.command_long_send(1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 375, 50000, 0, 0, 0, 0, 0)
    m = recv(bridge, "ACTUATOR_OUTPUT_STATUS")
    assert m.active == 8 and list(m.actuator[:3]) == [1100.0, 1900.0, 0.0]


def test_servo_and_actuator_commands(ends):
    make, bridge, _ = ends
    ap = make(autopilot="ardupilot", roll_source=lambda t: {1: 1500.0}, jitter_us=0)
    recv(bridge, "HEARTBEAT")
    bridge.mav.command_long_send(1, 1, mavlink.MAV_CMD_DO_SET_SERVO, 0, 5, 1712, 0, 0, 0, 0, 0)
    assert recv(bridge, "COMMAND_ACK").result == mavlink.MAV_RESULT_ACCEPTED
    assert ap.servo_commands == {5: 1712.0}
    bridge.mav.command_long_send(1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 36, 50000, 0, 0, 0, 0, 0)
    assert recv(bridge, "SERVO_OUTPUT_RAW").servo5_raw == 1712  # the commanded output shows
    bridge.mav.command_long_send(1, 1, mavlink.MAV_CMD_DO_SET_ACTUATOR, 0, 0.5, 0, 0, 0, 0, 0, 0)
    ack = recv(bridge, "COMMAND_ACK", cond=lambda m: m.command == mavlink.MAV_CMD_DO_SET_ACTUATOR)
    assert ack.result == mavlink.MAV_RESULT_UNSUPPORTED
    assert [c.command for c in ap.commands][:1] == [mavlink.MAV_CMD_DO_SET_SERVO]


def test_a_ground_station_arms_and_disarms_it(ends):
    make, bridge, _ = ends
    ap = make(autopilot="px4")
    armed = mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert not recv(bridge, "HEARTBEAT").base_mode & armed
    bridge.mav.command_long_send(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    assert recv(bridge, "COMMAND_ACK").result == mavlink.MAV_RESULT_ACCEPTED and ap.armed
    assert recv(bridge, "HEARTBEAT", cond=lambda m: m.base_mode & armed) is not None
    bridge.mav.command_long_send(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0.5, 0, 0, 0, 0, 0, 0)
    assert recv(bridge, "COMMAND_ACK").result == mavlink.MAV_RESULT_DENIED and ap.armed
    bridge.mav.command_long_send(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 0, 0, 0, 0, 0, 0)
    assert recv(bridge, "COMMAND_ACK").result == mavlink.MAV_RESULT_ACCEPTED and not ap.armed


def test_routes_gcs_requests_to_the_bridge_and_bridge_messages_to_the_gcs(ends):
    make, bridge, gcs = ends
    mock = make(autopilot="ardupilot")
    say_hello(bridge, mavlink.MAV_TYPE_ONBOARD_CONTROLLER)
    say_hello(gcs)
    deadline = time.monotonic() + 3
    while mock.routes.get((255, 190)) != "gcs" and time.monotonic() < deadline:
        time.sleep(0.005)
    assert mock.routes.get((255, 190)) == "gcs" and mock.routes.get((1, 191)) == "fc"
    # the GCS sees the bridge's heartbeat through the mock (once the mock knows the GCS)
    bridge.mav.heartbeat_send(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    hb = recv(gcs, "HEARTBEAT", cond=lambda m: m.get_srcComponent() == 191)
    assert hb is not None and hb.type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER

    gcs.mav.param_request_read_send(1, 191, b"WB_KP", -1)
    req = recv(bridge, "PARAM_REQUEST_READ")
    assert req is not None and req.param_id == "WB_KP" and req.get_srcSystem() == 255
    bridge.mav.param_value_send(b"WB_KP", 7.0, mavlink.MAV_PARAM_TYPE_REAL32, 1, 0)
    pv = recv(gcs, "PARAM_VALUE", cond=lambda m: m.get_srcComponent() == 191)
    assert pv is not None and pv.param_id == "WB_KP" and pv.param_value == 7.0

    bridge.mav.named_value_float_send(0, b"L_warp", 2.5)
    nv = recv(gcs, "NAMED_VALUE_FLOAT")
    assert nv is not None and nv.name == "L_warp" and (nv.get_srcSystem(), nv.get_srcComponent()) == (1, 191)

    # a command for the autopilot is handled there and not passed to the bridge
    gcs.mav.command_long_send(1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 74, 100000, 0, 0, 0, 0, 0)
    ack = recv(gcs, "COMMAND_ACK")
    assert ack is not None and ack.result == mavlink.MAV_RESULT_ACCEPTED
    assert recv(gcs, "VFR_HUD") is not None  # FC streams reach the GCS
    assert recv(bridge, "COMMAND_LONG", timeout=0.3) is None


def test_tuning_the_real_bridge_through_the_mock(ends, tmp_path):
    make, bridge_end, gcs = ends
    # the bridge side: the real link, parameter server and telemetry instead of the plain endpoint
    port = int(bridge_end.port.getsockname()[1])
    bridge_end.close()
    link = FcLink(f"udpin:127.0.0.1:{port}")
    assert link.open()
    store = ParamStore([ParamSpec("WB_KP", 7.0, 0.0, 50.0, "PI gain")], tmp_path / "p.json")
    server = ParamServer(store, link)
    tlm = Telemetry(link, rate_hz=20)
    stop = threading.Event()

    def loop() -> None:
        while not stop.is_set():
            server.poll(link.poll())
            if link.ready:
                tlm.named_float("L_sp", 1.5)
            time.sleep(0.003)

    mock = make(autopilot="ardupilot")
    th = threading.Thread(target=loop, daemon=True)
    th.start()
    try:
        say_hello(gcs)
        deadline = time.monotonic() + 5
        while not {(1, 191), (255, 190)} <= mock.routes.keys() and time.monotonic() < deadline:
            time.sleep(0.005)
        gcs.mav.param_request_list_send(1, 0)  # QGroundControl asks every component
        names = set()
        deadline = time.monotonic() + 3
        while "WB_KP" not in names and time.monotonic() < deadline:
            m = recv(gcs, "PARAM_VALUE", timeout=0.3)
            if m is not None:
                names.add(m.param_id)
        assert "WB_KP" in names and "SYSID_THISMAV" in names  # the bridge's and the FC's
        gcs.mav.param_set_send(1, 191, b"WB_KP", 11.0, mavlink.MAV_PARAM_TYPE_REAL32)
        pv = recv(gcs, "PARAM_VALUE", cond=lambda m: m.param_id == "WB_KP" and m.param_value == 11.0)
        assert pv is not None and store.get("WB_KP") == 11.0
        nv = recv(gcs, "NAMED_VALUE_FLOAT", cond=lambda m: m.name == "L_sp")
        assert nv is not None and nv.value == 1.5
        assert link.system_id == 1 and link.autopilot == "ardupilot"
    finally:
        stop.set()
        th.join(5)
        link.close()
        store.close()


def test_link_asks_again_after_the_fc_forgets_its_streams(ends):
    make, bridge, _ = ends
    port = int(bridge.port.getsockname()[1])
    bridge.close()
    link = FcLink(f"udpin:127.0.0.1:{port}", servo_rate_hz=50, rerequest_s=0.3)
    assert link.open()
    ap = make(autopilot="px4")
    try:
        assert link.connect(5)
        deadline = time.monotonic() + 5
        while link.servo_time is None and time.monotonic() < deadline:
            link.poll()
            time.sleep(0.005)
        assert link.servo_time is not None and 1 in link.servo_pwm
        asked = link.counters.stream_requests
        ap.pause_streams(0.5, forget=True)  # as if the FC rebooted
        stalled_at = time.monotonic()
        while time.monotonic() < stalled_at + 5:
            link.poll()
            if link.counters.stream_requests > asked and link.servo_time > stalled_at + 0.5:
                break
            time.sleep(0.005)
        assert link.counters.stream_requests > asked
        assert link.servo_time > stalled_at + 0.5  # streaming again
        assert 375 in ap.intervals
    finally:
        link.close()


def test_csv_roll_source_and_scenarios(tmp_path):
    f = tmp_path / "roll.csv"
    f.write_text("t,ch1,ch2,airspeed\n0,1000,2000,10\n1,2000,1000,14\n")
    roll = CsvRoll(f)
    assert roll(0.5) == {1: 1500.0, 2: 1500.0}
    assert roll(5.0) == {1: 2000.0, 2: 1000.0}  # held at the end
    assert roll.airspeed(0.25) == pytest.approx(11.0)
    assert CsvRoll(f, loop=True)(1.5)[1] == pytest.approx(1500.0)
    bad = tmp_path / "bad.csv"
    bad.write_text("time,ch1\n0,1\n")
    with pytest.raises(ValueError, match="'t'"):
        CsvRoll(bad)
    assert isinstance(load_scenario("sine"), SineRoll)
    assert load_scenario("warpbridge.sitl.mock_autopilot:SineRoll") is SineRoll
    with pytest.raises(ValueError):
        load_scenario("nonsense")


def test_runs_as_a_process_with_a_roll_file(tmp_path):
    f = tmp_path / "roll.csv"
    f.write_text("t,ch1,ch2\n0,1300,1700\n100,1300,1700\n")
    port = free_udp_port()
    bridge = endpoint(port, 1, 191)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "warpbridge.sitl.mock_autopilot",
            "--fc-port",
            str(port),
            "--autopilot",
            "px4",
            "--roll-file",
            str(f),
            "--duration",
            "20",
        ],
        env=env,
        cwd=str(tmp_path),
    )
    try:
        hb = recv(bridge, "HEARTBEAT", timeout=10)
        assert hb is not None and hb.autopilot == mavlink.MAV_AUTOPILOT_PX4
        bridge.mav.command_long_send(1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 375, 20000, 0, 0, 0, 0, 0)
        m = recv(bridge, "ACTUATOR_OUTPUT_STATUS")
        assert m is not None
        assert abs(m.actuator[0] - 1300) <= 1 and abs(m.actuator[1] - 1700) <= 1
    finally:
        proc.terminate()
        proc.wait(10)
        bridge.close()
    assert proc.returncode == 0


# ---------------------------------------------------------------------- ground-station outputs, as a SITL's


def listener(port: int):
    """A ground station that only listens on ``port`` (never sends): a raw socket and a parser."""
    import socket

    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", port))
    s.settimeout(0.05)
    return s, mavlink.MAVLink(None)


def heard(sock, parser, cond, timeout: float = 3.0):
    """The first message ``cond`` accepts, with the address it came from, or (None, None)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            data, addr = sock.recvfrom(65536)
        except OSError:
            continue
        for m in parser.parse_buffer(data) or []:
            if m.get_type() != "BAD_DATA" and cond(m):
                return m, addr
    return None, None


def test_a_ground_station_that_only_listens_sees_the_vehicle_and_component_191():
    fc_port, p1, p2 = free_udp_port(), free_udp_port(), free_udp_port()
    bridge = endpoint(fc_port, 1, 191)
    gcs1, parse1 = listener(p1)
    gcs2, parse2 = listener(p2)
    mock = MockAutopilot(fc_port, [f"udp:127.0.0.1:{p1}", p2], autopilot="ardupilot").start()
    try:
        hb, mock_addr = heard(gcs1, parse1, lambda m: m.get_type() == "HEARTBEAT")
        assert hb is not None and (hb.get_srcSystem(), hb.get_srcComponent()) == (1, 1)  # without asking
        say_hello(bridge, mavlink.MAV_TYPE_ONBOARD_CONTROLLER)
        for _ in range(3):
            bridge.mav.heartbeat_send(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            bridge.mav.param_value_send(b"WB_KP", 7.0, mavlink.MAV_PARAM_TYPE_REAL32, 1, 0)
            time.sleep(0.05)
        for sock, parser in ((gcs1, parse1), (gcs2, parse2)):  # both outputs, neither has sent a byte
            hb191, _ = heard(sock, parser, lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 191)
            assert hb191 is not None and hb191.type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER
            pv, _ = heard(sock, parser, lambda m: m.get_type() == "PARAM_VALUE")
            assert pv is not None and pv.param_id == "WB_KP" and pv.get_srcComponent() == 191
        assert mock.gcs_links == ["gcs", "gcs2"]
    finally:
        mock.stop()
        bridge.close()
        gcs1.close()
        gcs2.close()


def test_an_output_replies_to_wherever_the_ground_station_sends_from():
    fc_port, out_port = free_udp_port(), free_udp_port()
    first, parse_first = listener(out_port)
    mock = MockAutopilot(fc_port, out_port, autopilot="px4").start()
    moved, parse_moved = listener(free_udp_port())  # a ground station on another port, e.g. MAVProxy's udpout
    try:
        _, mock_addr = heard(first, parse_first, lambda m: m.get_type() == "HEARTBEAT")
        assert mock_addr is not None
        gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        moved.sendto(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID,
                                                       0, 0, 0, 3).pack(gcs), mock_addr)
        moved.sendto(mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 74, 1e5,
                                                          0, 0, 0, 0, 0).pack(gcs), mock_addr)
        ack, _ = heard(moved, parse_moved, lambda m: m.get_type() == "COMMAND_ACK")
        assert ack is not None and ack.result == mavlink.MAV_RESULT_ACCEPTED
        assert heard(moved, parse_moved, lambda m: m.get_type() == "HEARTBEAT")[0] is not None
        time.sleep(0.3)
        while heard(first, parse_first, lambda m: True, timeout=0.1)[0] is not None:
            pass  # what was already on its way
        assert heard(first, parse_first, lambda m: True, timeout=1.5)[0] is None  # nothing more to the old port
    finally:
        mock.stop()
        first.close()
        moved.close()


def test_ground_station_output_strings():
    from warpbridge.sitl.mock_autopilot import gcs_output_string

    assert gcs_output_string(14550) == "udp:127.0.0.1:14550"
    assert gcs_output_string("udp:127.0.0.1:14550") == "udp:127.0.0.1:14550"
    assert gcs_output_string("udpout:10.0.0.2:14550") == "udpout:10.0.0.2:14550"
    assert gcs_output_string("udpin:0.0.0.0:14551") == "udpin:0.0.0.0:14551"
    assert gcs_output_string("192.168.1.5:14550") == "udp:192.168.1.5:14550"  # MAVProxy --out style
    for bad in ("udp:14550", "udp:host:0", "udp:host:70000", "serial:/dev/x:1", "udp:host:x", ""):
        with pytest.raises(ValueError):
            gcs_output_string(bad)


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_parameter_download_over_ftp_as_the_autopilot_does(ends, autopilot):
    from warpbridge.bridge.mavftp import (
        ERR_FILE_NOT_FOUND,
        OP_ACK,
        OP_BURST_READ_FILE,
        OP_NAK,
        OP_OPEN_FILE_RO,
        FtpOp,
    )

    make, _, gcs = ends
    mock = make(autopilot=autopilot)
    say_hello(gcs)
    path = b"@PARAM/param.pck"
    gcs.mav.file_transfer_protocol_send(0, 1, 1, FtpOp(0, 1, OP_OPEN_FILE_RO, len(path), 0, 0, 0, path).pack())
    reply = recv(gcs, "FILE_TRANSFER_PROTOCOL")
    assert reply is not None and (reply.target_system, reply.target_component) == (255, 190)
    op = FtpOp.parse(reply.payload)
    if autopilot == "px4":  # PX4 has no @PARAM: refused at once, the client falls back to the list
        assert op.opcode == OP_NAK and op.data[0] == ERR_FILE_NOT_FOUND
        return
    assert op.opcode == OP_ACK
    gcs.mav.file_transfer_protocol_send(0, 1, 1, FtpOp(1, 1, OP_BURST_READ_FILE, 200).pack())
    data = b""
    while (m := recv(gcs, "FILE_TRANSFER_PROTOCOL")) is not None:
        op = FtpOp.parse(m.payload)
        if op.opcode != OP_ACK:
            break
        data += op.data
    magic, num, total = struct.unpack("<HHH", data[:6])
    assert (magic, num, total) == (0x671B, len(mock.params), len(mock.params))
    assert b"SYSID_THISMAV" in data
