"""What the bridge says and does when it starts: a STATUSTEXT even when the FC's stream already flows,
modes that need a sensor when there is none, the feed-forward state started from the measured warp,
and (in the lean run path) a calibration computed in a worker process."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

from warpbridge.bridge.app import Bridge
from warpbridge.bridge.config import load_config
from warpbridge.bridge.params import ParamError
from warpbridge.hw.loop import LoopBackend
from warpbridge.sitl.field_tuning import SimLink

REPO = Path(__file__).resolve().parents[1]


def write_config(tmp_path: Path, *, sensor: str = "none", mode: str = "ff+pi", bias: float = 2.0,
                 right_sensor: bool = True, cycle_log: str | None = None) -> Path:
    cfg = tmp_path / "wb.toml"
    sensors = sensor != "none"
    cfg.write_text(f"""
[link]
connection = "udpin:127.0.0.1:1"
[servo]
backend = "loop:"
[sensor]
backend = "{sensor}"
[params]
file = "params.json"
[wing.left]
source_channel = 1
servo_channel = 0
bias_deg = {bias}
{"sensor_channel = 5" if sensors else ""}
[wing.left.control]
mode = "{mode}"
[wing.left.sensor]
counts = [0, 1000]
deg = [0, 20]
[wing.right]
source_channel = 1
reverse = true
servo_channel = 1
bias_deg = {bias}
{"sensor_channel = 6" if sensors and right_sensor else ""}
[wing.right.control]
mode = "{mode}"
[wing.right.sensor]
counts = [0, 1000]
deg = [0, 20]
""" + (f'[loop]\nlog = "{cycle_log}"\n' if cycle_log else ""))
    return cfg


class Rig:
    def __init__(self, tmp_path: Path, *, counts=None, pulses=None, **cfg) -> None:
        self.t = 0.0
        self.link = SimLink()
        self.board = LoopBackend(counts=counts or {}, clock=lambda: self.t)
        for ch, p in (pulses or {}).items():
            self.board.pulses[ch] = (p, 0.0)  # what the board was sending when the bridge started
        self.bridge = Bridge(load_config(write_config(tmp_path, **cfg)), servo=self.board,
                             sensor=self.board if counts is not None else None, link=self.link, clock=lambda: self.t)

    def run(self, seconds: float, pwm: float = 1500.0) -> None:
        for _ in range(round(seconds / 0.01)):
            self.t += 0.01
            self.link.servo_pwm, self.link.servo_time = {1: pwm}, self.t
            self.bridge.tick()

    def close(self) -> None:
        self.bridge.close()


def test_start_is_announced_even_when_the_servo_stream_already_flows(tmp_path):
    rig = Rig(tmp_path, sensor="none", mode="ff")
    rig.run(0.05)  # the FC has been streaming all along: no failsafe, no "back" message
    assert rig.link.texts[0] == "WB started: ff, no sensor, 100 Hz"
    assert not any("failsafe" in t for t in rig.link.texts)
    rig.run(1.0)
    assert rig.link.texts.count("WB started: ff, no sensor, 100 Hz") == 1  # once
    rig.close()


def test_a_mode_that_needs_a_sensor_is_refused_live_and_explained_at_start(tmp_path, caplog):
    caplog.set_level(logging.INFO)
    rig = Rig(tmp_path, sensor="none", mode="ff+pi")  # the config asks for ff+pi; no sensor anywhere
    rig.run(0.1)
    assert rig.link.texts[:2] == ["WB started: ff+pi (ff runs: no sensor), no sensor, 100 Hz",
                                  "WB mode ff+pi needs a warp sensor (ff runs: no sensor)"]
    assert rig.link.named["WB_mode"] == 2.0  # what runs: ff
    store = rig.bridge.store
    store.set("WB_MODE", 2)  # ff: fine
    for mode in (1, 3):
        with pytest.raises(ParamError, match="needs a warp sensor and none is configured"):
            store.set("WB_MODE", mode)
        assert store.get("WB_MODE") == 2
    assert all(w.ctl.mode == "ff" for w in rig.bridge.wings.values())
    store.set("WB_MODE", 0)
    rig.run(0.1)
    assert rig.link.named["WB_mode"] == 0.0 and "WB mode open" in rig.link.texts
    assert "WB mode ff+pi needs a warp sensor" in caplog.text  # and the journal says it too
    rig.close()


def test_with_one_wing_blind_the_mode_is_accepted_and_the_telemetry_shows_the_fallback(tmp_path):
    rig = Rig(tmp_path, sensor="loop:", mode="ff", right_sensor=False, counts={5: 100.0})
    rig.bridge.store.set("WB_MODE", 3)
    rig.run(0.2)
    assert "WB mode ff+pi (right: ff, no sensor)" in rig.link.texts
    assert rig.bridge.wings["left"].last and rig.link.named["WB_mode"] == 2.0  # right runs ff
    rig.close()


def test_feed_forward_starts_from_the_measured_warp_and_the_tendon_position(tmp_path):
    # the wing sits at 4 deg (200 counts on a 0..1000 -> 0..20 deg sensor) with the tendon at 3.5 mm
    # (pulse 1500 + 3.5 / 0.02 = 1675 us). Paper model: z = (u - a1 w^2 - a2 w - a3) / az
    # = (3.5 + 0.0205*16 - 0.712*4 - 0.7958) / 0.5369 = 0.34308
    z_hand = (3.5 + 0.0205 * 16 - 0.712 * 4 - 0.7958) / 0.5369
    rig = Rig(tmp_path, sensor="loop:", mode="ff", bias=4.0, counts={5: 200.0, 6: 200.0},
              pulses={0: 1675.0, 1: 1675.0})
    ctl = rig.bridge.wings["left"].ctl
    assert ctl._model.w == pytest.approx(4.0) and ctl._model.z == pytest.approx(z_hand, abs=1e-9)
    rig.run(0.01)  # neutral (4 deg) = where the wing is: the tendon stays put
    assert rig.board.pulse(0) == pytest.approx(1675.0, abs=0.25)
    rig.close()
    # without a sensor the state starts at rest: the same neutral costs a different tendon (no z)
    other = tmp_path / "blind"
    other.mkdir()
    blind = Rig(other, sensor="none", mode="ff", bias=4.0, pulses={0: 1675.0})
    blind.run(0.01)
    u_rest = -0.0205 * 16 + 0.712 * 4 + 0.7958  # z = 0
    assert blind.board.pulse(0) == pytest.approx(1500 + u_rest / 0.02, abs=0.25)
    blind.close()


def test_a_reading_outside_the_calibration_leaves_the_state_at_rest(tmp_path, caplog):
    caplog.set_level(logging.INFO)
    rig = Rig(tmp_path, sensor="loop:", mode="ff", counts={5: 2000.0, 6: 200.0}, pulses={0: 1675.0, 1: 1675.0})
    assert rig.bridge.wings["left"].ctl._model.z == 0.0
    assert rig.bridge.wings["right"].ctl._model.z != 0.0
    assert "outside its calibration" in caplog.text
    rig.close()


CALIBRATE_IN_WORKER = """
import sys
from pathlib import Path
from warpbridge.model import _jit


