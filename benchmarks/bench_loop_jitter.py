"""Loop period jitter of the bridge at 100 Hz, against plain loops measured in the same run.

``python benchmarks/bench_loop_jitter.py [--seconds 10]`` runs, one after the other, in this process:

- ``sleep``: ``time.sleep(period)`` after each iteration (the naive loop: it drifts);
- ``timer``: ``bridge.loop_timer.LoopTimer`` with no work (absolute deadlines);
- ``bridge``: ``run_bridge`` with the ``loop:`` servo backend, fed 50 Hz SERVO_OUTPUT_RAW by the mock
  autopilot in a separate process, ``wake_on_message = false`` so every cycle is a timer tick;
- ``bridge rt``: the same as ``warpbridge run`` with ``[loop] realtime = "auto"`` (``bridge.realtime``).

Periods come from the tick start times (the bridge's from its cycle log). It prints the median
period, p99 and max of |period - 10 ms|, and the ratio of each p99 to the timer baseline's.
"""

from __future__ import annotations

import argparse
import csv
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from warpbridge.bridge.app import run_bridge  # noqa: E402
from warpbridge.bridge.config import load_config  # noqa: E402
from warpbridge.bridge.loop_timer import LoopTimer  # noqa: E402

RATE = 100.0


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def naive(seconds: float) -> np.ndarray:
    ts = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        ts.append(time.monotonic())
        time.sleep(1.0 / RATE)
    return np.diff(ts)


def timer(seconds: float) -> np.ndarray:
    lt = LoopTimer(RATE)
    ts = []
    while lt.elapsed() < seconds:
        ts.append(time.monotonic())
        lt.wait()
    return np.diff(ts)


def bridge(seconds: float, workdir: Path, realtime: bool = False) -> np.ndarray:
    """The bridge's tick periods: in this process (``run_bridge``, ordinary scheduling), or with
    ``realtime`` as ``warpbridge run`` with ``[loop] realtime = "auto"`` (SCHED_FIFO etc. where permitted)."""
    port = free_udp_port()
    cfg = workdir / "wb.toml"
    wing = """
[wing.{n}]
source_channel = 1
reverse = {r}
servo_channel = {c}
bias_deg = 2.0
"""
    cfg.write_text(f"""
[link]
connection = "udpin:127.0.0.1:{port}"
servo_rate_hz = 50
[loop]
rate_hz = {RATE:g}
wake_on_message = false
log = "cycles.csv"
realtime = "{'auto' if realtime else 'off'}"
[params]
file = "params.json"
[servo]
backend = "loop:"
""" + wing.format(n="left", r="false", c=0) + wing.format(n="right", r="true", c=1))
    mock = subprocess.Popen([sys.executable, "-m", "warpbridge.sitl.mock_autopilot", "--fc-port", str(port),
                             "--duration", str(seconds + 5)], cwd=REPO)
    try:
        if realtime:
            out = subprocess.run([sys.executable, "-m", "warpbridge.bridge.cli", "run", "--config", str(cfg),
                                  "--duration", str(seconds)], cwd=workdir, capture_output=True, text=True)
            print("  bridge rt: " + "; ".join(ln.split("real time: ", 1)[1] for ln in out.stderr.splitlines()
                                               if "real time: " in ln))
        else:
            stop = threading.Event()
            threading.Timer(seconds, stop.set).start()
            run_bridge(load_config(cfg), stop_event=stop)
    finally:
        mock.terminate()
        mock.wait(5)
    with open(workdir / "cycles.csv") as f:
        t = np.array([float(r["t"]) for r in csv.DictReader(f)])
    return np.diff(t[int(RATE):])  # skip the first second (start-up)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        runs = {"sleep": naive(args.seconds), "timer": timer(args.seconds), "bridge": bridge(args.seconds, Path(d)),
                "bridge rt": bridge(args.seconds, Path(d), realtime=True)}
    period = 1.0 / RATE
    base99 = np.percentile(np.abs(runs["timer"] - period), 99)
    print(f"\nloop period at {RATE:g} Hz over {args.seconds:g} s")
    print(f"{'loop':<10} {'ticks':>6} {'median ms':>10} {'p50 |dev| ms':>13} {'p99 |dev| ms':>13} {'max ms':>8}"
          f" {'p99 x timer':>12}")
    for name, p in runs.items():
        dev = np.abs(p - period)
        print(f"{name:<10} {p.size:>6} {1e3 * np.median(p):>10.3f} {1e3 * np.median(dev):>13.3f} "
              f"{1e3 * np.percentile(dev, 99):>13.3f} {1e3 * dev.max():>8.2f} {np.percentile(dev, 99) / base99:>12.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
