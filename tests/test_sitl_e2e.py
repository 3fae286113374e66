"""End to end: ``warpbridge sitl`` over real UDP and a real pty, three processes, a few seconds."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from sitl.cmd_sitl import parse_effects


@pytest.mark.slow
def test_sitl_runs_the_three_processes_and_agrees_with_lockstep(tmp_path):
    out = tmp_path / "run"
    # Gains in the loop's stable range: with the paper's Kp = 7 mm/deg the real-time loop is
    # marginal and a scheduling hiccup on a busy machine sets it oscillating (see the report of issue 4).
    proc = subprocess.run(
        [sys.executable, "-m", "bridge.cli", "sitl", "--duration", "4", "--kp", "0.7", "--ki", "20",
         "--out", str(out)],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["cycles"] >= 390  # 4 s at 100 Hz (the last cycle may miss the log)
    rt, ls = summary["rms_deg"]["realtime"], summary["rms_deg"]["lockstep"]
    for wing in ("left", "right"):
        assert 0 < rt[wing] < 0.2  # ff+pi tracked the reference through the whole chain
        assert rt[wing] == pytest.approx(ls[wing], rel=0.2)  # the same scenario flown in lock-step
    assert "real time" in proc.stdout and "lock-step" in proc.stdout
    assert (out / "sitl.png").stat().st_size > 10_000
    cycles = (out / "bridge-cycles.csv").read_text().splitlines()
    assert len(cycles) > 390 and cycles[0].startswith("t,mode")
    assert "ff+pi" in cycles[-1]  # the bridge followed the FC (not failsafe) at the end


def test_effects_option_parses_names_and_parameters():
    e = parse_effects("delay=0.03, backlash=0.2,pretension=0.3:1.1,aero_deg_per_kpa=2")
    assert (e.delay_s, e.backlash_mm, e.pretension_offset_mm, e.pretension_gain) == (0.03, 0.2, 0.3, 1.1)
    assert e.aero_deg_per_kpa == 2.0
    assert set(e.active()) == {"delay", "backlash", "pretension", "aero_load"}
    from bridge.errors import UserError

    for bad in ("warp=1", "delay", "delay=x", "delay=-1", "backlash=1:2"):
        with pytest.raises(UserError):
            parse_effects(bad)
