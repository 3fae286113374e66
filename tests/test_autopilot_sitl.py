"""The bridge against a real autopilot's SITL (opt-in): ArduPlane's ``arduplane`` binary.

Skipped unless ``WARPBRIDGE_ARDUPLANE`` names an ``arduplane`` SITL binary (built with
``./waf configure --board sitl && ./waf plane``; see docs/autopilot-sitl.md). Run with::

    WARPBRIDGE_ARDUPLANE=/path/to/ardupilot/build/sitl/bin/arduplane python -m pytest -m autopilot_sitl

The autopilot starts in a temporary directory as ``arduplane -w --model plane --speedup 1 --serial0 tcp:0 -I<n>``
on a free instance number ``n`` (its TCP ports 5760+10n for a ground station on SERIAL0,
5762+10n for the bridge on SERIAL1), with ``Tools/autotest/models/plane.parm`` of its source tree
when that is found (``WARPBRIDGE_ARDUPILOT_SRC``, or the tree the binary was built in) and
always ``SCHED_LOOP_RATE 100`` (SERVO_OUTPUT_RAW at 50 Hz) and ``SYSID_MYGCS 255`` (RC override
from our ground station). A pymavlink ground station on SERIAL0 heartbeats (ArduPilot routes a
component's messages only to links it has heard from) and moves the aileron with
RC_CHANNELS_OVERRIDE, in MANUAL: output 1 (``SERVO1_FUNCTION`` 4) follows stick 1. The bridge is
the real command, ``warpbridge run``, on SERIAL1, with a Pololu Maestro emulated on a pty.

The checks: the servo targets follow an aileron sweep in the right direction, with the
hysteresis of the feed-forward visible; the start STATUSTEXT and the named values reach the
ground station through the FC; a parameter set through the FC is answered (and a refused one
explained); the output-function check names a wrong channel (``--check`` and at run time) and
judges again when a ground station changes an output's function.

PX4's SIH airplane is ``tests/test_px4_sitl.py`` (``WARPBRIDGE_PX4``).
"""

from __future__ import annotations

import math
import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from helpers import GroundStation, sitl_bridge_toml, sitl_wing_toml, stop_flight, stop_process, wait_for

from warpbridge.bridge.mavlink_env import mavlink, mavutil
from warpbridge.sitl.maestro_emu import MaestroEmulator

ARDUPLANE = os.environ.get("WARPBRIDGE_ARDUPLANE", "")
pytestmark = [
    pytest.mark.autopilot_sitl,
    pytest.mark.xdist_group("arduplane_sitl"),  # one worker, one after another: SITLs compete for ports and CPU
    pytest.mark.skipif(not (ARDUPLANE and os.access(ARDUPLANE, os.X_OK)),
                       reason="opt-in: set WARPBRIDGE_ARDUPLANE to an ArduPlane SITL binary (docs/autopilot-sitl.md)"),
]

OWN_PARAMS = "SCHED_LOOP_RATE 100\nSYSID_MYGCS 255\n"  # 50 Hz SERVO_OUTPUT_RAW; RC override from sysid 255
SERVO_CH = {"left": 0, "right": 1}
PULSE_ZERO, MM_PER_US = 1200.0, 0.02  # tendon zero at 1200 us: a one-sided tendon, pulls on longer pulses


def _port_free(port: int, kind: int) -> bool:
    with socket.socket(socket.AF_INET, kind) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def free_instance() -> int:
    """An ArduPilot SITL instance number whose ports are all free (other runs may use 0..). Each process
    starts its search elsewhere (by its pid), so that parallel workers starting a SITL at the same moment
    do not pick the same free number."""
    for n in sorted(range(20, 200), key=lambda k: (k - os.getpid()) % 180):
        tcp = [5760 + 10 * n, 5762 + 10 * n, 5763 + 10 * n]
        if all(_port_free(p, socket.SOCK_STREAM) for p in tcp) and _port_free(5501 + 10 * n, socket.SOCK_DGRAM):
            return n
    raise RuntimeError("no free ArduPilot SITL instance number")


