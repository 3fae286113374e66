"""Start-up of ``warpbridge run``: neutral on the servo board first, a lean import path, interpreted kernels
that agree with the compiled ones, and a numba cache that lands somewhere writable."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from helpers import free_udp_port

from warpbridge.bridge import jitcache
from warpbridge.bridge.config import ControlConfig, ServoCal, load_config
from warpbridge.bridge.startup import PAPER_CENTRE, centre_line, load_model, neutral_pulses, neutral_tendon_mm
from warpbridge.model import _jit
from warpbridge.model.boucwen import BoucWenParams
from warpbridge.model.effects import Effects
from warpbridge.model.modelfile import ModelFile
from warpbridge.sitl.maestro_emu import MaestroEmulator
from warpbridge.sitl.mock_autopilot import MockAutopilot

PAPER = BoucWenParams.paper()


def config_file(tmp_path: Path, fc_port: int, servo: str, *, bias: float = 2.0, mm_per_us: float = 0.02) -> Path:
    cfg = tmp_path / "wb.toml"
    cfg.write_text(f"""
[link]
connection = "udpin:127.0.0.1:{fc_port}"
[servo]
backend = "{servo}"
[params]
file = "params.json"
[wing.left]
source_channel = 1
servo_channel = 0
bias_deg = {bias}
[wing.left.servo]
mm_per_us = {mm_per_us}
[wing.right]
source_channel = 1
reverse = true
servo_channel = 1
bias_deg = {bias}
[wing.right.servo]
mm_per_us = {mm_per_us}
""")
    return cfg


# ---------------------------------------------------------------------- what neutral is


def test_neutral_is_the_tendon_of_the_neutral_warp_through_each_wings_calibration(tmp_path):
    # paper model at 2 deg: u = -0.0205*4 + 0.7120*2 + 0.7958 = 2.1378 mm (hysteretic state z = 0)
    cfg = load_config(config_file(tmp_path, 1, "loop:", bias=2.0))
    assert neutral_tendon_mm(PAPER, cfg.left) == pytest.approx(2.1378, abs=1e-9)
    # 1500 us + 2.1378 mm / 0.02 mm/us = 1606.89 us, on the Maestro's quarter-us grid: 1607.0
    assert neutral_pulses(cfg, PAPER) == {0: 1607.0, 1: 1607.0}
    # a horn that pulls on shorter pulses: the same tendon is 1500 - 106.89 = 1393.11 us -> 1393.0
    rev = load_config(config_file(tmp_path, 1, "loop:", bias=2.0, mm_per_us=-0.02))
    assert neutral_pulses(rev, PAPER) == {0: 1393.0, 1: 1393.0}
    # no pre-warp: the unloaded wing, u = a3 = 0.7958 mm -> 1539.79 us -> 1539.75
    flat = load_config(config_file(tmp_path, 1, "loop:", bias=0.0))
    assert neutral_pulses(flat, PAPER) == {0: 1539.75, 1: 1539.75}
    # never outside the wing's tendon limits
    limited = replace(cfg.left, control=ControlConfig(u_max_mm=1.5))
    assert neutral_tendon_mm(PAPER, limited) == 1.5
    narrow = replace(cfg.left, servo=ServoCal(pulse_min_us=1450.0, pulse_max_us=1550.0))
    assert neutral_tendon_mm(PAPER, narrow) == pytest.approx(1.0)  # (1550 - 1500) * 0.02


def test_the_quick_read_of_the_model_file_matches_the_full_one(tmp_path):
    assert PAPER_CENTRE == (PAPER.a1, PAPER.a2, PAPER.a3)
    model = BoucWenParams(a1=-0.03, a2=0.8, a3=0.5, az=0.7, A=3.0, n=2.5)
    path = tmp_path / "model.json"
    path.write_text(json.dumps(ModelFile(model, Effects(pretension_offset_mm=0.6, pretension_gain=1.1,
                                                        friction_scale=1.3)).to_dict()))
    cfg = replace(load_config(config_file(tmp_path, 1, "loop:")), model_file=path)
    full = load_model(cfg)  # the validated read, effects folded by model.compensation
    assert centre_line(cfg) == pytest.approx((full.a1, full.a2, full.a3), rel=1e-12)
    # a friction change that keeps a level off the band's middle
    path.write_text(json.dumps(ModelFile(model, Effects(pretension_offset_mm=0.6, pretension_gain=1.1,
                                                        friction_scale=1.3, friction_pivot=-0.7)).to_dict()))
    pivoted = load_model(cfg)
    assert pivoted.a3 != pytest.approx(full.a3, rel=1e-6)
    assert centre_line(cfg) == pytest.approx((pivoted.a1, pivoted.a2, pivoted.a3), rel=1e-12)
    # pre-tension in its whole-loop form: the band scales with the backbone, the friction shift after it
    path.write_text(json.dumps(ModelFile(model, Effects(pretension_offset_mm=0.6, pretension_gain=1.1,
                                                        pretension_loop=1.0, friction_scale=1.3,
                                                        friction_pivot=-0.7)).to_dict()))
    looped = load_model(cfg)
    assert looped.a3 != pytest.approx(pivoted.a3, rel=1e-6)
    assert centre_line(cfg) == pytest.approx((looped.a1, looped.a2, looped.a3), rel=1e-12)
    # a file of the earlier effect forms (no "effect_forms" mark): the quick read follows the full one
    doc = ModelFile(model, Effects(pretension_offset_mm=0.6, pretension_gain=1.1, friction_scale=1.3)).to_dict()
    del doc["effect_forms"]
    path.write_text(json.dumps(doc))
    full = load_model(cfg)
    assert centre_line(cfg) == pytest.approx((full.a1, full.a2, full.a3), rel=1e-12)
    # hand check of the fold u = offset + u_model / gain without friction: a3 = 0.5 / 1.1 + 0.6
    path.write_text(json.dumps(ModelFile(model, Effects(pretension_offset_mm=0.6, pretension_gain=1.1)).to_dict()))
    assert centre_line(cfg)[2] == pytest.approx(1.054545454545, rel=1e-9)
    path.write_text("{not json")
    assert centre_line(cfg) is None  # the bridge's full read reports the error; nothing commanded early


def test_run_commands_neutral_before_loading_mavlink_and_loads_nothing_it_does_not_fly_with(tmp_path):
    """The real command against the mock autopilot and a Maestro on a pty. Python's import log
    (PYTHONPROFILEIMPORTTIME) and the bridge's log share stderr, in order."""
    targets: list[tuple[int, float]] = []
    emu = MaestroEmulator(on_target=lambda ch, q: targets.append((ch, q / 4.0)), link=tmp_path / "maestro")
    emu.start()
    port = free_udp_port()
    mock = MockAutopilot(port, autopilot="ardupilot").start()
    cfg = config_file(tmp_path, port, f"maestro:{tmp_path / 'maestro'}", bias=2.0)
    env = dict(os.environ, PYTHONPROFILEIMPORTTIME="1")
    env.pop("WARPBRIDGE_JIT", None)
    try:
        r = subprocess.run([sys.executable, "-m", "warpbridge.bridge.cli", "run", "--config", str(cfg),
                            "--duration", "3"], capture_output=True, text=True, timeout=120, cwd=tmp_path, env=env)
    finally:
        mock.stop()
        emu.stop()
    assert r.returncode == 0, r.stderr[-3000:]
    lines = r.stderr.splitlines()
    imported = [ln.split("|")[-1].strip() for ln in lines if ln.startswith("import time:")]
    neutral = next(i for i, ln in enumerate(lines) if "servo board" in ln and "neutral" in ln)
    first_mavlink = next(i for i, ln in enumerate(lines) if ln.startswith("import time:") and "pymavlink" in ln)
    assert neutral < first_mavlink, "neutral must be commanded before MAVLink is loaded"
    first_numpy = next(i for i, ln in enumerate(lines) if ln.startswith("import time:") and "numpy" in ln)
    assert neutral < first_numpy, "... and before numpy"
    assert targets[:2] == [(0, 1607.0), (1, 1607.0)]  # the first two commands: neutral, as computed above
    heavy = sorted({m.split(".")[0] for m in imported} & {"numba", "llvmlite", "scipy", "matplotlib", "tqdm"})
    assert heavy == [], f"warpbridge run imported {heavy}"
    assert any(m == "warpbridge.bridge.app" for m in imported)  # the log really is the whole run


