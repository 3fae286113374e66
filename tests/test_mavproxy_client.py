"""MAVProxy as the ground station of the running bridge: lists, shows, sets parameters, sees telemetry.

MAVProxy talks to the mock autopilot's GCS port, which routes to the bridge process
(component 191, ``--target-component=191``), exactly as on an aircraft. It runs with its
default modules, as a user starts it, so it fetches parameters over MAVLink FTP first.
Commands go in on MAVProxy's stdin as a user would type them (``--cmd`` runs before
the link is up). Install it with ``pip install --no-deps MAVProxy`` (it then needs only
pymavlink, pyserial and numpy, which the project has already); skipped when it is not
installed.
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
from test_bridge_process import Rig, wait_for

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
             "--no-state"],
            stdin=subprocess.PIPE, stdout=self._out, stderr=subprocess.STDOUT, text=True, cwd=workdir)

    def wait(self, cond):
        """Wait until ``cond()`` while MAVProxy keeps working (``wait_while_working``)."""
        return wait_while_working(cond, self.proc.pid)

    def output(self) -> str:
        return self.out_path.read_text(errors="replace")

    def timed(self, line: str, pattern: str, timeout: float = 30.0) -> tuple[float, re.Match | None]:
        """Send ``line``; seconds until ``pattern`` first appears in the output after it, and the match."""
        mark = len(self.output())
        t0 = time.monotonic()
        self.command(line)
        found = wait_for(lambda: re.search(pattern, self.output()[mark:]), timeout, step=0.005)
        return time.monotonic() - t0, found or None

    def command(self, line: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()

    def close(self) -> None:
        """Stop MAVProxy as a user at its prompt would: ``exit``, then the end of its input, which
        the prompt is blocked reading; killed only if it does not stop."""
        try:
            self.command("exit")
            assert self.proc.stdin is not None
            self.proc.stdin.close()
            self.proc.wait(10)
        except (OSError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait(5)
        self._out.close()


@pytest.mark.slow
def test_mavproxy_lists_sets_and_sees_the_bridge(tmp_path):
    rig = Rig(tmp_path)
    mp = None
    try:
        rig.start()
        rig.gcs.close()  # MAVProxy takes the GCS port
        mp = MavProxy(rig.gcs_port, tmp_path)
        # MAVProxy and the bridge answer as fast as a busy machine lets them: wait while MAVProxy works
        assert mp.wait(lambda: re.search(r"Received (\d+) parameters", mp.output())), mp.output()
        assert re.search(r"Received (\d+) parameters \(ftp\)", mp.output()), mp.output()  # FTP answered
        assert int(re.search(r"Received (\d+) parameters", mp.output()).group(1)) >= 21
        assert "FTP: request timed out" not in mp.output()
        mp.command("param show WB_K*")
        assert mp.wait(lambda: "WB_KP            7.0" in mp.output()), mp.output()
        assert "WB_KI            1.0" in mp.output()

        mp.command("param set WB_KP 5")
        assert mp.wait(lambda: json.loads((tmp_path / "params.json").read_text())["params"].get("WB_KP") == 5.0
                        if (tmp_path / "params.json").exists() else False)
        mark = len(mp.output())

        def shown() -> bool:  # MAVProxy's table follows the echo when its loop gets to it: ask again
            mp.command("param show WB_KP")
            return wait_for(lambda: "WB_KP            5.0" in mp.output()[mark:], 1.0)

        assert mp.wait(shown), mp.output()[mark:]

        mp.command("param set WB_KI 500")  # refused: the bridge says why, MAVProxy shows it
        assert mp.wait(lambda: "param WB_KI: 500 above max 50" in mp.output()), mp.output()
        time.sleep(3.5)  # MAVProxy re-sends the set (3 attempts, 1 s apart) as the echo keeps the old value
        assert mp.output().count("param WB_KI: 500 above max 50") == 1, mp.output()  # reported once

        time.sleep(0.5)
        mp.command("status NAMED_VALUE_FLOAT")
        assert mp.wait(lambda: "NAMED_VALUE_FLOAT {time_boot_ms" in mp.output()), mp.output()
    finally:
        if mp is not None:
            mp.close()
        rig.close()
    assert "Traceback" not in rig.stderr()


@pytest.mark.slow
def test_mavproxy_parameter_fetch_over_ftp_beats_the_plain_list(tmp_path):
    """MAVProxy fetches over MAVLink FTP first; answered at once, that takes two round trips, faster
    than the plain PARAM_REQUEST_LIST (paced for a radio), where an unanswered FTP would cost its ten
    1 s retries first. Three fetches each way in the same run; the best of each is compared, as a busy
    machine stretches single round trips."""
    rig = Rig(tmp_path)
    mp = None
    try:
        rig.start()
        rig.gcs.close()
        mp = MavProxy(rig.gcs_port, tmp_path)
        assert mp.wait(lambda: "Received" in mp.output()), mp.output()
        n = int(re.search(r"Received (\d+) parameters \(ftp\)", mp.output()).group(1))
        times: dict[str, list[float]] = {"ftp": [], "list": []}
        for how, setting, pattern in (("ftp", "1", r"Received (\d+) parameters \(ftp\)"),
                                      ("list", "0", r"Received (\d+) parameters\n")):
            mp.command(f"set param_ftp {setting}")
            for _ in range(3):
                took, m = mp.timed("param fetch", pattern)
                assert m is not None and int(m.group(1)) == n, mp.output()
                times[how].append(took)
        print(f"MAVProxy parameter fetch of {n} parameters, 3 each: FTP {sorted(times['ftp'])} s, "
              f"PARAM_REQUEST_LIST {sorted(times['list'])} s")
        assert "FTP: request timed out" not in mp.output() and "retry" not in mp.output().lower()
        assert min(times["ftp"]) < min(times["list"])
    finally:
        if mp is not None:
            mp.close()
        rig.close()