def plane_defaults() -> Path | None:
    """``Tools/autotest/models/plane.parm`` of the ArduPilot source tree, if it can be found."""
    src = os.environ.get("WARPBRIDGE_ARDUPILOT_SRC")
    roots = [Path(src)] if src else []
    roots += list(Path(ARDUPLANE).resolve().parents)[2:4]  # <src>/build/sitl/bin/arduplane
    for root in roots:
        parm = root / "Tools" / "autotest" / "models" / "plane.parm"
        if parm.is_file():
            return parm
    return None


class ArduPlane:
    """The SITL process in its own directory."""

    def __init__(self, folder: Path, extra_params: str = "") -> None:
        self.folder = folder
        self.instance = free_instance()
        self.gcs_port, self.bridge_port = 5760 + 10 * self.instance, 5762 + 10 * self.instance
        own = folder / "warpbridge-test.parm"
        own.write_text(OWN_PARAMS + extra_params)
        defaults = [str(p) for p in (plane_defaults(), own) if p is not None]
        self.log = open(folder / "arduplane.log", "wb")  # noqa: SIM115 - closed in stop()
        self.proc = subprocess.Popen([ARDUPLANE, "-w", "--model", "plane", "--speedup", "1", "--serial0", "tcp:0", "-I",
                                      str(self.instance), "--defaults", ",".join(defaults)],
                                     cwd=folder, stdout=self.log, stderr=subprocess.STDOUT)

    def wait_listening(self, timeout: float = 60.0) -> None:
        def up() -> bool:
            if self.proc.poll() is not None:
                raise RuntimeError(f"arduplane exited: {(self.folder / 'arduplane.log').read_text()[-2000:]}")
            return not _port_free(self.bridge_port, socket.SOCK_STREAM)
        assert wait_for(up, timeout), "arduplane did not open its ports"

    def stop(self) -> None:
        stop_process(self.proc)
        self.log.close()


class Gcs(GroundStation):
    """A ground station on SERIAL0: heartbeats, RC override, and what component 191 sends."""

    def __init__(self, port: int) -> None:
        super().__init__(mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=255,
                                                    source_component=mavlink.MAV_COMP_ID_MISSIONPLANNER))
        self.stick: int | None = None  # RC 1 override, us
        self.params: dict[str, float] = {}
        self.servo1: int | None = None  # the FC's output 1 (aileron), us
        self.fc_heartbeat = False
        self._next_hb = self._next_rc = 0.0
        self.start()

    def periodic(self, now: float) -> None:
        if now >= self._next_hb:
            self._next_hb = now + 1.0
            self.mav.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            self.mav.mav.command_long_send(1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                           mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW, 100000, 0, 0, 0, 0, 0)
        if self.stick is not None and now >= self._next_rc:
            self._next_rc = now + 0.1
            self.mav.mav.rc_channels_override_send(1, 1, self.stick, 0, 0, 0, 0, 0, 0, 0)

    def take(self, m: Any) -> None:
        t = m.get_type()
        if t == "HEARTBEAT" and m.get_srcComponent() == 1:
            self.fc_heartbeat = True
        if t == "SERVO_OUTPUT_RAW" and m.port == 0:
            self.servo1 = m.servo1_raw
        if t == "PARAM_VALUE" and m.get_srcComponent() == 191:
            with self.lock:
                self.params[m.param_id] = m.param_value


def bridge_config(folder: Path, port: int, *, left_source: int = 1, mode: str = "ff") -> Path:
    wings = [sitl_wing_toml(name, left_source if name == "left" else 1, name == "right", SERVO_CH[name], mode,
                            pulse_zero_us=PULSE_ZERO, mm_per_us=MM_PER_US) for name in ("left", "right")]
    cfg = folder / "wb.toml"
    cfg.write_text(sitl_bridge_toml(f"tcp:127.0.0.1:{port}", f"maestro:{folder / 'maestro'}", "".join(wings)))
    return cfg


class Bridge:
    """``warpbridge run`` on the autopilot's SERIAL1 with a Maestro on a pty."""

    def __init__(self, folder: Path, port: int, **config: Any) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        self.targets: list[tuple[float, int, float]] = []
        self.emu = MaestroEmulator(on_target=lambda ch, q: self.targets.append((time.monotonic(), ch, q / 4)),
                                   link=folder / "maestro")
        self.emu.start()
        self.stderr = folder / "bridge.stderr"
        self._err = open(self.stderr, "wb")  # noqa: SIM115 - closed in stop()
        self.proc = subprocess.Popen([sys.executable, "-m", "warpbridge.bridge.cli", "run", "--config",
                                      str(bridge_config(folder, port, **config))],
                                     cwd=folder, stdout=subprocess.DEVNULL, stderr=self._err)

    def pulse(self, channel: int, since: float) -> float | None:
        got = [p for t, ch, p in list(self.targets) if ch == channel and t >= since]
        return got[-1] if got else None

    def log(self) -> str:
        return self.stderr.read_text(errors="replace")

    def stop(self) -> int:
        rc = stop_process(self.proc)
        self._err.close()
        self.emu.stop()
        return rc