# ---------------------------------------------------------------------- interpreted kernels


INTERPRETED_RUN = """
import sys, numpy as np
from warpbridge.model import _jit
assert _jit.interpret()
from warpbridge.model.boucwen import BoucWenParams, Stepper
assert "numba" not in sys.modules
w = np.load(sys.argv[1])
s = Stepper(BoucWenParams.paper(), w0=float(w[0]))
u = [s.inverse_step(float(x)) for x in w]
f = Stepper(BoucWenParams.paper(), w0=float(w[0]))
back = [f.forward_step(x) for x in u]
np.save(sys.argv[2], np.array([u, back]))
"""


def test_interpreted_kernels_agree_with_the_compiled_ones(tmp_path):
    from warpbridge.model.boucwen import Stepper

    rng = np.random.default_rng(5)
    t = np.arange(0, 8, 0.01)
    w = 4 + 3 * np.sin(2 * np.pi * 0.7 * t) + 0.05 * rng.standard_normal(t.size)  # reversals large and tiny
    np.save(tmp_path / "w.npy", w)
    script = tmp_path / "interp.py"
    script.write_text(INTERPRETED_RUN)
    r = subprocess.run([sys.executable, str(script), str(tmp_path / "w.npy"), str(tmp_path / "out.npy")],
                       capture_output=True, text=True, timeout=300, env={**os.environ, "WARPBRIDGE_JIT": ""})
    assert r.returncode == 0, r.stderr
    u_i, back_i = np.load(tmp_path / "out.npy")
    s = Stepper(PAPER, w0=float(w[0]))
    u_c = np.array([s.inverse_step(float(x)) for x in w])
    f = Stepper(PAPER, w0=float(w[0]))
    back_c = np.array([f.forward_step(float(x)) for x in u_c])
    assert np.max(np.abs(u_i - u_c)) < 1e-9
    assert np.max(np.abs(back_i - back_c)) < 1e-6
    assert np.max(np.abs(back_c - w)) < 1e-6  # and the forward map undoes the inverse


