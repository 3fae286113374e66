"""MAVProxy as the ground station of the running bridge: lists, shows, sets parameters, sees telemetry.

MAVProxy talks to the mock autopilot's GCS port, which routes to the bridge process
(component 191, ``--target-component=191``), exactly as on an aircraft. Commands go in
on MAVProxy's stdin as a user would type them. Install it with
``pip install --no-deps MAVProxy`` (it then needs only pymavlink, pyserial and numpy,
which the project has already); skipped when it is not installed.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers import wait_while_working
from test_bridge_process import Rig

MAVPROXY = shutil.which("mavproxy.py") or str(Path(sys.executable).with_name("mavproxy.py"))
if not Path(MAVPROXY).exists():
    pytest.skip("MAVProxy not installed (pip install --no-deps MAVProxy)", allow_module_level=True)


class MavProxy:
    """mavproxy.py on the GCS port, fed commands on stdin; its output collected in a file."""

    def __init__(self, port: int, workdir: Path) -> None:
        self.out_path = workdir / "mavproxy.out"
        self._out = open(self.out_path, "w")
        self.proc = subprocess.Popen(
            [MAVPROXY, f"--master=udpin:127.0.0.1:{port}", "--target-system=1", "--target-component=191",
             "--no-state", "--default-modules=param"],
            stdin=subprocess.PIPE, stdout=self._out, stderr=subprocess.STDOUT, text=True, cwd=workdir)

    def wait(self, cond):
        """Wait until ``cond()`` while MAVProxy keeps working (``wait_while_working``)."""
        return wait_while_working(cond, self.proc.pid)

    def output(self) -> str:
        return self.out_path.read_text(errors="replace")

    def command(self, line: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()

    def close(self) -> None:
        try:
            self.command("exit")
            self.proc.wait(10)
        except (OSError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait(5)
        self._out.close()


def test_mavproxy_lists_sets_and_sees_the_bridge(tmp_path):
    rig = Rig(tmp_path)
    mp = None
    try:
        rig.start()
        rig.gcs.close()  # MAVProxy takes the GCS port
        mp = MavProxy(rig.gcs_port, tmp_path)
        # MAVProxy and the bridge answer as fast as a busy machine lets them: wait while MAVProxy works
        assert mp.wait(lambda: re.search(r"Received (\d+) parameters", mp.output())), mp.output()
        assert int(re.search(r"Received (\d+) parameters", mp.output()).group(1)) >= 21
        mp.command("param show WB_K*")
        assert mp.wait(lambda: "WB_KP            7.0" in mp.output()), mp.output()
        assert "WB_KI            1.0" in mp.output()

        mp.command("param set WB_KP 5")
        assert mp.wait(lambda: json.loads((tmp_path / "params.json").read_text())["params"].get("WB_KP") == 5.0
                        if (tmp_path / "params.json").exists() else False)
        mark = len(mp.output())
        mp.command("param show WB_KP")
        assert mp.wait(lambda: "WB_KP            5.0" in mp.output()[mark:]), mp.output()[mark:]

        mp.command("param set WB_KI 500")  # refused: the bridge says why, MAVProxy shows it
        assert mp.wait(lambda: "param WB_KI: 500 above max 50" in mp.output()), mp.output()

        time.sleep(0.5)
        mp.command("status NAMED_VALUE_FLOAT")
        assert mp.wait(lambda: "NAMED_VALUE_FLOAT {time_boot_ms" in mp.output()), mp.output()
    finally:
        if mp is not None:
            mp.close()
        rig.close()
    assert "Traceback" not in rig.stderr()