@pytest.fixture(scope="module")
def plane(tmp_path_factory) -> Iterator[tuple[ArduPlane, Gcs]]:
    folder = tmp_path_factory.mktemp("arduplane")
    ap = ArduPlane(folder)
    gcs = None
    try:
        ap.wait_listening()
        gcs = Gcs(ap.gcs_port)
        assert wait_for(lambda: gcs.fc_heartbeat, 30.0), "no heartbeat from ArduPlane"
        yield ap, gcs
    finally:
        if gcs is not None:
            gcs.close()
        ap.stop()


@pytest.fixture
def bridge_factory(plane, tmp_path):
    made: list[Bridge] = []

    def make(name: str = "bridge", **config: Any) -> Bridge:
        b = Bridge(tmp_path / name, plane[0].bridge_port, **config)
        made.append(b)
        return b

    yield make
    for b in made:
        if b.proc.poll() is None:
            b.stop()


def hold(gcs: Gcs, bridge: Bridge, stick: int, seconds: float = 2.5) -> tuple[float, float]:
    """Hold the aileron stick; the left and right tendon pulses at the end."""
    gcs.stick = stick
    time.sleep(seconds)
    since = time.monotonic() - 0.3
    left, right = bridge.pulse(SERVO_CH["left"], since), bridge.pulse(SERVO_CH["right"], since)
    assert left is not None and right is not None, bridge.log()[-3000:]
    return left, right


def test_servo_targets_follow_an_aileron_sweep_through_arduplane(plane, bridge_factory):
    _, gcs = plane
    gcs.stick = 1500
    bridge = bridge_factory()
    t0 = time.monotonic()
    assert wait_for(lambda: gcs.latest("WB_mode", t0) == 2.0, 30.0), bridge.log()[-3000:]  # ff, following
    centre_up = None
    sweep = {}
    for stick in (1100, 1500, 1900, 1500, 1100):
        left, right = hold(gcs, bridge, stick)
        if stick == 1500 and centre_up is None:
            centre_up = (left, right)
        sweep.setdefault(stick, []).append((left, right))
    centre_down = sweep[1500][-1]
    # right stick (roll right): the left wing gains lift -> its tendon pulls (longer pulse); the right relaxes
    assert sweep[1900][0][0] > centre_up[0] > sweep[1100][0][0] + 50
    assert sweep[1900][0][1] < centre_up[1] < sweep[1100][0][1] - 50
    # the feed-forward's hysteresis: the same warp from above needs the tendon released further
    assert centre_up[0] - centre_down[0] > 10, (centre_up, centre_down)
    # the setpoints are the mixer's (docs: a = (pwm - 1500) / 400 below trim; w = bias (1 + a) for the
    # wing that relaxes, bias + a (max - bias) for the one that gains lift) of what the FC outputs now
    a = (gcs.servo1 - 1500) / 400.0
    assert a < -0.5, gcs.servo1  # stick left
    assert gcs.latest("L_sp") == pytest.approx(2.0 * (1 + a), abs=0.05)
    assert gcs.latest("R_sp") == pytest.approx(2.0 + (-a) * 6.0, abs=0.05)
    assert bridge.stop() == 0