# ---------------------------------------------------------------------- where numba caches


def test_numba_cache_stays_beside_the_package_when_it_is_writable():
    assert jitcache.choose({}, Path("/pkg"), can_write=lambda p: True) is None
    assert jitcache.choose({"NUMBA_CACHE_DIR": "/mine"}, Path("/pkg"), can_write=lambda p: False) is None


@pytest.mark.parametrize("env, writable, expected", [
    ({"CACHE_DIRECTORY": "/var/cache/warpbridge-unit", "HOME": "/home/u"}, {"/var/cache/warpbridge-unit"},
     "/var/cache/warpbridge-unit"),  # systemd CacheDirectory=
    ({"XDG_CACHE_HOME": "/x/cache", "HOME": "/home/u"}, {"/x/cache/warpbridge"}, "/x/cache/warpbridge"),
    ({"HOME": "/home/u"}, {"/home/u/.cache/warpbridge"}, "/home/u/.cache/warpbridge"),
    ({"HOME": "/nonexistent"}, {"/var/cache/warpbridge"}, "/var/cache/warpbridge"),
])
def test_numba_cache_moves_somewhere_writable_when_the_package_directory_is_read_only(env, writable, expected):
    got = jitcache.choose(env, Path("/usr/lib/python3/site-packages/warpbridge/model"),
                          can_write=lambda p: str(p) in writable)
    assert str(got) == expected


