"""Ground stations attach to ``warpbridge sitl`` as to a real SITL: the default output, ``--gcs``, and
three real clients (pymavlink, MAVSDK, MAVProxy) listing component 191's WB_* parameters.

No test binds UDP 14550 (it may be in use on this machine): the default is checked in the parsed
options; the clients listen on free ports given with ``--gcs``, each on its own output."""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from helpers import free_udp_port

from warpbridge.bridge.errors import UserError
from warpbridge.bridge.mavlink_env import mavlink
from warpbridge.sitl import cmd_sitl

MAVPROXY = shutil.which("mavproxy.py") or str(Path(sys.executable).with_name("mavproxy.py"))


def parse(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    cmd_sitl.add_arguments(p)
    return p.parse_args(list(argv))


def test_by_default_the_sitl_sends_to_14550_like_ardupilot_and_px4():
    assert cmd_sitl.gcs_outputs(parse()) == ["udp:127.0.0.1:14550"]
    assert cmd_sitl.gcs_outputs(parse("--no-gcs")) == []
    port = free_udp_port()
    assert cmd_sitl.gcs_outputs(parse("--gcs", "udp:127.0.0.1:14550", "--gcs", "10.0.0.5:14550",
                                      "--gcs", f"udpin:127.0.0.1:{port}")) == [
        "udp:127.0.0.1:14550", "udp:10.0.0.5:14550", f"udpin:127.0.0.1:{port}"]


def test_bad_ground_station_outputs_are_refused_before_anything_starts():
    with pytest.raises(UserError, match="udp:HOST:PORT"):
        cmd_sitl.gcs_outputs(parse("--gcs", "udp:14550"))
    with pytest.raises(UserError, match="contradict"):
        cmd_sitl.gcs_outputs(parse("--gcs", "udp:127.0.0.1:14551", "--no-gcs"))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", 0))
        port = taken.getsockname()[1]
        with pytest.raises(UserError, match="cannot listen"):
            cmd_sitl.gcs_outputs(parse("--gcs", f"udpin:127.0.0.1:{port}"))


# ---------------------------------------------------------------------- real clients on a running sitl


class Listener:
    """A pymavlink-level ground station that only listens until told to ask for parameters."""

    def __init__(self, port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.05)
        self.parser = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        self.peer: tuple[str, int] | None = None
        self.heartbeats: set[tuple[int, int]] = set()
        self.params: dict[str, mavlink.MAVLink_param_value_message] = {}
        self.count: int | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data, self.peer = self.sock.recvfrom(65536)
            except OSError:
                continue
            for m in self.parser.parse_buffer(data) or []:
                if m.get_type() == "HEARTBEAT":
                    self.heartbeats.add((m.get_srcSystem(), m.get_srcComponent()))
                elif m.get_type() == "PARAM_VALUE" and m.get_srcComponent() == 191:
                    self.params[m.param_id] = m
                    self.count = m.param_count

    def ask_list(self) -> None:
        assert self.peer is not None
        self.sock.sendto(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID,
                                                           0, 0, 0, 3).pack(self.parser), self.peer)
        self.sock.sendto(mavlink.MAVLink_param_request_list_message(1, 191).pack(self.parser), self.peer)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.sock.close()


def wait_for(cond, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.05)
    return bool(cond())


def pymavlink_client(port: int, results: dict) -> None:
    gcs = Listener(port)
    try:
        # it has sent nothing: the vehicle and the bridge must still show up, as on a real SITL's 14550
        results["passive_191"] = wait_for(lambda: {(1, 1), (1, 191)} <= gcs.heartbeats, 60.0)
        gcs.ask_list()
        results["pymavlink_all"] = wait_for(lambda: gcs.count is not None and len(gcs.params) == gcs.count, 30.0)
        mode = gcs.params.get("WB_MODE")
        results["pymavlink_mode"] = None if mode is None else (mode.param_type, mode.param_value)
        results["pymavlink_names"] = sorted(gcs.params)
    finally:
        gcs.close()


def mavsdk_client(port: int, results: dict) -> None:
    try:
        from mavsdk import ComponentType, Configuration, Mavsdk
        from mavsdk.plugins.param import Param, ParamError, ParamResult, ProtocolVersion
    except (ImportError, OSError) as e:
        results["mavsdk_skip"] = str(e)
        return
    drone = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    try:
        drone.add_any_connection(f"udpin://127.0.0.1:{port}")
        system = drone.first_autopilot(60.0)
        assert system is not None
        assert wait_for(lambda: 191 in system.component_ids(), 30.0)
        param = Param(system)
        try:  # select component 191 first; mavsdk 4.x raises although it succeeded
            param.select_component(191, ProtocolVersion.V1)
        except ParamError as e:
            if e.result not in (ParamResult.SUCCESS, ParamResult.UNKNOWN):
                raise
        results["mavsdk_mode"] = param.get_param_int("WB_MODE")
        results["mavsdk_kp"] = param.get_param_float("WB_KP")
        param.set_param_int("WB_AD_DRIFT", 1)
        results["mavsdk_drift"] = param.get_param_int("WB_AD_DRIFT")
    except Exception as e:  # noqa: BLE001 - reported by the test
        results["mavsdk_error"] = repr(e)
    finally:
        drone.destroy()