def test_start_message_named_values_and_parameters_through_the_fc(plane, bridge_factory):
    _, gcs = plane
    gcs.stick = 1700
    t0 = time.monotonic()
    bridge = bridge_factory()
    assert wait_for(lambda: gcs.text("WB started: ff", t0), 30.0), bridge.log()[-3000:]
    assert wait_for(lambda: gcs.latest("L_sp", t0) is not None, 10.0)
    names = {n for t, n, _ in list(gcs.floats) if t >= t0}
    assert {"L_sp", "R_sp", "L_cmd", "R_cmd", "L_ff", "WB_mode", "WB_lat"} <= names, names
    # stick right of centre: once the FC's outputs reach the bridge (its first reports may come from the
    # neutral it commands at start, before the first SERVO_OUTPUT_RAW)
    def sides() -> tuple[float, float]:
        return gcs.latest("L_sp", t0) or 0.0, gcs.latest("R_sp", t0) or 0.0

    assert wait_for(lambda: sides()[0] > sides()[1], 10.0), sides()
    gcs.mav.mav.param_set_send(1, 191, b"WB_KP", 2.5, mavlink.MAV_PARAM_TYPE_REAL32)
    assert wait_for(lambda: gcs.params.get("WB_KP") == pytest.approx(2.5), 10.0), gcs.params
    t1 = time.monotonic()
    gcs.mav.mav.param_set_send(1, 191, b"WB_KP", 500.0, mavlink.MAV_PARAM_TYPE_REAL32)
    assert wait_for(lambda: gcs.text("param WB_KP: 500 above max 50", t1), 10.0)
    assert gcs.params["WB_KP"] == pytest.approx(2.5)  # the echo carries the value kept
    gcs.mav.mav.param_set_send(1, 191, b"WB_MODE", 3.0, mavlink.MAV_PARAM_TYPE_REAL32)
    assert wait_for(lambda: gcs.text("WB_MODE: not applied: ff+pi needs a warp sensor", t1), 10.0)
    assert "FC autopilot: ardupilot" in bridge.log() and "asked the FC for SERVO_OUTPUT_RAW at 50 Hz" in bridge.log()
    assert bridge.stop() == 0


