"""Config loading: the example is valid, every bad key is named in a one-line UserError."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from helpers import LOOP_SERVO_WINGS

from warpbridge.bridge.config import load_config
from warpbridge.bridge.errors import UserError

EXAMPLE = Path(__file__).resolve().parents[1] / "warpbridge.example.toml"


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "wb.toml"
    p.write_text(text)
    return p


def example_with(old: str, new: str) -> str:
    text = EXAMPLE.read_text()
    assert old in text, old
    return text.replace(old, new, 1)


def test_example_config_is_valid_and_paths_are_relative_to_it(tmp_path):
    cfg = load_config(write(tmp_path, EXAMPLE.read_text()))
    assert cfg.loop.rate_hz == 100
    assert cfg.left.source_channel == 1 and not cfg.left.reverse and cfg.right.reverse
    assert cfg.params_file == tmp_path / "warpbridge-params.json"
    assert cfg.loop.log == tmp_path / "logs" / "warpbridge-{time}.csv"
    assert cfg.model_file is None
    assert cfg.left.control.mode == "ff+pi" and (cfg.left.control.kp, cfg.left.control.ki) == (0.5, 10.0)
    assert cfg.left.sensor.counts[0] == 100 and len(cfg.left.sensor.deg) == 4


def test_minimal_config_takes_defaults(tmp_path):
    cfg = load_config(write(tmp_path, """
[link]
connection = "udpin:0.0.0.0:14550"
[model]
file = "models/m.json"
""" + LOOP_SERVO_WINGS))
    assert cfg.sensor_backend == "none"
    assert cfg.model_file == tmp_path / "models" / "m.json"
    assert cfg.left.sensor_channel is None
    assert cfg.left.servo.mm_limits == (-10.0, 10.0)
    assert (cfg.right.control.kp, cfg.right.control.ki) == (0.5, 10.0)  # mm/deg, mm/(deg s)


@pytest.mark.parametrize("old,new,key", [
    ('rate_hz = 100', 'rate_hz = 0', "rate_hz"),
    ('rate_hz = 100', 'rate_hz = "fast"', "rate_hz"),
    ('connection = "/dev/ttyAMA0,921600"', 'connection = ""', "connection"),
    ('gcs_sysid_allow = []', 'gcs_sysid_allow = [300]', "gcs_sysid_allow"),
    ('source_system = 0', 'source_system = 1.5', "source_system"),
    ('source_channel = 1', 'source_channel = 0', "source_channel"),
    ('pwm_trim = 1500', 'pwm_trim = 1950', "pwm_trim"),
    ('bias_deg = 2.0', 'bias_deg = 9.0', "bias_deg"),
    ('reverse = false', 'reverse = "no"', "reverse"),
    ('mode = "ff+pi"', 'mode = "pid"', "mode"),
    ('kp = 0.5', 'kp = -1', "kp"),
    ('mm_per_us = 0.02', 'mm_per_us = 0', "mm_per_us"),
    ('pulse_zero_us = 1200', 'pulse_zero_us = 2200', "pulse_zero_us"),
    ('counts = [100, 400, 700, 1000]', 'counts = [100, 400, 300, 1000]', "counts"),
    ('deg = [-1.0, 4.0, 9.5, 15.0]', 'deg = [-1.0, 4.0]', "deg"),
    ('servo_channel = 1', 'servo_channel = 0', "servo_channel"),
    ('max_warp_deg = 8.0', 'max_warp_deg = 8.0\nmax_warp = 3', "max_warp"),
    ('[telemetry]', '[telemetry]\nrate = 5', "rate"),
    ('backend = "maestro:/dev/ttyACM0,115200"', '', "backend"),
])
def test_bad_values_name_the_key(tmp_path, old, new, key):
    with pytest.raises(UserError) as e:
        load_config(write(tmp_path, example_with(old, new)))
    msg = str(e.value)
    assert "\n" not in msg
    assert re.search(rf"\b{re.escape(key)}\b", msg), msg


def test_unknown_section_and_missing_wing(tmp_path):
    with pytest.raises(UserError, match=r"\[servos\]"):
        load_config(write(tmp_path, EXAMPLE.read_text() + "\n[servos]\nx = 1\n"))
    text = EXAMPLE.read_text()
    cut = text[:text.index("[wing.right]")]
    with pytest.raises(UserError, match=r"wing\.right"):
        load_config(write(tmp_path, cut))


def test_unreadable_and_invalid_toml(tmp_path):
    with pytest.raises(UserError, match="cannot read"):
        load_config(tmp_path / "nope.toml")
    with pytest.raises(UserError, match="not valid TOML"):
        load_config(write(tmp_path, "[link\n"))


def test_px4_example_is_valid_and_the_play_comes_from_the_pwm_jitter(tmp_path):
    px4 = EXAMPLE.with_name("warpbridge.px4.example.toml")
    cfg = load_config(write(tmp_path, px4.read_text()))
    assert cfg.right.source_channel == 2 and cfg.link.pwm_jitter_us == 2.0
    # +-2 us through the steepest side of the mix: (8 - 2) deg over 400 us above trim
    assert cfg.left.control.deadband_deg == pytest.approx(2.0 * 6.0 / 400.0)
    cfg = load_config(write(tmp_path, example_with("pwm_jitter_us = 2", "pwm_jitter_us = 0")))
    assert cfg.left.control.deadband_deg == 0.0
    with pytest.raises(UserError, match="pwm_jitter_us"):
        load_config(write(tmp_path, example_with("i_max_mm = 2.0", "i_max_mm = 2.0\ndeadband_deg = 0.08")))
