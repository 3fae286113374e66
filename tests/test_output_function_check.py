"""Is the configured source channel an aileron? The FC's output functions read with the parameter protocol.

Expected verdicts come from the autopilots' own tables, typed in here: ArduPilot's
``SRV_Channel::Aux_servo_function_t`` (4 aileron, 19 elevator, 70 throttle, 77 left elevon) and PX4's
``output_functions.yaml`` (101.. motors, 201.. servos) with ``CA_SV_CSi_TYPE`` (1 left aileron,
3 elevator). PX4 sends integer parameters byte-wise: the float whose bits are the integer.
"""

from __future__ import annotations

import struct
import subprocess
import sys
import time

import pytest
from helpers import free_udp_port

from warpbridge.bridge.link import FcLink
from warpbridge.bridge.mavlink_env import mavlink
from warpbridge.bridge.outputcheck import OutputFunctionCheck, SourceWatch, decode_param, function_param
from warpbridge.sitl.mock_autopilot import MockAutopilot, OutputFunctionParams

INT16, INT32, REAL32 = mavlink.MAV_PARAM_TYPE_INT16, mavlink.MAV_PARAM_TYPE_INT32, mavlink.MAV_PARAM_TYPE_REAL32


class FakeLink:
    """What the check uses of ``FcLink``: ids, autopilot, and the PARAM_REQUEST_READs it sent."""

    def __init__(self, autopilot: str) -> None:
        self.autopilot, self.system_id, self.fc_alive = autopilot, 1, True
        self.asked: list[str] = []

    def send(self, msg) -> bool:
        assert msg.get_type() == "PARAM_REQUEST_READ" and (msg.target_system, msg.target_component) == (1, 1)
        self.asked.append(msg.param_id)
        return True


def param_value(name: str, value: float, ptype: int, src=(1, 1)):
    msg = mavlink.MAVLink_param_value_message(name.encode(), value, ptype, 900, 0)
    msg._header = mavlink.MAVLink_header(msg.id, srcSystem=src[0], srcComponent=src[1])
    return msg


def px4_int(v: int) -> float:
    """PX4's byte-wise encoding of an INT32 parameter."""
    return struct.unpack("<f", struct.pack("<i", v))[0]


def run_check(link: FakeLink, channels: dict[str, int], answers: dict[str, tuple[float, int]], seconds=6.0):
    """Drive the check for ``seconds`` (0.1 s steps); the 'FC' answers what it is asked from ``answers``."""
    check = OutputFunctionCheck(link, channels)
    t, reported = 0.0, []
    pending: list = []
    while t < seconds:
        _, new = check.take(pending, t)
        reported += new
        pending = [param_value(n, *answers[n]) for n in link.asked if n in answers]
        link.asked.clear()
        t += 0.1
    return check, reported


def test_parameter_names_follow_each_autopilot():
    assert function_param("ardupilot", 1) == "SERVO1_FUNCTION"
    assert function_param("ardupilot", 17) == "SERVO17_FUNCTION"
    assert function_param("px4", 3) == "PWM_MAIN_FUNC3"
    assert function_param("px4", 18) == "PWM_AUX_FUNC2"  # SERVO_OUTPUT_RAW port 1: the second output group


def test_px4_integers_are_decoded_bytewise_and_ardupilot_values_taken_as_they_are():
    assert px4_int(201) == pytest.approx(2.8166e-43, rel=1e-3)  # a denormal: the integer's bits
    assert decode_param(px4_int(201), INT32, "px4") == 201.0
    assert decode_param(px4_int(-5), INT32, "px4") == -5.0
    assert decode_param(4.0, INT16, "ardupilot") == 4.0
    assert decode_param(15.0, REAL32, "px4") == 15.0  # floats are floats on both


@pytest.mark.parametrize("value, kind, word", [
    (4, "aileron", "aileron"),
    (19, "not_aileron", "elevator"),
    (70, "not_aileron", "throttle"),
    (0, "not_aileron", "disabled"),
    (77, "mixed", "left elevon"),
    (24, "mixed", "left flaperon"),
    (95, "unknown", "script"),
])
def test_ardupilot_servo_functions(value, kind, word):
    link = FakeLink("ardupilot")
    check, reported = run_check(link, {"left": 3}, {"SERVO3_FUNCTION": (float(value), INT16)})
    assert check.done and len(reported) == 1
    v = reported[0]
    assert (v.wing, v.channel, v.kind) == ("left", 3, kind) and word in v.what
    assert v.ok == (kind in ("aileron", "mixed"))
    assert len(v.status()) <= 50 or kind == "unknown"  # one STATUSTEXT, no chunks
    if kind == "not_aileron":
        assert v.status() == f"WB L out 3 is {word}, not aileron"


def test_px4_servo_functions_follow_the_control_surface_type():
    link = FakeLink("px4")
    answers = {"PWM_MAIN_FUNC3": (px4_int(201), INT32), "PWM_MAIN_FUNC4": (px4_int(202), INT32),
               "PWM_MAIN_FUNC6": (px4_int(101), INT32), "PWM_MAIN_FUNC7": (px4_int(204), INT32),
               "CA_SV_CS_COUNT": (px4_int(3), INT32), "CA_SV_CS0_TYPE": (px4_int(1), INT32),
               "CA_SV_CS1_TYPE": (px4_int(3), INT32)}
    check, _ = run_check(link, {"a": 3, "b": 4, "c": 6, "d": 7}, answers)
    v = check.verdicts
    assert v["a"].kind == "aileron" and "left aileron" in v["a"].what  # the SIH airplane's output 3
    assert v["b"].kind == "not_aileron" and "elevator" in v["b"].what
    assert v["c"].kind == "not_aileron" and "motor 1" in v["c"].what
    assert v["d"].kind == "not_aileron" and "tilt servo" in v["d"].what  # servo 4 > 3 control surfaces