def main():
    assert _jit.interpret()
    sys.path.insert(0, sys.argv[2])
    import test_calibrate as T
    from warpbridge.bridge.calibrate import CalState, Worker
    h = T.Harness(Path(sys.argv[1]))
    assert not h.bridge.tuning.adapt_every == 1  # interpreted: the estimator runs at a lower rate
    h.bridge.store.set("WB_CAL_RUN", 1)
    h.calibrate()
    tuning = h.bridge.tuning
    assert tuning.state == CalState.APPLIED, h.link.texts
    for name in ("left", "right"):
        tf = tuning.last_results[name].transform
        print(name, tf.offset, tf.gain)
        assert abs(tf.offset - 0.7) < 0.1 and abs(tf.gain - 1.08) < 0.02
    assert not Worker().in_process  # the fit ran in a worker process (with compiled kernels)
    h.close()


if __name__ == "__main__":
    main()
"""


@pytest.mark.slow
def test_calibration_of_the_lean_bridge_runs_in_a_worker_process(tmp_path):
    script = tmp_path / "cal.py"
    script.write_text(CALIBRATE_IN_WORKER)
    env = {k: v for k, v in os.environ.items() if k != "WARPBRIDGE_JIT"}
    r = subprocess.run([sys.executable, str(script), str(tmp_path), str(REPO / "tests")], capture_output=True,
                       text=True, timeout=900, env=env)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-4000:]
    assert "left 0.7" in r.stdout or "left 0.6" in r.stdout


def test_the_cycle_log_stamps_each_row_when_the_sensors_were_read(tmp_path):
    """The link's messages can take milliseconds to handle before the wings' sensors are read; a row stamped at
    the cycle's start would place the servo's motion between rows that much wrong for identify."""
    import csv

    rig = Rig(tmp_path, counts={5: 500, 6: 500}, sensor="loop:", cycle_log="cycles.csv")
    poll = rig.link.poll

    def slow_poll():  # the link's messages take 4 ms to handle this cycle, none the next
        rig.t += 0.004 if round(rig.t / 0.01) % 2 else 0.0
        return poll()

    rig.link.poll = slow_poll
    ticks = []
    for _ in range(10):
        rig.t = round(rig.t / 0.01) * 0.01 + 0.01  # the loop's next deadline
        ticks.append(rig.t)
        rig.link.servo_pwm, rig.link.servo_time = {1: 1500.0}, rig.t
        rig.bridge.tick()
    rig.close()
    with open(tmp_path / "cycles.csv", newline="") as f:
        t = [float(r["t"]) for r in csv.DictReader(f)]
    late = [0.004 if round(tk / 0.01) % 2 else 0.0 for tk in ticks]
    assert t == pytest.approx([tk + dl for tk, dl in zip(ticks, late, strict=True)], abs=2e-6)
