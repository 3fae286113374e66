"""Start-up of ``warpbridge run``: peak memory, time to the first servo command, time to follow the FC.

``python benchmarks/bench_startup.py [--runs 5] [--duration 4]`` starts the real command,
``python -m warpbridge.bridge.cli run --config ...``, as a fresh process against the mock
autopilot (ArduPilot, aileron held at 1700 us, SERVO_OUTPUT_RAW at 50 Hz) and a Pololu
Maestro emulated on a pty (two tendon servos, two flex sensors reading 3 deg; mode
ff+pi, so the PI and the pre-tension estimator run). For each run it measures:

- ``rss``: the process's peak resident memory (``wait4`` ru_maxrss, the whole life of the process);
- ``first cmd``: from spawning the process to the first Set Target on the Maestro's pty;
- ``follows FC``: from spawning to the first cycle that follows the FC's aileron (the bridge's
  first ``WB_mode`` NAMED_VALUE_FLOAT that is not -1, as the mock autopilot receives it);
- ``cpu/cycle``: CPU time per 100 Hz cycle in steady state, from the process's rusage over a long
  and a short run (difference divided by the difference in cycles);

and, apart, the cost of one control cycle per kernel mode (``_tick_cost.py``: ``Bridge.tick`` with
both sensors, ff+pi, the pre-tension estimator on; median, mean and p99).

Variants: the default lean run path (kernels interpreted, ``model._jit``), with an empty numba cache
(``NUMBA_CACHE_DIR`` pointing at a fresh directory: the first boot of a new install) and with the
one the runs before it filled; and ``WARPBRIDGE_JIT=1`` (numba-compiled kernels in the loop),
cold and warm. Beside them, in the same run, the floor: a process that only imports numpy and
pymavlink (what any MAVLink companion program in Python loads). Medians over ``--runs``; the load
average is printed before and after, since every figure here moves with it.

Figures of an earlier version that imported every module at start (same machine): 237 MB peak, 2.5-3.8 s to
the first cycle.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "benchmarks"))
from _common import table  # noqa: E402

from warpbridge.sitl.maestro_emu import MaestroEmulator  # noqa: E402
from warpbridge.sitl.mock_autopilot import MockAutopilot  # noqa: E402

SENSOR_CH = {"left": 6, "right": 7}
COUNTS_3DEG = 3.0 / 20.0 * 1000.0  # sensor table 0..1000 counts -> 0..20 deg
OLD = {"rss": "237 MB", "first": "2.5-3.8 s (first cycle)"}

CONFIG = """
[link]
connection = "udpin:127.0.0.1:{port}"
[loop]
rate_hz = 100
[params]
file = "params.json"
[servo]
backend = "maestro:{maestro}"
[sensor]
backend = "maestro:"
[wing.left]
source_channel = 1
servo_channel = 0
sensor_channel = 6
bias_deg = 2
[wing.left.sensor]
counts = [0, 1000]
deg = [0, 20]
[wing.right]
source_channel = 1
reverse = true
servo_channel = 1
sensor_channel = 7
bias_deg = 2
[wing.right.sensor]
counts = [0, 1000]
deg = [0, 20]
"""


def tick_cost(mode: str) -> tuple[float, float, float]:
    """(median, mean, p99) ms of one ``Bridge.tick`` with the kernels ``mode``, in a process of its own."""
    env = {k: v for k, v in os.environ.items() if k != "WARPBRIDGE_JIT"}
    r = subprocess.run([sys.executable, str(REPO / "benchmarks" / "_tick_cost.py"), mode], capture_output=True,
                       text=True, env=env, timeout=600)
    if r.returncode != 0:
        raise RuntimeError(r.stderr[-2000:])
    a, b, c = (float(x) for x in r.stdout.split()[-3:])
    return a, b, c


class WatchingMock(MockAutopilot):
    """The mock autopilot, noting when the bridge first reports a mode that follows the FC."""

    following_at: float | None = None

    def _route(self, link_name, msg) -> None:
        if self.following_at is None and msg.get_type() == "NAMED_VALUE_FLOAT" \
                and str(msg.name).rstrip("\x00") == "WB_mode" and msg.value >= 0:
            self.following_at = time.monotonic()
        super()._route(link_name, msg)


def free_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_rusage(proc: subprocess.Popen, timeout: float) -> tuple[int, object]:
    """Wait for ``proc`` and return (status, its rusage)."""
    deadline = time.monotonic() + timeout
    while True:
        pid, status, ru = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            proc.returncode = os.waitstatus_to_exitcode(status)
            return proc.returncode, ru
        if time.monotonic() > deadline:
            proc.kill()
        time.sleep(0.02)


def run_bridge(duration: float, env_extra: dict[str, str]) -> dict[str, float]:
    """One fresh ``warpbridge run``; its figures."""
    with tempfile.TemporaryDirectory(prefix="wb-bench-start-") as tmp:
        folder = Path(tmp)
        first: list[float] = []
        emu = MaestroEmulator(on_target=lambda ch, q: first.append(time.monotonic()) if not first else None,
                              read_analog=lambda ch: int(COUNTS_3DEG) if ch in SENSOR_CH.values() else None,
                              link=folder / "maestro")
        emu.start()
        port = free_port()
        mock = WatchingMock(port, autopilot="ardupilot", jitter_us=0, roll_source=lambda t: {1: 1700.0, 2: 1500.0})
        mock.start()
        (folder / "wb.toml").write_text(CONFIG.format(port=port, maestro=folder / "maestro"))
        env = {k: v for k, v in os.environ.items() if k != "WARPBRIDGE_JIT"}
        env.update(env_extra)
        try:
            t0 = time.monotonic()
            proc = subprocess.Popen([sys.executable, "-m", "warpbridge.bridge.cli", "-q", "run", "--config",
                                     str(folder / "wb.toml"), "--duration", str(duration)],
                                    cwd=folder, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
            rc, ru = wait_rusage(proc, duration + 120.0)
            err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
        finally:
            mock.stop()
            emu.stop()
        if rc != 0:
            raise RuntimeError(f"warpbridge run exited {rc}: {err[-2000:]}")
        return {"rss_mb": ru.ru_maxrss / 1024.0, "first_s": (first[0] - t0) if first else float("nan"),
                "follow_s": (mock.following_at - t0) if mock.following_at else float("nan"),
                "cpu_s": ru.ru_utime + ru.ru_stime}


def floor_process() -> dict[str, float]:
    """A process that imports numpy and pymavlink and exits: the floor of any Python MAVLink companion."""
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-c", "import numpy, pymavlink.mavutil"], env={**os.environ,
                            "MAVLINK20": "1"})
    _, ru = wait_rusage(proc, 60.0)
    return {"rss_mb": ru.ru_maxrss / 1024.0, "first_s": time.monotonic() - t0}


def med(rows: list[dict[str, float]], key: str) -> float:
    vals = [r[key] for r in rows if r[key] == r[key]]
    return statistics.median(vals) if vals else float("nan")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5, help="runs per variant (medians reported)")
    ap.add_argument("--duration", type=float, default=4.0, help="seconds each bridge runs")
    ap.add_argument("--cpu-extra", type=float, default=6.0, help="extra seconds of the long runs for cpu/cycle")
    args = ap.parse_args(argv)
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())} ({os.cpu_count()} CPUs)")
    with tempfile.TemporaryDirectory(prefix="wb-numba-warm-") as warm_dir:
        variants = [
            ("lean (interpreted kernels), empty numba cache", lambda: {"NUMBA_CACHE_DIR": tempfile.mkdtemp()}),
            ("lean (interpreted kernels), warm numba cache", lambda: {"NUMBA_CACHE_DIR": warm_dir}),
            ("WARPBRIDGE_JIT=1 (compiled), empty cache",
             lambda: {"NUMBA_CACHE_DIR": tempfile.mkdtemp(), "WARPBRIDGE_JIT": "1"}),
            ("WARPBRIDGE_JIT=1 (compiled), warm cache", lambda: {"NUMBA_CACHE_DIR": warm_dir, "WARPBRIDGE_JIT": "1"}),
        ]
        run_bridge(args.duration, {"NUMBA_CACHE_DIR": warm_dir, "WARPBRIDGE_JIT": "1"})  # fill the warm cache
        results: dict[str, list[dict[str, float]]] = {}
        long_runs: dict[str, list[dict[str, float]]] = {}
        for i in range(args.runs):  # interleaved, so that a change of load hits every variant alike
            for name, env in variants:
                results.setdefault(name, []).append(run_bridge(args.duration, env()))
                print(f"  run {i + 1}/{args.runs} {name}: " + ", ".join(
                    f"{k} {v:.3g}" for k, v in results[name][-1].items()), flush=True)
        for name, env in (variants[1], variants[3]):
            long_runs[name] = [run_bridge(args.duration + args.cpu_extra, env()) for _ in range(max(1, args.runs // 2))]
        floors = [floor_process() for _ in range(args.runs)]
    floor_rss, floor_t = med(floors, "rss_mb"), med(floors, "first_s")
    rows = [["floor: python -c 'import numpy, pymavlink.mavutil'", floor_rss, 1.0, floor_t, "-", "-"]]
    for name, rs in results.items():
        cpu = "-"
        if name in long_runs:
            extra_cycles = args.cpu_extra * 100.0
            cpu = f"{1e3 * (med(long_runs[name], 'cpu_s') - med(rs, 'cpu_s')) / extra_cycles:.3f}"
        rows.append([name, med(rs, "rss_mb"), med(rs, "rss_mb") / floor_rss, med(rs, "first_s"), med(rs, "follow_s"),
                     cpu])
    print()
    print(table(rows, ["process", "peak RSS MB", "x floor", "first servo cmd s", "follows FC s", "cpu ms/cycle"]))
    print(f"\nmedians of {args.runs} runs each ({args.duration:g} s per run; first servo cmd and the floor's time are"
          f" from spawning the process: for the floor, to its exit)")
    print(f"an earlier version importing every module at start: peak RSS {OLD['rss']}, {OLD['first']}")
    n_tick = max(1, args.runs // 2)
    ticks = {mode: [tick_cost(mode) for _ in range(n_tick)] for mode in ("interpreted", "compiled")}
    print()
    print(table([[mode, *(statistics.median(r[i] for r in rs) for i in range(3))] for mode, rs in ticks.items()],
                ["kernels", "tick median ms", "tick mean ms", "tick p99 ms"]))
    print(f"one Bridge.tick (both sensors, ff+pi, estimator on): medians over {n_tick} processes of 3000 cycles")
    print("targets: peak RSS < 100 MB; first servo command < 1 s with a warm cache")
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
