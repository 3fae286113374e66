"""One bridge per parameter store: a second ``run`` or ``calibrate`` on the same configuration is refused
before it opens anything, naming the process that holds the store."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from warpbridge.bridge.cli import main
from warpbridge.bridge.errors import UserError
from warpbridge.bridge.instance_lock import InstanceLock

REPO = Path(__file__).resolve().parents[1]
HOLD = """
import sys, time
from warpbridge.bridge.instance_lock import InstanceLock
InstanceLock(sys.argv[1]).acquire("run")
print("held", flush=True)
time.sleep(60)
"""


def test_a_second_holder_is_refused_until_the_first_lets_go(tmp_path):
    params = tmp_path / "warpbridge-params.json"
    first = InstanceLock(params).acquire("run")
    with pytest.raises(UserError, match=r"another warpbridge \(pid \d+\) is running"):
        InstanceLock(params).acquire("calibrate")
    first.release()
    InstanceLock(params).acquire("calibrate").release()


@pytest.fixture
def held_config(tmp_path):
    """The example configuration in a folder of its own, its parameter store held by another process."""
    cfg = tmp_path / "wb.toml"
    shutil.copy(REPO / "warpbridge.example.toml", cfg)
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(tmp_path / "warpbridge-params.json")],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        yield cfg, holder.pid
    finally:
        holder.kill()
        holder.wait()


@pytest.mark.parametrize("argv", [["calibrate", "--no-fc", "--config"], ["run", "--check", "--config"],
                                  ["run", "--config"]])
def test_run_and_calibrate_refuse_a_configuration_in_use(held_config, capsys, argv):
    cfg, pid = held_config
    assert main([*argv, str(cfg)]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"another warpbridge (pid {pid}) is running" in err and "warpbridge-params.json" in err
    assert not (cfg.parent / "logs").exists()  # nothing was opened: no cycle log started beside the running one