def mavproxy_client(port: int, workdir: Path, results: dict) -> None:
    out_path = workdir / "mavproxy.out"
    with open(out_path, "w") as out:
        proc = subprocess.Popen(
            [MAVPROXY, f"--master=udpin:127.0.0.1:{port}", "--target-system=1", "--target-component=191",
             "--no-state"], stdin=subprocess.PIPE, stdout=out, stderr=subprocess.STDOUT, text=True, cwd=workdir)
        try:
            got = wait_for(lambda: re.search(r"Received (\d+) parameters", out_path.read_text(errors="replace")), 60)
            text = out_path.read_text(errors="replace")
            results["mavproxy_received"] = re.search(r"Received (\d+) parameters.*", text).group(0) if got else text
            proc.stdin.write("param show WB_MODE\n")  # commands on stdin: --cmd runs before the link is up
            proc.stdin.flush()
            wait_for(lambda: re.search(r"WB_MODE\s+\d", out_path.read_text(errors="replace")), 10)
            results["mavproxy_mode"] = re.findall(r"WB_MODE\s+(\S+)", out_path.read_text(errors="replace"))
        finally:
            proc.kill()
            proc.wait(10)


@pytest.mark.slow
@pytest.mark.skipif(not Path(MAVPROXY).exists(), reason="MAVProxy not installed (pip install --no-deps MAVProxy)")
def test_pymavlink_mavsdk_and_mavproxy_list_the_bridges_parameters_through_warpbridge_sitl(tmp_path):
    ports = [free_udp_port() for _ in range(3)]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    log = tmp_path / "sitl.out"
    with open(log, "w") as f:
        sitl = subprocess.Popen(
            [sys.executable, "-m", "warpbridge.bridge.cli", "sitl", "--duration", "120", "--no-plot",
             "--out", str(tmp_path / "run"), *(a for p in ports for a in ("--gcs", f"udp:127.0.0.1:{p}"))],
            stdout=f, stderr=subprocess.STDOUT, env=env)
    results: dict = {}
    try:
        clients = [threading.Thread(target=pymavlink_client, args=(ports[0], results)),
                   threading.Thread(target=mavsdk_client, args=(ports[1], results)),
                   threading.Thread(target=mavproxy_client, args=(ports[2], tmp_path, results))]
        for c in clients:
            c.start()
        for c in clients:
            c.join(150)
    finally:
        sitl.send_signal(signal.SIGINT)
        try:
            sitl.wait(30)
        except subprocess.TimeoutExpired:
            sitl.kill()
    text = log.read_text(errors="replace")
    assert "Traceback" not in text, text
    assert f"sending to 127.0.0.1:{ports[0]}" in text
    assert results.get("passive_191"), (results, text)
    assert results.get("pymavlink_all"), results
    names = results["pymavlink_names"]
    assert {"WB_MODE", "WB_KP", "WB_CAL_RUN", "WB_ADAPT", "WB_BW_AZ"} <= set(names)
    assert all(n.startswith("WB_") for n in names)
    assert results["pymavlink_mode"] == (mavlink.MAV_PARAM_TYPE_INT32, 3.0)  # ff+pi, cast as ArduPilot does
    if "mavsdk_skip" not in results:
        assert "mavsdk_error" not in results, results
        assert results["mavsdk_mode"] == 3 and results["mavsdk_kp"] == pytest.approx(0.5)  # the default kp, mm/deg
        assert results["mavsdk_drift"] == 1
    assert results["mavproxy_received"].startswith(f"Received {len(names)} parameters"), results
    assert float(results["mavproxy_mode"][-1]) == 3.0, results  # MAVProxy prints ArduPilot's cast ints as 3.0


def test_free_ports_lie_below_the_ephemeral_range_and_are_never_handed_out_twice():
    """A port from the ephemeral range can be given to any socket that sends before binding, between the
    check and the listener's bind (seen: the bridge could not listen on its FC port and waited forever)."""
    low = cmd_sitl._ephemeral_low()
    ports = [cmd_sitl.free_udp_port() for _ in range(40)]
    assert len(set(ports)) == len(ports)
    assert all(1024 <= p < low for p in ports)
    for p in ports[:5]:  # and free: they bind
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", p))


def test_the_banner_names_the_usual_ground_station_port_only_when_it_is_used():
    from warpbridge.sitl.cmd_sitl import gcs_banner

    assert "MAVProxy listen on 14550" in gcs_banner(["udp:127.0.0.1:14550"])
    other = gcs_banner(["udpin:127.0.0.1:14570"])
    assert other.startswith("listening on 127.0.0.1:14570") and "14550" not in other
    assert gcs_banner([]) == "none (--no-gcs)"
