"""A real PX4 flight with the bridge: its ``.ulg`` and the bridge's cycle log, read, joined and reviewed.

``tests/data/px4-flight.ulg`` and ``tests/data/px4-flight-cycles.csv`` are one flight of PX4 1.15's SIH
airplane with ``warpbridge run`` on its onboard link (tests/data/README.md says how they were made):
takeoff, then Altitude mode with a roll sweep. PX4 logged the bridge's NAMED_VALUE_FLOATs as
``debug_key_value``, its aileron output (output 1) as ``actuator_outputs`` at 50 Hz, attitude, rates,
airspeed and status.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import ManualClock

from warpbridge.bridge.commands.fclog import FcLog, read_fc_log
from warpbridge.bridge.commands.logfile import read_log
from warpbridge.bridge.commands.logjoin import CycleLog, align, read_cycle_log
from warpbridge.bridge.telemetry import PX4_NAMED_GAP_S, Telemetry

DATA = Path(__file__).parent / "data"
ULG = DATA / "px4-flight.ulg"
CYCLES = DATA / "px4-flight-cycles.csv"
BRIDGE_NAMES = {"L_sp", "R_sp", "L_warp", "R_warp", "L_cmd", "R_cmd", "L_ff", "R_ff", "L_pi", "R_pi", "WB_mode",
                "WB_aspd", "WB_lat"}
BIAS_DEG, WARP_PER_AILERON = 6.0, 6.0  # the rig of the flight: bias 6 deg, 0..12 deg, outputs 1000..2000 us


@pytest.fixture(scope="module")
def fc() -> FcLog:
    return read_fc_log(ULG)


@pytest.fixture(scope="module")
def cycles() -> CycleLog:
    return read_cycle_log(CYCLES)


def test_the_bridges_named_values_are_read_from_debug_key_value(fc):
    assert fc.fmt == "ulog" and fc.autopilot == "px4"
    assert BRIDGE_NAMES <= set(fc.named), sorted(fc.named)
    # the bridge sends to PX4 one name at a time, so PX4's logger kept every name about equally often
    counts = [len(s) for s in fc.named.values()]
    assert min(counts) > 0.9 * max(counts) and min(counts) > 250, {k: len(s) for k, s in fc.named.items()}
    assert 5.0 < fc.named["L_sp"].rate_hz < 11.0
    assert set(fc.named["WB_mode"].v) == {3.0}  # ff+pi throughout


def test_a_name_px4_cut_to_nine_characters_is_named_back(tmp_path):
    from test_fclog import ULG as SAMPLE
    from test_fclog import _with_debug_key_value

    out = tmp_path / "cut.ulg"
    _with_debug_key_value(SAMPLE, out, [(21_000_000 + 100_000 * k, "WB_cal_pc", float(k)) for k in range(20)])
    assert set(read_fc_log(out).named) == {"WB_cal_pct"}


def test_outputs_parameters_and_events_of_the_flight(fc):
    # PWM_MAIN_FUNC1 201 (servo 1) with CA_SV_CS0_TYPE 1 (left aileron): output 1
    assert fc.aileron_channels == [1]
    ail = fc.output(1)
    assert ail is not None and ail.rate_hz == pytest.approx(50.0, rel=0.05)
    assert 1000 <= ail.v.min() and ail.v.max() <= 2000 and np.ptp(ail.v) > 250
    # disarmed, PX4 holds its outputs at 900 us: those samples are not commands and are left out
    armed = next(e.t for e in fc.events if "Armed by external command" in e.text)
    assert ail.t[0] >= armed - 0.1
    assert fc.roll is not None and fc.roll_rate is not None and fc.roll_rate.rate_hz == pytest.approx(50.0, rel=0.05)
    assert fc.airspeed is not None and fc.airspeed.v.max() > 12.0  # it flew
    modes = [e.text for e in fc.events if e.kind == "mode"]
    assert "mode AUTO_TAKEOFF" in modes and modes[-1] == "mode ALTCTL", modes
    assert any(e.text == "[commander] Takeoff detected" for e in fc.events)
    assert not any("\x1b" in e.text for e in fc.events)  # PX4's colour escapes removed


def test_named_setpoints_follow_the_fcs_aileron_through_the_mixer(fc):
    """L_sp as PX4 logged it (on receipt) is the bridge's mixer of the output PX4 logged a little earlier."""
    sp, ail = fc.named["L_sp"], fc.output(1)
    rms = []
    for lag in np.arange(0.0, 0.05, 0.005):
        a = np.clip((ail.at(sp.t - lag) - 1500.0) / 500.0, -1.0, 1.0)
        e = sp.v - (BIAS_DEG + WARP_PER_AILERON * a)
        rms.append(float(np.sqrt(np.nanmean(e * e))))
    assert min(rms) < 0.15, rms


