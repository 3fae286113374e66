"""Tendon servos on the FC's outputs: the COMMAND_LONGs sent, rate limiting, and a real UDP link."""

from __future__ import annotations

import logging
import math
from types import SimpleNamespace

import pytest
from helpers import free_udp_port
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from warpbridge import hw
from warpbridge.hw.errors import DeviceError
from warpbridge.hw.fc_outputs import FcOutputs


class RecordingMav:
    """Stands in for ``connection.mav``: records command_long_send calls."""

    def __init__(self, fail: bool = False):
        self.calls: list[tuple] = []
        self.fail = fail

    def command_long_send(self, *args):
        if self.fail:
            raise OSError("link down")
        self.calls.append(args)


@pytest.fixture
def clock():
    return [100.0]


@pytest.fixture
def conn():
    return SimpleNamespace(mav=RecordingMav(), target_system=7, target_component=1)


def ardupilot(conn, clock, **kw):
    return FcOutputs(conn, 7, 1, "ardupilot", clock=lambda: clock[0], **kw)


def test_ardupilot_do_set_servo(conn, clock):
    out = ardupilot(conn, clock)
    out.set_pulse(9, 1500.4)
    assert conn.mav.calls == [(7, 1, mavlink.MAV_CMD_DO_SET_SERVO, 0, 9.0, 1500.0, 0.0, 0.0, 0.0, 0.0, 0.0)]


def test_only_changes_of_one_microsecond_or_keepalives_are_sent(conn, clock):
    out = ardupilot(conn, clock, keepalive_s=0.5)
    out.set_pulse(9, 1500.0)
    clock[0] += 0.1
    out.set_pulse(9, 1500.6)  # < 1 us: held back
    clock[0] += 0.1
    out.set_pulse(9, 1501.0)  # 1 us: sent
    clock[0] += 0.1
    out.set_pulse(10, 1501.0)  # other output: its own history
    clock[0] += 0.45
    out.set_pulse(9, 1501.0)  # unchanged but 0.55 s since the last one: keep-alive
    assert [(c[4], c[5]) for c in conn.mav.calls] == [(9, 1500), (9, 1501), (10, 1501), (9, 1501)]
    assert out.commands_sent == 4


def test_pulses_are_clamped_to_safe_limits(conn, clock):
    out = ardupilot(conn, clock, limits={9: (1100.0, 1900.0)})
    out.set_pulse(9, 2400.0)
    out.set_pulse(10, 500.0)  # default: pulse_range 1000..2000
    assert [c[5] for c in conn.mav.calls] == [1900.0, 1000.0]
    with pytest.raises(ValueError):
        out.set_pulse(9, math.nan)
    with pytest.raises(ValueError):
        out.set_pulse(0, 1500.0)  # ArduPilot servo numbers start at 1
    with pytest.raises(ValueError):
        out.set_limits(9, 900.0, 1500.0)  # outside pulse_range


def test_px4_do_set_actuator(conn, clock):
    out = FcOutputs(conn, 1, 1, "px4", pulse_range=(1000.0, 2000.0), clock=lambda: clock[0])
    out.set_pulse(2, 1750.0)
    out.set_pulse(5, 1000.0)
    (ts, tc, cmd, conf, *params), second = conn.mav.calls
    assert (ts, tc, cmd, conf) == (1, 1, mavlink.MAV_CMD_DO_SET_ACTUATOR, 0)
    assert params[1] == 0.5
    assert all(math.isnan(p) for i, p in enumerate(params[:6]) if i != 1)  # NaN: leave unchanged
    assert params[6] == 0.0  # actuator set index
    params5 = second[4:]
    assert params5[4] == -1.0 and math.isnan(params5[1])
    with pytest.raises(ValueError, match="1..6"):
        out.set_pulse(7, 1500.0)


def test_refusals_from_command_ack_are_reported(conn, clock):
    out = ardupilot(conn, clock)
    out.handle_ack(mavlink.MAVLink_command_ack_message(mavlink.MAV_CMD_DO_SET_SERVO, mavlink.MAV_RESULT_ACCEPTED))
    out.handle_ack(mavlink.MAVLink_command_ack_message(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 4))
    assert out.poll_errors() == 0
    out.handle_ack(mavlink.MAVLink_command_ack_message(mavlink.MAV_CMD_DO_SET_SERVO, mavlink.MAV_RESULT_FAILED))
    bits = out.poll_errors()
    assert bits == 1 << mavlink.MAV_RESULT_FAILED
    assert out.error_names(bits) == ["MAV_RESULT_FAILED"]
    clock[0] += 2.0  # no refusal since: a poll between two keep-alive refusals still reads it
    assert out.poll_errors() == bits
    clock[0] += 1.0  # 3 keep-alive periods without a refusal: the episode is over
    assert out.poll_errors() == 0


