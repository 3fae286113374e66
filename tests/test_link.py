"""FcLink against a pymavlink peer acting as the flight controller on loopback UDP/TCP."""

from __future__ import annotations

import math
import socket
import time

import pytest
from helpers import free_udp_port

from warpbridge.bridge.link import FcLink
from warpbridge.bridge.mavlink_env import mavlink, mavutil
from warpbridge.bridge.telemetry import Telemetry


class FakeClock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def pump(link: FcLink, until, timeout: float = 3.0, collect: list | None = None) -> bool:
    """Poll the link until ``until()`` holds (real-time limit only against hangs)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        msgs = link.poll()
        if collect is not None:
            collect.extend(msgs)
        if until():
            return True
        time.sleep(0.002)
    return False


def recv_types(peer, types, timeout: float = 3.0, cond=None):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        m = peer.recv_match(type=types, blocking=True, timeout=0.05)
        if m is not None and (cond is None or cond(m)):
            return m
    return None


@pytest.fixture
def pair():
    """(link, fc_peer, clock): the link listens (udpin), the peer is the FC (system 7)."""
    port = free_udp_port()
    clock = FakeClock()
    link = FcLink(f"udpin:127.0.0.1:{port}", servo_rate_hz=50, airspeed_rate_hz=10, rerequest_s=1.0, clock=clock)
    assert link.open()
    peer = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=7, source_component=1)
    yield link, peer, clock
    link.close()
    peer.close()


def fc_heartbeat(peer, autopilot=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, armed=False) -> None:
    base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    peer.mav.heartbeat_send(mavlink.MAV_TYPE_FIXED_WING, autopilot, base, 0, mavlink.MAV_STATE_ACTIVE)


def interval_request(msg_id: int):
    return lambda m: m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL and int(m.param1) == msg_id


def test_adopts_fc_system_ignores_gcs_and_requests_streams(pair):
    link, peer, _ = pair
    # a ground station's heartbeat on the same link must not be taken for the FC
    peer.mav.srcSystem, peer.mav.srcComponent = 255, 190
    peer.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    assert pump(link, lambda: link.counters.received >= 1)
    assert link.system_id is None and link.autopilot is None
    peer.mav.srcSystem, peer.mav.srcComponent = 7, 1
    fc_heartbeat(peer, armed=True)
    assert pump(link, lambda: link.system_id is not None)
    assert link.system_id == 7 and link.autopilot == "ardupilot" and link.armed

    hb = recv_types(peer, "HEARTBEAT")
    assert hb is not None
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (7, 191)
    assert hb.type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER and hb.autopilot == mavlink.MAV_AUTOPILOT_INVALID
    assert hb.get_msgbuf()[0] == 0xFD  # MAVLink 2 frame

    servo = recv_types(peer, "COMMAND_LONG", cond=interval_request(36))
    assert servo is not None
    assert (servo.target_system, servo.target_component) == (7, 1)
    assert servo.param2 == pytest.approx(20000.0)  # 50 Hz in us
    hud = recv_types(peer, "COMMAND_LONG", cond=interval_request(74))
    assert hud is not None and hud.param2 == pytest.approx(100000.0)

    peer.mav.command_ack_send(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAV_RESULT_ACCEPTED, 0, 0, 7, 191)
    assert pump(link, lambda: mavlink.MAV_CMD_SET_MESSAGE_INTERVAL in link.acks)
    assert link.acks[mavlink.MAV_CMD_SET_MESSAGE_INTERVAL] == mavlink.MAV_RESULT_ACCEPTED


def test_px4_asks_for_actuator_output_status_and_reads_count(pair):
    link, peer, _ = pair
    fc_heartbeat(peer, autopilot=mavlink.MAV_AUTOPILOT_PX4)
    assert pump(link, lambda: link.autopilot == "px4")
    assert recv_types(peer, "COMMAND_LONG", cond=interval_request(375)) is not None
    assert recv_types(peer, "COMMAND_LONG", cond=interval_request(36)) is not None
    # PX4 fills "active" with the number of outputs
    values = [1100.0, 1200.0, 1300.0, 1400.0] + [0.0] * 28
    peer.mav.actuator_output_status_send(123, 4, values)
    assert pump(link, lambda: link.servo_time is not None)
    assert link.servo_pwm == {1: 1100.0, 2: 1200.0, 3: 1300.0, 4: 1400.0}


def test_servo_output_raw_port_offset_and_absurd_values(pair):
    link, peer, _ = pair
    fc_heartbeat(peer)
    assert pump(link, lambda: link.system_id == 7)
    peer.mav.servo_output_raw_send(1, 0, 1500, 0, 65535, 1234, 900, 2100, 1000, 2000, *([0] * 8))
    peer.mav.servo_output_raw_send(2, 1, 1600, *([0] * 15))  # outputs 17..32
    assert pump(link, lambda: link.counters.servo_messages >= 2)
    assert link.servo_pwm[1] == 1500 and link.servo_pwm[4] == 1234 and link.servo_pwm[17] == 1600
    assert 2 not in link.servo_pwm and 3 not in link.servo_pwm
    assert {2, 3} <= link.servo_invalid
    assert link.servo_raw[3] == 65535
    assert link.counters.invalid_values >= 1
    assert 9 not in link.servo_raw  # 8-output message: extension fields not taken as outputs

    peer.mav.vfr_hud_send(14.5, 15.0, 90, 40, 100.0, 0.0)
    assert pump(link, lambda: link.airspeed is not None)
    before = link.counters.invalid_values
    peer.mav.vfr_hud_send(math.nan, math.inf, 0, 0, math.nan, math.nan)
    peer.mav.actuator_output_status_send(5, 0, [math.nan] * 32)  # empty mask, NaN values
    peer.mav.servo_output_raw_send(3, 0, 65535, 65535, 0, 0, 0, 0, 0, 0)
    peer.write(b"\xfd\x09\x00\x00garbage that is not mavlink")
    assert pump(link, lambda: link.counters.invalid_values >= before + 3 and link.counters.bad_data >= 1)
    assert link.airspeed == 14.5  # the NaN did not overwrite it
    assert 1 not in link.servo_pwm and link.servo_raw[1] == 65535
    # still alive and parsing after the rubbish
    peer.mav.servo_output_raw_send(4, 0, 1510, *([0] * 15))
    assert pump(link, lambda: link.servo_pwm.get(1) == 1510)


def test_asks_again_when_the_stream_stops(pair):
    link, peer, clock = pair
    fc_heartbeat(peer)
    assert pump(link, lambda: link.counters.stream_requests >= 2)
    assert recv_types(peer, "COMMAND_LONG", cond=interval_request(36)) is not None
    asked = link.counters.stream_requests
    # the stream flows: no new request however long it goes on
    for i in range(20):
        clock.t += 0.1
        fc_heartbeat(peer) if i % 10 == 0 else None
        peer.mav.servo_output_raw_send(i, 0, 1500 + i, *([0] * 15))
        peer.mav.vfr_hud_send(12.0, 12.0, 0, 0, 0.0, 0.0)
        assert pump(link, lambda i=i: link.servo_pwm.get(1) == 1500 + i)
    assert link.counters.stream_requests == asked
    # the stream stops: after rerequest_s the link asks again
    clock.t += 1.5
    assert pump(link, lambda: link.counters.stream_requests > asked)
    assert recv_types(peer, "COMMAND_LONG", cond=interval_request(36)) is not None


def test_named_float_and_chunked_statustext(pair):
    link, peer, _ = pair
    fc_heartbeat(peer)
    assert pump(link, lambda: link.system_id == 7)
    with pytest.raises(ValueError):
        link.send_named_float("ELEVENCHARS", 1.0)
    assert link.send_named_float("L_warp", 3.25)
    m = recv_types(peer, "NAMED_VALUE_FLOAT")
    assert m.name == "L_warp" and m.value == pytest.approx(3.25)

    text = "".join(chr(ord("a") + i % 26) for i in range(120))
    assert link.send_statustext(mavlink.MAV_SEVERITY_WARNING, text)
    chunks = [recv_types(peer, "STATUSTEXT") for _ in range(3)]
    assert all(c is not None for c in chunks)
    assert len({c.id for c in chunks}) == 1 and chunks[0].id != 0
    assert [c.chunk_seq for c in chunks] == [0, 1, 2]
    assert "".join(c.text for c in chunks) == text

    assert link.send_statustext(mavlink.MAV_SEVERITY_INFO, "short")
    m = recv_types(peer, "STATUSTEXT")
    assert m.text == "short" and m.id == 0


def test_missing_serial_device_backs_off_without_raising():
    clock = FakeClock()
    link = FcLink("/dev/warpbridge-no-such-port,57600", clock=clock)
    assert link.poll() == [] and not link.is_open
    assert link.poll() == []  # within back-off: no new attempt, no exception
    clock.t += 10
    assert link.poll() == [] and not link.is_open


def test_a_serial_fc_port_another_link_holds_is_refused_as_in_use():
    """The FC's serial port is held exclusively, as the Maestro's: a second bridge on it is told why it
    cannot open it, and gets it once the first lets go."""
    import os
    import tty

    master, slave = os.openpty()
    tty.setraw(slave)
    device = os.ttyname(slave)
    clock = FakeClock()
    first, second = FcLink(f"{device},57600", clock=clock), FcLink(f"{device},57600", clock=clock)
    try:
        assert first.open() and first.is_open
        assert not second.open() and not second.is_open
        assert second.open_error == "in use by another process (another bridge on the same port?)"
        first.close()
        clock.t += 10
        assert second.open()
    finally:
        first.close()
        second.close()
        os.close(master)
        os.close(slave)


def test_reconnects_when_tcp_peer_goes_away():
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind(("127.0.0.1", 0))
    server.listen(2)
    server.settimeout(5)
    port = server.getsockname()[1]
    enc = mavlink.MAVLink(None, srcSystem=3, srcComponent=1)
    hb = mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_PX4, 0, 0, mavlink.MAV_STATE_ACTIVE, 3
    ).pack(enc)
    clock = FakeClock()
    link = FcLink(f"tcp:127.0.0.1:{port}", clock=clock)
    try:
        assert link.open()
        conn, _ = server.accept()
        conn.sendall(hb)
        assert pump(link, lambda: link.system_id == 3)
        conn.close()  # FC side drops the connection
        assert pump(link, lambda: link.counters.reconnects == 1)
        clock.t += 10  # past the back-off
        assert pump(link, lambda: link.is_open)
        conn2, _ = server.accept()
        conn2.sendall(hb)
        assert pump(link, lambda: link.counters.fc_heartbeats >= 2)
        conn2.close()
    finally:
        link.close()
        server.close()


# ---------------------------------------------------------------------- telemetry over the link


def drain_until_marker(peer, mtype: str, marker) -> list:
    out = []
    deadline = time.monotonic() + 3
    while time.monotonic() < deadline:
        m = peer.recv_match(type=mtype, blocking=True, timeout=0.05)
        if m is None:
            continue
        if marker(m):
            return out
        out.append(m)
    raise AssertionError("marker not received")


def test_telemetry_rate_limits_each_name(pair):
    link, peer, clock = pair
    fc_heartbeat(peer)
    assert pump(link, lambda: link.system_id == 7)
    tlm = Telemetry(link, rate_hz=10, clock=clock)
    tlm.named_float("L_sp", 1.0)  # sent at once
    tlm.named_float("L_sp", 2.0)  # too soon: held, then replaced
    tlm.named_float("L_sp", 3.0)
    tlm.named_float("R_sp", 4.0)  # another name has its own budget
    tlm.poll()
    clock.t += 0.1
    tlm.poll()  # now L_sp = 3 is due
    tlm.poll()
    with pytest.raises(ValueError):
        tlm.named_float("L_far_too_long", 1.0)
    link.send_named_float("END", 0.0)
    got = drain_until_marker(peer, "NAMED_VALUE_FLOAT", lambda m: m.name == "END")
    assert [(m.name, m.value) for m in got] == [("L_sp", 1.0), ("R_sp", 4.0), ("L_sp", 3.0)]


def test_status_once_per_key_and_rate_limited(pair):
    link, peer, clock = pair
    fc_heartbeat(peer)
    assert pump(link, lambda: link.system_id == 7)
    tlm = Telemetry(link, rate_hz=10, key_holdoff_s=5.0, clock=clock)
    sev = mavlink.MAV_SEVERITY_WARNING
    assert tlm.status(sev, "left sensor lost", key="sensor_L")
    assert not tlm.status(sev, "left sensor lost", key="sensor_L")  # still active: no storm
    tlm.clear("sensor_L")
    clock.t += 1.0
    assert not tlm.status(sev, "left sensor lost", key="sensor_L")  # flapping within the hold-off
    tlm.clear("sensor_L")
    clock.t += 10.0
    assert tlm.status(sev, "left sensor lost", key="sensor_L")
    sent = [tlm.status(sev, f"note {i}") for i in range(8)]
    assert sent == [True] * 5 + [False] * 3
    clock.t += 1.0
    assert tlm.status(sev, "after a second")
    link.send_statustext(sev, "END")
    got = drain_until_marker(peer, "STATUSTEXT", lambda m: m.text == "END")
    assert [m.text for m in got] == ["left sensor lost"] * 2 + [f"note {i}" for i in range(5)] + ["after a second"]
