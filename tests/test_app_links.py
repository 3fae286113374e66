"""The bridge in-process with real links: an injected ``FcLink``, live WB_SRV_HZ, ``fc:`` refusals, telemetry
sent once the FC is known."""

from __future__ import annotations

import threading
import time

import pytest
from test_bridge_process import Gcs, config_text, free_udp_port, wait_for

from warpbridge.bridge.app import Bridge, run_bridge
from warpbridge.bridge.config import load_config
from warpbridge.bridge.link import FcLink
from warpbridge.bridge.mavlink_env import mavlink, mavutil
from warpbridge.sitl.mock_autopilot import MockAutopilot


def test_injected_link_status_waits_for_the_fc_and_servo_rate_applies_live(tmp_path):
    port = free_udp_port()
    cfg_path = tmp_path / "wb.toml"
    cfg_path.write_text(config_text(port, tmp_path / "none", servo_backend="loop:", sensor_backend="none"))
    config = load_config(cfg_path)
    link = FcLink(f"udpin:127.0.0.1:{port}", servo_rate_hz=50, rerequest_s=0.5)
    bridge = Bridge(config, link=link)
    fc = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1)
    texts, intervals = [], []
    try:
        for _ in range(20):  # nobody known yet: the start-up failsafe cannot be reported, nor is it lost
            bridge.tick()
        assert link.system_id is None and not bridge.telemetry.active("fs-start")

        def pump(seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                fc.mav.heartbeat_send(mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0)
                bridge.tick()
                while (m := fc.recv_msg()) is not None:
                    if m.get_type() == "STATUSTEXT":
                        texts.append(m.text)
                    elif m.get_type() == "COMMAND_LONG" and m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL \
                            and m.param1 == mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW:
                        intervals.append(m.param2)
                time.sleep(0.01)

        pump(0.5)
        assert texts.count("WB failsafe: no servo outputs yet, wings neutral") == 1
        assert intervals and intervals[-1] == pytest.approx(20000)
        bridge.store.set("WB_SRV_HZ", 200.0)  # as a PARAM_SET would: asks the FC again at once
        pump(0.2)
        assert intervals[-1] == pytest.approx(5000)
        assert link.servo_rate_hz == 200.0
    finally:
        bridge.close()
        fc.close()
    assert link.mav is not None  # the bridge does not close a link it was handed
    link.close()


def test_fc_outputs_refused_by_the_autopilot_are_reported_once(tmp_path):
    fc_port, gcs_port = free_udp_port(), free_udp_port()
    cfg_path = tmp_path / "wb.toml"
    # the mock refuses DO_SET_SERVO beyond output 16: the tendon servo on output 20 is "already in use"
    text = config_text(fc_port, tmp_path / "none", servo_backend="fc:", sensor_backend="none")
    text = text.replace("servo_channel = 0", "servo_channel = 20").replace("servo_channel = 1", "servo_channel = 9")
    cfg_path.write_text(text)
    config = load_config(cfg_path)
    mock = MockAutopilot(fc_port, gcs_port, autopilot="ardupilot", jitter_us=0).start()
    gcs = Gcs(gcs_port)
    stop = threading.Event()
    th = threading.Thread(target=run_bridge, args=(config, stop), daemon=True)
    th.start()
    try:
        assert wait_for(lambda: gcs.has_text("WB servo board error: MAV_RESULT_DENIED"), 10.0), gcs.texts
        assert wait_for(lambda: 9 in mock.servo_commands, 5.0)  # the other wing's output is driven
        assert mock.servo_commands[9] > 1000
        time.sleep(2.5)  # refusals keep coming (keep-alive every second): still one message
        assert gcs.count_text("WB servo board error") == 1
    finally:
        stop.set()
        th.join(10)
        gcs.close()
        mock.stop()
    assert not th.is_alive()
