"""The bridge against PX4's SITL (opt-in): the SIH fixed wing, airframe 10041_sihsim_airplane.

Skipped unless ``WARPBRIDGE_PX4`` names a PX4 SITL binary (``build/px4_sitl_default/bin/px4`` of a
``make px4_sitl_default`` build, v1.14 or later; see docs/autopilot-sitl.md). Run with::

    WARPBRIDGE_PX4=/path/to/PX4-Autopilot/build/px4_sitl_default/bin/px4 python -m pytest -m autopilot_sitl

PX4 starts headless (``px4 -d -i <n> <build>/etc``, ``PX4_SYS_AUTOSTART=10041``, ``PX4_SIMULATOR=sihsim``)
in a temporary directory on a free instance number n: its ground-station link listens on UDP 18570+n, its
onboard (API) link sends to 14540+n, where the bridge, the real ``warpbridge run``, listens
(``udpin``), as on a companion computer. The test's ground station speaks first to 18570+n (PX4 streams
a link to whoever it heard first, and forwards only to links it has heard from).

The stock airframe drives the aileron on output 3 (``PWM_MAIN_FUNC3`` 201, ``CA_SV_CS0_TYPE`` 1, left
aileron, roll torque -0.5): a roll-right stick lowers that output, so the left wing is ``reverse``. PX4
holds every output at its disarmed value (900 us) until it arms; with ``COM_PREARM_MODE`` 2 the servos
follow the sticks while disarmed, which lets the test move the aileron with MANUAL_CONTROL in Manual mode
without arming (SIH's airplane of v1.15 does not survive arming in its default Hold mode).

The checks: ``--check`` finds the aileron on output 3 and names output 4's elevator; the bridge holds
the wings neutral on the disarmed value, then follows a roll sweep in the right direction; its named
values, start message and parameter answers reach the ground station through PX4. Then a flight (the
airframe's outputs moved to where SIH 1.15 reads them, see below): takeoff and a roll sweep in Altitude
mode with the bridge on two simulated wings, PX4's ``.ulg`` (debug topics on) and the bridge's cycle log
read, joined and reviewed, ``warpbridge identify`` run on the ``.ulg``.
"""

from __future__ import annotations

import math
import os
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers import GroundStation, sitl_bridge_toml, sitl_wing_toml, stop_flight, stop_process, wait_for

from warpbridge.bridge.mavlink_env import mavlink, mavutil

PX4 = os.environ.get("WARPBRIDGE_PX4", "")
pytestmark = [
    pytest.mark.autopilot_sitl,
    pytest.mark.skipif(not (PX4 and os.access(PX4, os.X_OK)),
                       reason="opt-in: set WARPBRIDGE_PX4 to a PX4 SITL binary (docs/autopilot-sitl.md)"),
]

PX4_MANUAL = 1  # PX4 custom main mode


def _udp_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def free_instance() -> int:
    for n in range(3, 10):  # past 9 PX4 gives every instance the same offboard port
        ports = [18570 + n, 14580 + n, 14540 + n, 14280 + n, 14030 + n, 13030 + n, 13280 + n, 19450 + n,
                 19410 + n]
        if all(_udp_free(p) for p in ports):
            return n
    raise RuntimeError("no free PX4 SITL instance number")