def test_the_cycle_log_joins_by_the_fcs_stamps_and_the_checks_agree(fc, cycles):
    al = align(cycles, fc)
    assert al.method == "fc_t" and al.check_corr > 0.95, al
    # the stamps and the aileron both records agree within a few ms (measured: 3.3 ms)
    assert abs(al.residual_s) < 0.010, al
    # SIH's clock ran 0.47 % slow against the companion's (a busy machine): the line follows it
    assert al.drift < -0.002, al
    # PX4 stamps each named value on receipt: the logged L_sp comes after the cycle log's, by the hop
    # to the FC and the wait for its turn (measured: 4.8 ms); placed too late, it would come before
    assert 0.0 < al.telemetry_lag_s < 0.05, al
    assert al.overlap_s > 35.0


def test_review_writes_its_report_for_the_px4_flight(tmp_path):
    out = tmp_path / "px4.html"
    r = subprocess.run([sys.executable, "-m", "warpbridge.bridge.cli", "review", str(ULG), str(CYCLES), "-o",
                        str(out), "--no-progress", "--half-range", "500"], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "join: fc_t" in r.stdout
    html = out.read_text()
    assert html.startswith("<!doctype html>") and html.count("data:image/png;base64,") >= 4
    assert "<h2>Join</h2>" in html and "<h2>Roll authority</h2>" in html
    assert "RLL_RATE_FF" not in html and "FW_RR_FF" in html  # ArduPlane's parameter has no place in a PX4 review
    rv = json.loads(out.with_suffix(".json").read_text())
    assert rv["fc_format"] == "ulog" and rv["autopilot"] == "px4" and rv["source"] == "cycle log"
    assert abs(rv["alignment"]["residual_s"]) < 0.010
    assert rv["tracking"]["left"]["all"][0]["n"] > 10000
    # roll right: output 1 rises, the left wing gains lift (left - right > 0), the airplane rolls right
    reliable = [g for g in rv["roll_authority"] if g["reliable"]]
    assert reliable and all(g["gain"] > 0 for g in reliable), rv["roll_authority"]
    cruise = max(reliable, key=lambda g: g["n"])
    assert cruise["r2"] > 0.9 and 15.0 < cruise["gain"] < 40.0, cruise


def test_identify_reads_the_ulog_by_wing_and_says_the_rate_is_low(tmp_path):
    data = read_log(ULG, wing="left")
    assert data.warp is not None and data.airspeed is not None and len(data) > 250
    assert any("too low to tell a delay" in n for n in data.notes)
    model = tmp_path / "left.json"
    r = subprocess.run([sys.executable, "-m", "warpbridge.bridge.cli", "identify", str(ULG), "--wing", "left", "-o",
                        str(model), "--quiet", "--maxiter", "30"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "too low to tell a delay" in r.stdout + r.stderr
    assert json.loads(model.read_text())


# ------------------------------------------------------------------------------------------------ telemetry


class _Link:
    def __init__(self, autopilot: str | None, clock: ManualClock) -> None:
        self.autopilot, self.clock, self.sent = autopilot, clock, []

    def send_named_float(self, name: str, value: float) -> bool:
        self.sent.append((self.clock(), name))
        return True


def _run_cycles(autopilot: str | None, names: list[str], seconds: float = 2.0) -> list[tuple[float, str]]:
    clock = ManualClock()
    link = _Link(autopilot, clock)
    tlm = Telemetry(link, rate_hz=10.0, clock=clock)
    for k in range(int(seconds * 100)):  # a 100 Hz loop: every name updated, then poll()
        clock.t = k * 0.01
        for i, n in enumerate(names):
            tlm.named_float(n, float(i))
        tlm.poll()
    return link.sent


def test_to_px4_the_named_values_go_one_at_a_time_and_in_turn():
    names = sorted(BRIDGE_NAMES) + ["L_ad_off", "R_ad_off", "WB_cal"]
    sent = _run_cycles("px4", names)
    t = np.array([s[0] for s in sent])
    assert np.min(np.diff(t)) >= PX4_NAMED_GAP_S - 1e-9  # never two within one of PX4's logger cycles
    counts = {n: sum(1 for _, m in sent if m == n) for n in names}
    # a 100 Hz loop sends 100 a second, shared evenly: 16 names, 6 or 7 times a second each
    assert set(counts.values()) <= {12, 13}, counts
    # to other autopilots each name goes at its own rate, in one burst per period
    sent = _run_cycles("ardupilot", names)
    assert {sum(1 for _, m in sent if m == n) for n in names} <= {19, 20}
    assert all(sum(1 for u, _ in sent if u == t) == len(names) for t in {t for t, _ in sent})