def test_a_refusal_at_every_keepalive_is_one_unbroken_episode(conn, clock):
    out = ardupilot(conn, clock)
    refused = mavlink.MAVLink_command_ack_message(mavlink.MAV_CMD_DO_SET_SERVO, mavlink.MAV_RESULT_DENIED)
    polls = []
    for k in range(40):  # refusals each keep-alive (1 s), polls every 0.7 s, late or early against them
        if k % 10 == 0:
            out.handle_ack(refused)
        if k % 7 == 3:
            polls.append(out.poll_errors())
        clock[0] += 0.1
    assert polls and all(b == 1 << mavlink.MAV_RESULT_DENIED for b in polls)
    clock[0] += 2.6
    assert out.poll_errors() == 0


def test_link_failure_is_a_device_error(clock):
    out = ardupilot(SimpleNamespace(mav=RecordingMav(fail=True)), clock)
    with pytest.raises(DeviceError):
        out.set_pulse(9, 1500.0)


def test_needs_a_mavlink_connection():
    with pytest.raises(TypeError):
        FcOutputs(object())
    with pytest.raises(ValueError, match="autopilot"):
        FcOutputs(SimpleNamespace(mav=RecordingMav()), autopilot="inav")
    with pytest.raises(ValueError, match="mavlink_sender"):
        hw.open_servo("fc:")


def test_open_servo_takes_ids_and_autopilot_from_the_sender(conn):
    conn.autopilot = "px4"
    out = hw.open_servo("fc:", mavlink_sender=conn)
    assert (out.target_system, out.target_component, out.autopilot) == (7, 1, "px4")
    out = hw.open_servo("fc:ardupilot", mavlink_sender=conn, target_system=3)
    assert (out.target_system, out.autopilot) == (3, "ardupilot")
    assert isinstance(out, hw.ServoOutput)


def test_command_long_arrives_over_a_real_pymavlink_link():
    port = free_udp_port()
    fc = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=1, source_component=1)
    bridge = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=191)
    try:
        hw.open_servo("fc:ardupilot", mavlink_sender=bridge, target_system=1, target_component=1).set_pulse(10, 1620.0)
        msg = fc.recv_match(type="COMMAND_LONG", blocking=True, timeout=5)
        assert msg is not None
        assert (msg.target_system, msg.target_component) == (1, 1)
        assert msg.command == mavlink.MAV_CMD_DO_SET_SERVO
        assert (msg.param1, msg.param2) == (10.0, 1620.0)
        assert msg.get_srcComponent() == 191

        FcOutputs(bridge, 1, 1, "px4").set_pulse(1, 1250.0)
        msg = fc.recv_match(type="COMMAND_LONG", blocking=True, timeout=5)
        assert msg is not None and msg.command == mavlink.MAV_CMD_DO_SET_ACTUATOR
        assert msg.param1 == -0.5 and math.isnan(msg.param2) and msg.param7 == 0.0
    finally:
        bridge.close()
        fc.close()


def test_a_refusal_after_the_episode_ended_is_logged_again_without_a_poll(conn, clock, caplog):
    out = ardupilot(conn, clock)
    refused = mavlink.MAVLink_command_ack_message(mavlink.MAV_CMD_DO_SET_SERVO, mavlink.MAV_RESULT_DENIED)
    with caplog.at_level(logging.WARNING, logger="warpbridge.hw.fc_outputs"):
        out.handle_ack(refused)
        clock[0] += 1.0
        out.handle_ack(refused)  # the same episode: not logged again
        clock[0] += 3.0  # more than 2.5 keep-alive periods without a refusal, and no poll in between
        out.handle_ack(refused)
    assert sum("FC refused" in r.getMessage() for r in caplog.records) == 2
    assert out.poll_errors() == 1 << mavlink.MAV_RESULT_DENIED