def test_output_function_check_names_a_wrong_channel(plane, bridge_factory, tmp_path):
    ap, gcs = plane
    cfg = bridge_config(tmp_path, ap.bridge_port, left_source=2)  # output 2 is the elevator in ArduPlane
    r = subprocess.run([sys.executable, "-m", "warpbridge.bridge.cli", "run", "--config", str(cfg), "--check"],
                       capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "left wing: FC output 2 is NOT an aileron (SERVO2_FUNCTION 19 (elevator))" in r.stdout, r.stdout
    assert "right wing: FC output 1 is an aileron (SERVO1_FUNCTION 4 (aileron)): OK" in r.stdout
    t0 = time.monotonic()
    bridge = bridge_factory("wrong", left_source=2)
    assert wait_for(lambda: gcs.text("WB L out 2 is elevator, not aileron", t0), 30.0), \
        bridge.log()[-3000:]
    assert "is NOT an aileron" in bridge.log()
    assert bridge.stop() == 0


def test_a_changed_output_function_is_judged_again(plane, bridge_factory):
    _, gcs = plane
    t0 = time.monotonic()
    bridge = bridge_factory("changed")
    assert wait_for(lambda: "left wing: FC output 1 is an aileron" in bridge.log(), 30.0), bridge.log()[-3000:]
    try:  # a ground station moves the aileron off output 1: ArduPilot announces the new value on every link
        gcs.mav.mav.param_set_send(1, 1, b"SERVO1_FUNCTION", 0, mavlink.MAV_PARAM_TYPE_INT16)
        assert wait_for(lambda: gcs.text("WB L out 1 is disabled, not aileron", t0), 15.0), bridge.log()[-3000:]
    finally:
        gcs.mav.mav.param_set_send(1, 1, b"SERVO1_FUNCTION", 4, mavlink.MAV_PARAM_TYPE_INT16)
    assert wait_for(lambda: bridge.log().count("left wing: FC output 1 is an aileron") == 2, 15.0), \
        bridge.log()[-3000:]
    assert bridge.stop() == 0


# ---------------------------------------------------------------------------------------------- a flight
# ArduPlane takes off (TAKEOFF mode), then flies FBWA with an RC-override aileron sweep while the bridge
# runs ff+pi on SERIAL1 with two simulated wings behind the emulated Maestro (sensors included); the
# ground station records a tlog; the FC writes its DataFlash log. ``WARPBRIDGE_FLIGHT_OUT=<dir>`` keeps
# the three logs (how tests/data/ was made).

FLIGHT_PARAMS = (
    "LOG_BITMASK 8209\n"  # ATTITUDE_FAST (ATT, PIDR at 25 Hz) | CTUN (airspeed) | RC (RCIN, RCOU)
    "LOG_DISARMED 0\n"
    "EK2_ENABLE 0\nEK3_LOG_LEVEL 3\nSIM_ESC_TELEM 0\n"  # a small log: no EKF2, no EKF3 or ESC streams
    "TKOFF_ALT 50\n"
    # the tlog's streams: ATTITUDE 10 Hz, VFR_HUD 5 Hz, positions and status 2 Hz (SERVO_OUTPUT_RAW 10 Hz: Gcs)
    "SR0_EXTRA1 10\nSR0_EXTRA2 5\nSR0_POSITION 2\nSR0_EXT_STAT 2\nSR0_RAW_SENS 0\nSR0_RC_CHAN 0\n"
    "SR0_RAW_CTRL 0\nSR0_EXTRA3 0\nSR0_ADSB 0\n"
)
MODE_FBWA, MODE_TAKEOFF = 5, 13


class FlightGcs(Gcs):
    """``Gcs`` that records a tlog, flies (arm, modes, aileron and throttle sticks) and watches the FC."""

    def __init__(self, port: int, tlog: Path) -> None:
        self.throttle: int | None = None
        self.armed = False
        self.mode: int | None = None
        self.altitude = 0.0
        self.airspeed = 0.0
        self._tlog = tlog
        super().__init__(port)

    def start(self) -> None:
        self.mav.setup_logfile(str(self._tlog))  # pymavlink writes every message it receives, stamped: a tlog
        super().start()

    def periodic(self, now: float) -> None:
        stick, self.stick = self.stick, None  # our own override below carries the aileron and the throttle
        try:
            super().periodic(now)
        finally:
            self.stick = stick
        if (stick is not None or self.throttle is not None) and now >= self._next_rc:
            self._next_rc = now + 0.05
            self.mav.mav.rc_channels_override_send(1, 1, stick or 0, 0, self.throttle or 0, 0, 0, 0, 0, 0)

    def take(self, m: Any) -> None:
        super().take(m)
        t = m.get_type()
        if t == "HEARTBEAT" and m.get_srcComponent() == 1:
            self.armed = bool(m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            self.mode = m.custom_mode
        elif t == "GLOBAL_POSITION_INT":
            self.altitude = m.relative_alt / 1000.0
        elif t == "VFR_HUD":
            self.airspeed = m.airspeed

    def set_mode(self, mode: int) -> None:
        self.mav.mav.command_long_send(1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0,
                                       mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode, 0, 0, 0, 0, 0)

    def arm(self) -> None:
        self.mav.mav.command_long_send(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)


def fly(folder: Path, sweep_s: float = 36.0) -> dict[str, Path]:
    """One flight; returns the paths of the DataFlash log, the tlog and the bridge's cycle log."""
    import tomllib

    from warpbridge.sitl.cmd_sitl import EMULATED_BOARD_TIMEOUT_S, VirtualRig
    from warpbridge.sitl.lockstep import make_wings
    from warpbridge.sitl.scenarios import Rig, make_scenario
    from warpbridge.sitl.wing import WingSpec

    ap = ArduPlane(folder, FLIGHT_PARAMS)
    gcs = bridge = emu = err = None
    try:
        ap.wait_listening()
        gcs = FlightGcs(ap.gcs_port, folder / "flight.tlog")
        assert wait_for(lambda: gcs.fc_heartbeat, 30.0), "no heartbeat from ArduPlane"
        gcs.mav.mav.param_request_list_send(1, 1)  # as a ground station does on connecting: the tlog has them
        rig = Rig()
        wings = make_wings(make_scenario("steps", 600.0, rig=rig), WingSpec(), w0_deg=rig.bias_deg, grid=True)
        vrig = VirtualRig(rig, wings)
        emu = MaestroEmulator(on_target=vrig.on_target, read_analog=vrig.read_analog)
        pty = emu.start()
        toml = rig.config_toml(connection=f"tcp:127.0.0.1:{ap.bridge_port}",
                               servo_backend=f"maestro:{pty},timeout={EMULATED_BOARD_TIMEOUT_S:g}",
                               sensor_backend="maestro:", mode="ff+pi", log="cycles.csv", params_file="params.json",
                               servo_rate_hz=50.0)
        tomllib.loads(toml)
        (folder / "wb.toml").write_text(toml)
        err = open(folder / "bridge.stderr", "wb")  # noqa: SIM115 - closed below
        bridge = subprocess.Popen([sys.executable, "-m", "warpbridge.bridge.cli", "run", "--config",
                                   str(folder / "wb.toml")], cwd=folder, stdout=subprocess.DEVNULL, stderr=err)
        gcs.stick, gcs.throttle = 1500, 1000
        assert wait_for(lambda: gcs.latest("WB_mode") == 3.0, 60.0), (folder / "bridge.stderr").read_text()[-3000:]
        deadline = time.monotonic() + 120.0
        while not gcs.armed and time.monotonic() < deadline:  # arming waits for the EKF and GPS
            gcs.arm()
            time.sleep(2.0)
        assert gcs.armed, "ArduPlane did not arm"
        gcs.set_mode(MODE_TAKEOFF)
        assert wait_for(lambda: gcs.altitude > 25.0, 90.0), gcs.altitude
        gcs.throttle = 1700
        gcs.set_mode(MODE_FBWA)
        assert wait_for(lambda: gcs.mode == MODE_FBWA, 10.0)
        gcs.mav.mav.param_set_send(1, 1, b"RLL2SRV_TCONST", 0.45, mavlink.MAV_PARAM_TYPE_REAL32)  # an event
        t0 = time.monotonic()
        while (el := time.monotonic() - t0) < sweep_s:  # aileron: sine sweeps of growing amplitude, with holds
            amp = 150 + 250 * min(1.0, (el % (sweep_s / 3)) / (sweep_s / 3) * 1.5)
            phase = el % 6.0
            gcs.stick = int(1500 + (amp * math.sin(2 * math.pi * phase / 3.0) if phase < 4.5 else 0))
            gcs.throttle = (2000, 1700, 1450)[min(2, int(3 * el / sweep_s))]  # three airspeeds
            vrig.tick()
            time.sleep(0.02)
        gcs.stick = 1500
        time.sleep(1.0)
    finally:
        stop_flight(bridge, err, emu, gcs, ap)
    bins = sorted((folder / "logs").glob("*.BIN"))
    assert bins, f"no DataFlash log in {folder / 'logs'}"
    files = {"bin": bins[-1], "tlog": folder / "flight.tlog", "cycles": folder / "cycles.csv"}
    keep = os.environ.get("WARPBRIDGE_FLIGHT_OUT")
    if keep:
        import shutil

        Path(keep).mkdir(parents=True, exist_ok=True)
        suffix = {"bin": ".BIN", "tlog": ".tlog", "cycles": "-cycles.csv"}
        for name, p in files.items():
            shutil.copy(p, Path(keep) / ("arduplane-flight" + suffix[name]))
    return files


def test_a_flight_reviewed_from_the_fcs_dataflash_log_and_the_cycle_log(tmp_path):
    from warpbridge.bridge.commands.fclog import read_fc_log
    from warpbridge.bridge.commands.logjoin import read_cycle_log
    from warpbridge.bridge.commands.review import review

    files = fly(tmp_path)
    fc = read_fc_log(files["bin"])
    assert {"L_sp", "R_sp", "L_warp", "R_warp", "L_cmd", "WB_mode"} <= set(fc.named), sorted(fc.named)
    assert fc.aileron_channels == [1] and fc.output(1) is not None
    assert any(e.kind == "param" and "RLL2SRV_TCONST" in e.text for e in fc.events), fc.events
    cl = read_cycle_log(files["cycles"])
    rv, flight, al = review(fc, cl)
    assert al is not None and al.method == "fc_t" and al.check_corr > 0.8, al
    assert abs(al.residual_s) < 0.05, al
    assert rv.tracking["left"]["all"][0].n > 1000
    # right stick: the left wing gains lift (left - right > 0) and the aircraft rolls right; the bands of
    # the takeoff run (on the ground, no roll) fit nothing, the cruise band fits well
    cruise = max(rv.roll_authority, key=lambda g: g.n)
    assert cruise.gain > 0 and cruise.r2 > 0.7, rv.roll_authority
    assert all(g.gain > 0 for g in rv.roll_authority if g.r2 > 0.5), rv.roll_authority
    tl = read_fc_log(files["tlog"])
    assert "L_sp" in tl.named and tl.output(1) is not None
