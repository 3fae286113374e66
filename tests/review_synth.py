"""A synthetic flight with known answers, for the review's tests (a supplement to the real logs in tests/data).

The FC's aileron output is a sweep; the bridge's cycle log runs at 100 Hz on its own clock, offset from the
FC's by a known amount, taking 50 Hz servo messages after a known transit; the roll rate is a known gain per
airspeed times the differential warp, a known lag later."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from warpbridge.bridge.commands.fclog import FcEvent, FcLog, Series
from warpbridge.bridge.cyclelog import CycleLog as CycleLogWriter

OFFSET_S = 95.25  # FC time = bridge time + this
TRANSIT_S = 0.004  # FC stamp -> bridge reception
ROLL_LAG_S = 0.1


def gain_at(airspeed: np.ndarray) -> np.ndarray:
    """Roll rate per degree of differential warp, deg/s per deg: grows with airspeed."""
    return 1.5 * airspeed / 10.0


def setpoints(pwm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The bridge's mixer with trim 1500, half range 400, bias 6, max 12 deg (left gains lift on pwm > trim)."""
    a = np.clip((pwm - 1500.0) / 400.0, -1, 1)
    left = np.where(a >= 0, 6 + a * 6, 6 * (1 + a))
    right = np.where(a <= 0, 6 - a * 6, 6 * (1 - a))
    return left, right


def flight(duration: float = 60.0, seed: int = 0, fc_t0: float = 100.0):
    rng = np.random.default_rng(seed)
    # FC: outputs at 50 Hz, stamped on its clock
    t_msg = fc_t0 + np.arange(0.0, duration, 0.02)
    pwm = 1500 + 380 * np.sin(2 * np.pi * 0.3 * (t_msg - fc_t0)) * np.sin(2 * np.pi * 0.05 * (t_msg - fc_t0))
    pwm = np.round(pwm)
    airspeed_fc = 10 + 12 * (t_msg - fc_t0) / duration
    # bridge: 100 Hz cycles; each uses the newest message that has arrived
    t_b = np.arange((fc_t0 - OFFSET_S) + 0.005, (fc_t0 - OFFSET_S) + duration, 0.01)
    arrive = t_msg + TRANSIT_S - OFFSET_S
    k = np.searchsorted(arrive, t_b, side="right") - 1
    ok = k >= 0
    t_b, k = t_b[ok], k[ok]
    left, right = setpoints(pwm[k])
    warp_l = left + 0.2 * rng.standard_normal(left.size) + 0.3 * np.sin(t_b)
    warp_r = right + 0.2 * rng.standard_normal(right.size)
    delta = warp_l - warp_r
    fc_cycle_t = t_b + OFFSET_S
    air_b = np.interp(fc_cycle_t, t_msg, airspeed_fc)
    # roll rate on the FC at 50 Hz: gain x differential warp, ROLL_LAG_S later
    rate = np.interp(t_msg - ROLL_LAG_S, fc_cycle_t, gain_at(air_b) * delta, left=0.0)
    rate += 0.5 * rng.standard_normal(rate.size)
    named = {}
    t10 = np.arange(fc_t0 + 0.5, fc_t0 + duration - 0.5, 0.1)
    for name, v in (("L_sp", left), ("R_sp", right), ("L_warp", warp_l), ("R_warp", warp_r),
                    ("L_cmd", left * 0.8), ("R_cmd", right * 0.8), ("WB_aspd", air_b),
                    ("WB_mode", np.full(left.size, 3.0)), ("WB_lat", np.full(left.size, 8.0))):
        named[name] = Series(t10 + 0.003, np.interp(t10, fc_cycle_t, v))
    outputs = np.full((t_msg.size, 16), np.nan)
    outputs[:, 0] = pwm
    outputs[:, 2] = 1600
    fc = FcLog(path="synthetic.BIN", fmt="dataflash", autopilot="ardupilot", named=named, outputs_t=t_msg,
               outputs=outputs, roll=None, roll_rate=Series(t_msg, rate), airspeed=Series(t_msg, airspeed_fc),
               events=[FcEvent(fc_t0 + 20, "mode", "mode FBWA"), FcEvent(fc_t0 + 30, "param", "X 1 -> 2")],
               params={"SERVO1_FUNCTION": 4.0, "SCALING_SPEED": 15.0}, aileron_channels=[1])
    cycle = {"t": t_b, "fc_t": t_msg[k], "airspeed": air_b,
             "left": {"setpoint": left, "ff": left * 0.8, "pi": 0 * left, "u": left * 0.8, "warp": warp_l,
                      "pulse": 1200 + left * 20},
             "right": {"setpoint": right, "ff": right * 0.8, "pi": 0 * right, "u": right * 0.8, "warp": warp_r,
                       "pulse": 1200 + right * 20}}
    return fc, cycle


def write_cycle_log(path: Path, cycle: dict, with_fc_t: bool = True) -> Path:
    """Write ``cycle`` with the bridge's own cycle-log writer."""
    with CycleLogWriter(path, flush_s=1e9) as w:
        for i, t in enumerate(cycle["t"]):
            wings = {name: {f: float(v[i]) for f, v in cycle[name].items()} for name in ("left", "right")}
            w.write(float(t), "ff+pi", float(cycle["airspeed"][i]), wings,
                    fc_t=float(cycle["fc_t"][i]) if with_fc_t else None)
    return path


def placeholder_log(folder: Path, name: str = "synthetic.BIN") -> Path:
    """A file for the command's argument where the test hands the FC log in directly (the command checks that
    its inputs exist before reading them)."""
    path = folder / name
    path.write_bytes(b"\xa3\x95\x80")
    return path