class Px4:
    """The SITL process in its own directory (PX4 keeps parameters.bson, dataman and logs there)."""

    def __init__(self, folder: Path, rc_params: str = "", logger_topics: str | None = None) -> None:
        """``rc_params``: commands of a ``px4-rc.params`` (PX4's startup script sources the first one on
        its PATH after the airframe's defaults, before the logger starts); ``logger_topics``: the lines of
        an ``etc/logging/logger_topics.txt``, which replaces ``SDLOG_PROFILE``'s topic sets."""
        self.folder = folder
        self.instance = free_instance()
        self.gcs_port, self.bridge_port = 18570 + self.instance, 14540 + self.instance
        etc = Path(PX4).resolve().parents[1] / "etc"
        env = dict(os.environ, PX4_SYS_AUTOSTART="10041", PX4_SIM_MODEL="sihsim_airplane", PX4_SIMULATOR="sihsim")
        if rc_params:
            (folder / "px4-rc.params").write_text(rc_params)
            env["PATH"] = f"{folder}{os.pathsep}{env.get('PATH', '')}"
        if logger_topics is not None:
            # PX4 links ./etc to its etc folder unless ./etc is a folder: one of links, and logging/ of our own
            (folder / "etc" / "logging").mkdir(parents=True)
            for entry in etc.iterdir():
                (folder / "etc" / entry.name).symlink_to(entry)
            (folder / "etc" / "logging" / "logger_topics.txt").write_text(logger_topics)
        self.log_path = folder / "px4.log"
        self.log = open(self.log_path, "wb")  # noqa: SIM115 - closed in stop()
        self.proc = subprocess.Popen([PX4, "-d", "-i", str(self.instance), str(etc)], cwd=folder, env=env,
                                     stdin=subprocess.DEVNULL, stdout=self.log, stderr=subprocess.STDOUT)

    def wait_started(self, timeout: float = 60.0) -> None:
        def up() -> bool:
            if self.proc.poll() is not None:
                raise RuntimeError(f"px4 exited: {self.log_path.read_text(errors='replace')[-2000:]}")
            return "Startup script returned successfully" in self.log_path.read_text(errors="replace")
        assert wait_for(up, timeout), "px4 did not start"

    def stop(self) -> None:
        stop_process(self.proc)
        self.log.close()


class Gcs(GroundStation):
    """A ground station on PX4's GCS link: heartbeats, the roll stick (MANUAL_CONTROL), what 191 sends."""

    def __init__(self, port: int, target: int) -> None:
        super().__init__(mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255,
                                                    source_component=mavlink.MAV_COMP_ID_MISSIONPLANNER))
        self.target = target
        self.roll: int | None = None  # MANUAL_CONTROL y, -1000..1000
        self.params: dict[tuple[int, str], float] = {}
        self.servo3: int | None = None
        self.custom_mode = 0
        self._next_hb = self._next_stick = 0.0
        self.start()

    def periodic(self, now: float) -> None:
        if now >= self._next_hb:
            self._next_hb = now + 1.0
            self.mav.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        if self.roll is not None and now >= self._next_stick:
            self._next_stick = now + 0.05
            self.mav.mav.manual_control_send(self.target, 0, self.roll, 500, 0, 0)

    def take(self, m: Any) -> None:
        t = m.get_type()
        comp = m.get_srcComponent()
        if t == "HEARTBEAT" and comp == 1:
            self.custom_mode = m.custom_mode
        if t == "SERVO_OUTPUT_RAW" and m.port == 0:
            self.servo3 = m.servo3_raw
        if t == "PARAM_VALUE":
            value = m.param_value
            if comp == 1 and m.param_type in (mavlink.MAV_PARAM_TYPE_INT32, mavlink.MAV_PARAM_TYPE_UINT8):
                value = struct.unpack("<i", struct.pack("<f", value))[0]  # PX4 packs integers bytewise
            with self.lock:
                self.params[comp, m.param_id] = value

    def set_px4_int(self, name: str, value: int) -> None:
        packed = struct.unpack("<f", struct.pack("<i", value))[0]
        self.mav.mav.param_set_send(self.target, 1, name.encode(), packed, mavlink.MAV_PARAM_TYPE_INT32)

    def manual_mode(self) -> None:
        self.mav.mav.command_long_send(self.target, 1, mavlink.MAV_CMD_DO_SET_MODE, 0,
                                       mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, PX4_MANUAL, 0, 0, 0, 0, 0)


def bridge_config(folder: Path, port: int, left_source: int = 3) -> Path:
    # output 3 falls with a roll-right stick: the left wing is the reversed one
    wings = sitl_wing_toml("left", left_source, True, 0, "ff", pwm=(1000, 1500, 2000)) + \
        sitl_wing_toml("right", 3, False, 1, "ff", pwm=(1000, 1500, 2000))
    cfg = folder / "wb.toml"
    cfg.write_text(sitl_bridge_toml(f"udpin:127.0.0.1:{port}", "loop:", wings))
    return cfg