def test_no_answer_is_unknown_after_three_tries_and_an_answer_later_is_judged_again():
    link = FakeLink("ardupilot")
    check = OutputFunctionCheck(link, {"left": 1})
    asked, reported, t = 0, [], 0.0
    while t < 6.0:
        _, new = check.take([], t)
        reported += new
        asked += len(link.asked)
        link.asked.clear()
        t += 0.1
    assert asked == 3 and check.done
    assert [v.kind for v in reported] == ["unknown"] and "no answer to SERVO1_FUNCTION" in reported[0].what
    # a ground station sets the parameter later: the FC broadcasts PARAM_VALUE, the verdict follows
    _, new = check.take([param_value("SERVO1_FUNCTION", 4.0, INT16)], t)
    assert [v.kind for v in new] == ["aileron"]
    # PARAM_VALUE from someone else (another component) is not the FC's answer
    rest, new = check.take([param_value("SERVO1_FUNCTION", 19.0, INT16, src=(1, 191))], t + 0.1)
    assert new == [] and len(rest) == 1


def test_another_autopilot_cannot_tell():
    check, reported = run_check(FakeLink("generic"), {"left": 1}, {})
    assert [v.kind for v in reported] == ["unknown"] and "generic" in reported[0].what


def test_mock_publishes_output_functions_as_each_autopilot():
    ap = OutputFunctionParams("ardupilot", {1: "elevator", 5: "aileron"})
    assert ap.values["SERVO1_FUNCTION"] == 19 and ap.values["SERVO5_FUNCTION"] == 4
    assert ap.encode("SERVO5_FUNCTION") == (4.0, INT16)
    px4 = OutputFunctionParams("px4")  # default: 1, 2 ailerons, 3 throttle, 4 rudder
    assert [px4.values[f"PWM_MAIN_FUNC{i}"] for i in (1, 2, 3, 4, 5)] == [201, 202, 101, 203, 0]
    assert (px4.values["CA_SV_CS0_TYPE"], px4.values["CA_SV_CS2_TYPE"], px4.values["CA_SV_CS_COUNT"]) == (1, 4, 3)
    value, ptype = px4.encode("PWM_MAIN_FUNC2")
    assert ptype == INT32 and struct.unpack("<i", struct.pack("<f", value))[0] == 202


def check_against_mock(autopilot: str, channels: dict[str, int], roles=None) -> dict:
    """The check through a real ``FcLink`` to the mock autopilot over loopback UDP."""
    port = free_udp_port()
    link = FcLink(f"udpin:127.0.0.1:{port}", servo_rate_hz=10.0)
    mock = MockAutopilot(port, autopilot=autopilot, output_functions=roles).start()
    try:
        assert link.connect(10.0)
        check = OutputFunctionCheck(link, channels)
        deadline = time.monotonic() + 10.0
        while not check.done and time.monotonic() < deadline:
            check.take(link.poll(), link.clock())
            link.mav.select(0.05)
        return check.verdicts
    finally:
        mock.stop()
        link.close()


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_against_the_mock_autopilot(autopilot):
    v = check_against_mock(autopilot, {"left": 1, "right": 3})
    assert v["left"].kind == "aileron" and v["right"].kind == "not_aileron"
    assert ("throttle" if autopilot == "ardupilot" else "motor 1") in v["right"].what
    moved = check_against_mock(autopilot, {"left": 1}, roles={1: "elevator", 5: "aileron"})
    assert moved["left"].kind == "not_aileron" and "elevator" in moved["left"].what


def test_run_check_fails_plainly_on_a_wrong_channel(tmp_path):
    port = free_udp_port()
    cfg = tmp_path / "wb.toml"
    cfg.write_text(f"""
[link]
connection = "udpin:127.0.0.1:{port}"
[servo]
backend = "loop:"
[params]
file = "params.json"
[wing.left]
source_channel = 4
servo_channel = 0
[wing.right]
source_channel = 1
reverse = true
servo_channel = 1
""")
    mock = MockAutopilot(port, autopilot="ardupilot").start()
    try:
        r = subprocess.run([sys.executable, "-m", "warpbridge.bridge.cli", "run", "--config", str(cfg), "--check"],
                           capture_output=True, text=True, timeout=120, cwd=tmp_path)
    finally:
        mock.stop()
    assert r.returncode == 2, r.stdout + r.stderr
    assert "outputs: left wing: FC output 4 is NOT an aileron (SERVO4_FUNCTION 21 (rudder))" in r.stdout, r.stdout
    assert "outputs: right wing: FC output 1 is an aileron (SERVO1_FUNCTION 4 (aileron)): OK" in r.stdout
    assert "check: FAILED" in r.stdout


def test_source_watch_warns_once_when_the_output_never_moves_in_flight():
    calls = []
    watch = SourceWatch({"left": 1, "right": 2}, still_s=30.0, on_still=lambda *a: calls.append(a))
    for i in range(4000):  # 40 s at 100 Hz: output 1 still, output 2 moving
        watch.update({1: 1500.0 + (i % 3) - 1, 2: 1500.0 + 200.0 * ((i // 100) % 2)}, True, 14.0, 0.01)
    assert [c[:2] for c in calls] == [("left", 1)] and calls[0][3] == pytest.approx(30.0, abs=0.02)
    quiet = SourceWatch({"left": 1}, still_s=30.0, on_still=lambda *a: calls.append(a))
    for _ in range(4000):
        quiet.update({1: 1500.0}, False, 14.0, 0.01)  # disarmed
        quiet.update({1: 1500.0}, True, 2.0, 0.01)  # armed, but sitting on the ground
    assert len(calls) == 1