def test_numba_cache_last_resort_is_the_temporary_directory(tmp_path):
    env: dict[str, str] = {}
    got = jitcache.configure(env, Path("/read-only/model"),
                             can_write=lambda p: str(p).startswith(os.environ.get("TMPDIR", "/tmp")))
    assert got is not None and env["NUMBA_CACHE_DIR"] == str(got) and "warpbridge-" in got.name


@pytest.mark.slow
def test_numba_really_compiles_into_the_chosen_directory(tmp_path):
    cache = tmp_path / "cache"
    code = ("import numpy as np\n"
            "from warpbridge.model.boucwen import BoucWenParams, inverse\n"
            "inverse(BoucWenParams.paper(), np.linspace(0, 5, 50))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600,
                       env={**os.environ, "NUMBA_CACHE_DIR": str(cache), "WARPBRIDGE_JIT": "1"})
    assert r.returncode == 0, r.stderr
    assert any(p.suffix == ".nbi" for p in cache.rglob("*")), sorted(cache.rglob("*"))
    # in the folder of the kernels' current sources: a kernel is never served from another version's cache
    dirs = {p.relative_to(cache).parts[0] for p in cache.rglob("*.nbi")}
    assert dirs == {f"kernels-{_jit.kernel_fingerprint()}"}, dirs


def _kernel_tree(root: Path) -> None:
    for d, body in (("model", "def f():\n    return 1\n"), ("sitl", "X = 2\n")):
        (root / d).mkdir(parents=True, exist_ok=True)
        (root / d / "k.py").write_text(body)


def test_kernel_fingerprint_follows_every_kernel_source(tmp_path):
    _kernel_tree(tmp_path)
    before = _jit.kernel_fingerprint(tmp_path)
    assert _jit.kernel_fingerprint(tmp_path) == before
    (tmp_path / "model" / "k.py").write_text("def f():\n    return 2\n")  # a callee changed (an upgrade)
    changed = _jit.kernel_fingerprint(tmp_path)
    assert changed != before
    (tmp_path / "sitl" / "k.py").write_text("X = 3\n")
    last = _jit.kernel_fingerprint(tmp_path)
    assert last not in (before, changed)
    (tmp_path / "docs").mkdir()  # outside the kernel folders: no recompile
    (tmp_path / "docs" / "k.py").write_text("not a kernel\n")
    assert _jit.kernel_fingerprint(tmp_path) == last


def test_versioned_cache_dir_drops_other_versions_only(tmp_path):
    (tmp_path / "kernels-old" / "x").mkdir(parents=True)
    (tmp_path / "kernels-new").mkdir()
    (tmp_path / "mine").mkdir()
    got = _jit.versioned_cache_dir(tmp_path, "new")
    assert got == tmp_path / "kernels-new" and got.is_dir()
    assert not (tmp_path / "kernels-old").exists() and (tmp_path / "mine").is_dir()
    assert _jit.versioned_cache_dir(tmp_path / "absent", "v") == tmp_path / "absent" / "kernels-v"


@pytest.mark.parametrize("rate, said", [(float("inf"), "20 ms lag;"), (60.0, "20 ms lag, at most 60 mm/s;")])
def test_the_models_servo_is_said_with_its_cap_only_when_it_has_one(tmp_path, caplog, rate, said):
    from warpbridge.bridge.startup import load_model_file

    path = tmp_path / "model.json"
    path.write_text(json.dumps(ModelFile(PAPER, Effects(servo_tau_s=0.02, servo_rate_mm_s=rate)).to_dict()))
    cfg = replace(load_config(config_file(tmp_path, 1, "loop:")), model_file=path)
    with caplog.at_level("INFO", logger="warpbridge.bridge.startup"):
        mf = load_model_file(cfg)
    assert mf.effects.servo_rate_mm_s == rate
    msg = next(r.getMessage() for r in caplog.records if "servo follows" in r.getMessage())
    assert said in msg and "inf" not in msg