@pytest.fixture(scope="module")
def px4(tmp_path_factory) -> Iterator[tuple[Px4, Gcs]]:
    folder = tmp_path_factory.mktemp("px4")
    ap = Px4(folder)
    gcs = None
    try:
        ap.wait_started()
        gcs = Gcs(ap.gcs_port, ap.instance + 1)  # PX4's MAV_SYS_ID is its instance + 1
        assert wait_for(lambda: gcs.servo3 is not None, 30.0), "no SERVO_OUTPUT_RAW from PX4"
        yield ap, gcs
    finally:
        if gcs is not None:
            gcs.close()
        ap.stop()


def run_bridge(folder: Path, port: int, **kw: Any) -> tuple[subprocess.Popen, Path]:
    folder.mkdir(parents=True, exist_ok=True)
    err = folder / "bridge.stderr"
    proc = subprocess.Popen([sys.executable, "-m", "warpbridge.bridge.cli", "run", "--config",
                             str(bridge_config(folder, port, **kw))], cwd=folder,
                            stdout=subprocess.DEVNULL, stderr=open(err, "wb"))  # noqa: SIM115
    return proc, err


def test_check_finds_the_aileron_on_output_3_and_names_the_elevator(px4, tmp_path):
    ap, _ = px4
    r = subprocess.run([sys.executable, "-m", "warpbridge.bridge.cli", "run", "--config",
                        str(bridge_config(tmp_path, ap.bridge_port, left_source=4)), "--check"],
                       capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "link: FC system" in r.stdout and "(px4)" in r.stdout, r.stdout
    assert ("right wing: FC output 3 is an aileron (PWM_MAIN_FUNC3 201, CA_SV_CS0_TYPE 1 (left aileron)): OK"
            in r.stdout), r.stdout
    assert "left wing: FC output 4 is NOT an aileron (PWM_MAIN_FUNC4 202" in r.stdout, r.stdout


def test_bridge_parks_on_the_disarmed_value_then_follows_a_roll_sweep_through_px4(px4, tmp_path):
    ap, gcs = px4
    t0 = time.monotonic()
    proc, err = run_bridge(tmp_path / "b", ap.bridge_port)
    try:
        assert wait_for(lambda: gcs.text("WB started: ff", t0), 60.0), err.read_text()[-3000:]
        # disarmed at PX4's disarmed value (900 us): both wings neutral, not full aileron
        assert wait_for(lambda: gcs.servo3 == 900, 10.0), gcs.servo3
        assert wait_for(lambda: gcs.latest("L_sp", t0) is not None, 20.0), err.read_text()[-3000:]
        time.sleep(1.0)
        assert gcs.latest("L_sp") == pytest.approx(2.0) and gcs.latest("R_sp") == pytest.approx(2.0)
        assert "its disarmed value, wing neutral" in err.read_text()
        # servos live while disarmed, Manual mode, the roll stick moves output 3
        gcs.set_px4_int("COM_PREARM_MODE", 2)
        assert wait_for(lambda: gcs.params.get((1, "COM_PREARM_MODE")) == 2, 10.0), gcs.params
        gcs.roll = 0
        gcs.manual_mode()
        assert wait_for(lambda: gcs.custom_mode >> 16 == PX4_MANUAL, 10.0), hex(gcs.custom_mode)
        assert wait_for(lambda: gcs.servo3 is not None and abs(gcs.servo3 - 1500) < 30, 10.0), gcs.servo3
        sp = {}
        for roll in (0, 300, -300):
            gcs.roll = roll
            assert wait_for(lambda roll=roll: (gcs.servo3 - 1500) * roll < 0 if roll else True, 10.0), \
                gcs.servo3
            time.sleep(1.5)
            pwm = gcs.servo3
            sp[roll] = (gcs.latest("L_sp"), gcs.latest("R_sp"), pwm)
        # roll right lowers output 3 (the airframe's torque -0.5); the left wing (reversed) gains lift
        assert sp[300][2] < 1500 < sp[-300][2]
        assert sp[0][0] == pytest.approx(2.0, abs=0.1)
        assert sp[300][0] > sp[0][0] > sp[-300][0]
        assert sp[300][1] < sp[0][1] < sp[-300][1]
        a = (1500 - sp[300][2]) / 500.0  # the mixer's normalised aileron for the reversed left wing
        assert sp[300][0] == pytest.approx(2.0 + a * 6.0, abs=0.1)
        assert sp[300][1] == pytest.approx(2.0 * (1 - a), abs=0.1)
        # a parameter set through PX4 reaches the bridge (component 191) and its answer comes back
        gcs.mav.mav.param_set_send(gcs.target, 191, b"WB_KP", 2.5, mavlink.MAV_PARAM_TYPE_REAL32)
        assert wait_for(lambda: gcs.params.get((191, "WB_KP")) == pytest.approx(2.5), 10.0), gcs.params
        assert "FC autopilot: px4" in err.read_text()
    finally:
        gcs.roll = None
        assert stop_process(proc) == 0, err.read_text()[-3000:]


# ---------------------------------------------------------------------------------------------- a flight
# PX4 1.15's SIH airplane flies once its outputs are where SIH reads them (its airframe file of 1.15 puts
# the surfaces on outputs 3-6 while SIH takes aileron, elevator, rudder, throttle from outputs 1-4; PX4
# moved them after 1.15) and with the signs SIH 1.15 applies; with 9 N of thrust (6 N by default) it
# lifts off the runway, whose ground contact in 1.15 holds the pitch at zero. It takes off in Takeoff
# mode, then flies Altitude mode with a MANUAL_CONTROL roll sweep at three throttle settings, while the
# bridge runs ff+pi on the onboard link with two simulated wings behind the emulated Maestro (sensors
# included). The logger logs from boot with its debug topics on (SDLOG_PROFILE 33: the default set and
# the debug set, whose debug_key_value is each NAMED_VALUE_FLOAT PX4 receives). ``WARPBRIDGE_FLIGHT_OUT=
# <dir>`` keeps the .ulg and the cycle log (how tests/data/px4-flight* were made), logging then only the
# topics the review reads (``SMALL_LOG_TOPICS``) to keep the file small.

FLIGHT_RC_PARAMS = """
param set PWM_MAIN_FUNC1 201
param set PWM_MAIN_FUNC2 202
param set PWM_MAIN_FUNC3 203
param set PWM_MAIN_FUNC4 101
param set PWM_MAIN_FUNC5 0
param set PWM_MAIN_FUNC6 0
param set CA_SV_CS0_TRQ_R 0.5
param set CA_SV_CS1_TRQ_P -1
param set SIH_T_MAX 9
param set SDLOG_MODE 1
param set SDLOG_PROFILE 33
"""
SMALL_LOG_TOPICS = """debug_key_value
actuator_outputs 20 0
vehicle_attitude 20
vehicle_angular_velocity 20
airspeed_validated 100
vehicle_status 500
"""
PX4_ALTCTL, PX4_AUTO, PX4_TAKEOFF = 2, 4, 2  # custom main modes; Auto's sub mode Takeoff


class FlightGcs(Gcs):
    """``Gcs`` that flies: arms, sets modes, sends both sticks; watches output 1, altitude, airspeed."""

    def __init__(self, port: int, target: int) -> None:
        self.throttle = 500  # MANUAL_CONTROL z, 0..1000
        self.armed = False
        self.altitude = self.airspeed = 0.0
        self.servo1: int | None = None
        super().__init__(port, target)

    def periodic(self, now: float) -> None:
        roll, self.roll = self.roll, None  # our own MANUAL_CONTROL below carries the throttle too
        try:
            super().periodic(now)
        finally:
            self.roll = roll
        if roll is not None and now >= self._next_stick:
            self._next_stick = now + 0.05
            self.mav.mav.manual_control_send(self.target, 0, roll, self.throttle, 0, 0)

    def take(self, m: Any) -> None:
        super().take(m)
        t = m.get_type()
        if t == "HEARTBEAT" and m.get_srcComponent() == 1:
            self.armed = bool(m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
        elif t == "SERVO_OUTPUT_RAW" and m.port == 0:
            self.servo1 = m.servo1_raw
        elif t == "GLOBAL_POSITION_INT":
            self.altitude = m.relative_alt / 1000.0
        elif t == "VFR_HUD":
            self.airspeed = m.airspeed

    def set_mode(self, main: int, sub: int = 0) -> None:
        self.mav.mav.command_long_send(self.target, 1, mavlink.MAV_CMD_DO_SET_MODE, 0,
                                       mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub, 0, 0, 0, 0)

    def arm(self) -> None:
        self.mav.mav.command_long_send(self.target, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)


def fly(folder: Path, sweep_s: float = 30.0, small_log: bool = False) -> dict[str, Path]:
    """One flight; returns the paths of PX4's .ulg and the bridge's cycle log."""
    from warpbridge.sitl.cmd_sitl import EMULATED_BOARD_TIMEOUT_S, VirtualRig
    from warpbridge.sitl.lockstep import make_wings
    from warpbridge.sitl.maestro_emu import MaestroEmulator
    from warpbridge.sitl.scenarios import Rig, make_scenario
    from warpbridge.sitl.wing import WingSpec

    ap = Px4(folder, FLIGHT_RC_PARAMS, SMALL_LOG_TOPICS if small_log else None)
    gcs = bridge = emu = err = None
    try:
        ap.wait_started()
        gcs = FlightGcs(ap.gcs_port, ap.instance + 1)
        assert wait_for(lambda: gcs.servo1 is not None, 30.0), "no SERVO_OUTPUT_RAW from PX4"
        # the estimator settles first (about 35 s): the bridge starts then, its cycle log holds the flight
        assert wait_for(lambda: "Ready for takeoff" in ap.log_path.read_text(errors="replace"), 150.0), \
            ap.log_path.read_text(errors="replace")[-2000:]
        # PX4's outputs span 1000..2000 us; a roll-right command raises output 1 (CA_SV_CS0_TRQ_R 0.5): the
        # rig's left wing gains lift on a rising output, its right wing is the reversed one
        rig = Rig(pwm_min=1000.0, pwm_max=2000.0)
        wings = make_wings(make_scenario("steps", 600.0, rig=rig), WingSpec(), w0_deg=rig.bias_deg, grid=True)
        vrig = VirtualRig(rig, wings)
        emu = MaestroEmulator(on_target=vrig.on_target, read_analog=vrig.read_analog)
        pty = emu.start()
        (folder / "wb.toml").write_text(rig.config_toml(
            connection=f"udpin:127.0.0.1:{ap.bridge_port}",
            servo_backend=f"maestro:{pty},timeout={EMULATED_BOARD_TIMEOUT_S:g}", sensor_backend="maestro:",
            mode="ff+pi", log="cycles.csv", params_file="params.json", servo_rate_hz=50.0))
        err = open(folder / "bridge.stderr", "wb")  # noqa: SIM115 - closed below
        bridge = subprocess.Popen([sys.executable, "-m", "warpbridge.bridge.cli", "run", "--config",
                                   str(folder / "wb.toml")], cwd=folder, stdout=subprocess.DEVNULL, stderr=err)
        assert wait_for(lambda: gcs.latest("WB_mode") == 3.0, 60.0), (folder / "bridge.stderr").read_text()[-3000:]
        gcs.roll, gcs.throttle = 0, 500  # sticks centred from the start: PX4 takes Altitude mode with them
        deadline = time.monotonic() + 30.0
        while not gcs.armed and time.monotonic() < deadline:
            gcs.arm()
            wait_for(lambda: gcs.armed, 2.0)
        assert gcs.armed, "PX4 did not arm"
        gcs.set_mode(PX4_AUTO, PX4_TAKEOFF)
        assert wait_for(lambda: gcs.altitude > 20.0, 60.0), gcs.altitude
        for _ in range(5):
            gcs.set_mode(PX4_ALTCTL)
            if wait_for(lambda: gcs.custom_mode >> 16 == PX4_ALTCTL, 2.0):
                break
        assert gcs.custom_mode >> 16 == PX4_ALTCTL, (hex(gcs.custom_mode), ap.log_path.read_text()[-1000:])
        t0 = time.monotonic()
        while (el := time.monotonic() - t0) < sweep_s:  # roll stick: sines of growing amplitude, with holds
            amp = 250 + 450 * min(1.0, (el % (sweep_s / 3)) / (sweep_s / 3) * 1.5)
            phase = el % 6.0
            gcs.roll = int(amp * math.sin(2 * math.pi * phase / 3.0)) if phase < 4.5 else 0
            gcs.throttle = (1000, 600, 250)[min(2, int(3 * el / sweep_s))]  # three airspeeds
            vrig.tick()
            time.sleep(0.02)
        gcs.roll = 0
        time.sleep(1.0)
        assert gcs.altitude > 5.0, f"the airplane came down: {gcs.altitude:.1f} m"
    finally:
        stop_flight(bridge, err, emu, gcs, ap)
    ulgs = sorted((folder / "log").rglob("*.ulg"))
    assert ulgs, f"no .ulg in {folder / 'log'}: {ap.log_path.read_text(errors='replace')[-2000:]}"
    files = {"ulg": ulgs[-1], "cycles": folder / "cycles.csv"}
    keep = os.environ.get("WARPBRIDGE_FLIGHT_OUT")
    if keep:
        import shutil

        Path(keep).mkdir(parents=True, exist_ok=True)
        shutil.copy(files["ulg"], Path(keep) / "px4-flight.ulg")
        shutil.copy(files["cycles"], Path(keep) / "px4-flight-cycles.csv")
    return files


def test_a_px4_flight_reviewed_from_the_ulog_and_the_cycle_log(tmp_path):
    from warpbridge.bridge.commands.fclog import read_fc_log
    from warpbridge.bridge.commands.logjoin import read_cycle_log
    from warpbridge.bridge.commands.review import review

    files = fly(tmp_path, small_log=bool(os.environ.get("WARPBRIDGE_FLIGHT_OUT")))
    fc = read_fc_log(files["ulg"])
    # the bridge sends to PX4 one name at a time: its logger, which keeps one debug_key_value per cycle, has them all
    assert fc.autopilot == "px4" and {"L_sp", "R_sp", "L_warp", "R_warp", "L_cmd", "WB_mode"} <= set(fc.named), \
        {k: len(s) for k, s in fc.named.items()}
    assert min(len(s) for s in fc.named.values()) > 0.9 * max(len(s) for s in fc.named.values())
    assert fc.aileron_channels == [1] and fc.output(1) is not None
    assert np.ptp(fc.output(1).v) > 200  # the sweep moved the aileron
    assert fc.airspeed is not None and fc.airspeed.v.max() > 10.0  # it flew
    assert any(e.text == "mode ALTCTL" for e in fc.events), fc.events
    cl = read_cycle_log(files["cycles"])
    rv, flight, al = review(fc, cl)
    assert al is not None and al.method == "fc_t" and al.check_corr > 0.8, al
    assert abs(al.residual_s) < 0.05 and al.telemetry_lag_s > 0, al
    assert rv.tracking["left"]["all"][0].n > 1000
    # roll right: the left wing gains lift (left - right > 0) and the airplane rolls right
    cruise = max(rv.roll_authority, key=lambda g: g.n)
    assert cruise.gain > 0 and cruise.r2 > 0.5, rv.roll_authority
    out = tmp_path / "review.html"
    r = subprocess.run([sys.executable, "-m", "warpbridge.bridge.cli", "review", str(files["ulg"]),
                        str(files["cycles"]), "-o", str(out), "--no-progress"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert out.stat().st_size > 10_000 and out.with_suffix(".json").is_file()
    r = subprocess.run([sys.executable, "-m", "warpbridge.bridge.cli", "identify", str(files["ulg"]), "--wing",
                        "left", "-o", str(tmp_path / "left.json"), "--quiet"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert (tmp_path / "left.json").is_file()
