"""The bridge's latency and loop timing under CPU contention, with and without its real-time settings.

``python benchmarks/bench_contention.py [--seconds 10] [--rates 100,400] [--loads idle,shared,both]``
runs the real bridge (``warpbridge run``: open mode, no sensor, a Maestro emulator on a pty) fed
SERVO_OUTPUT_RAW over loopback UDP by a minimal sender in this process (each message a new aileron,
so each asks for a new pulse), and times every message from ``sendto`` to its Set Target bytes on
the pty. Under each load, measured in the same run, one after the other:

- ``baseline``: a plain pymavlink recv -> Maestro write process (no control), ordinary scheduling;
- ``rt off``: the bridge with ``[loop] realtime = "off"`` (ordinary scheduling, nothing locked);
- ``rt auto``: the bridge with ``[loop] realtime = "auto"`` (SCHED_FIFO 20, locked memory, frozen gc
  where permitted; its log line says what was applied and refused).

Loads: ``idle`` (nothing else), ``shared`` (a busy-loop process pinned to the core the bridge is
pinned to, as a camera process sharing the bridge's core), ``both`` (a busy loop on every core; the
bridge unpinned). This process (sender, emulator) is pinned to another core and, where permitted,
runs at SCHED_FIFO 30, so that its timestamps are not the thing being delayed.

Per variant and rate it prints p50 / p99 / max latency (ms) of the messages whose pulse was written,
how many were skipped (never written: a later message reached the bridge before it ran a cycle for
this one, so it wrote the later one; the baseline writes every message), and from the bridge's
cycle log over the measured window: missed ticks (periods of the 100 Hz loop with no tick: the
timer skipped them) and late ticks (started more than 1 ms after their deadline), and the ratio of
each p99 to the baseline's under the same load. Last, the pause a full garbage
collection costs a process that imported the bridge, before and after ``gc.freeze``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH))
from bench_latency import (  # noqa: E402
    BASELINE,
    MATCH_S,
    REPO,
    aileron_sequence,
    config,
    expected_pulse,
    free_udp_port,
    mavlink,
    mavutil,
)

from warpbridge.sitl.maestro_emu import MaestroEmulator  # noqa: E402

LOOP_HZ = 100.0
LATE_S = 0.001
NEUTRAL_DEG = 2.0  # the left wing's setpoint at neutral aileron (bias_deg in bench_latency's config)
HOG = "while True: pass\n"
ALL_CPUS = frozenset(os.sched_getaffinity(0))


def cores() -> tuple[int, int]:
    """(core for the bridge, core for this process): the last and the first this process may use."""
    return max(ALL_CPUS), min(ALL_CPUS)


def child_setup(cpus: frozenset[int] | set[int] = ALL_CPUS):
    """``preexec_fn`` of every child: ordinary scheduling (not this process's SCHED_FIFO) on ``cpus``."""
    def setup() -> None:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        os.sched_setaffinity(0, cpus)
    return setup


def start_hogs(load: str, bridge_core: int) -> list[subprocess.Popen]:
    if load == "idle":
        return []
    targets = [bridge_core] if load == "shared" else sorted(ALL_CPUS)
    return [subprocess.Popen([sys.executable, "-c", HOG], preexec_fn=child_setup({c})) for c in targets]


def stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        p.kill()
    for p in procs:
        p.wait(5)


def make_fast() -> str:
    """Pin this process to its core and raise it to SCHED_FIFO 30 if permitted (its threads, started
    later, inherit both; its children do not: ``child_setup``); say which."""
    _, mine = cores()
    os.sched_setaffinity(0, {mine})
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(30))
        return f"sender/emulator on CPU {mine} at SCHED_FIFO 30"
    except OSError as e:
        return f"sender/emulator on CPU {mine}, ordinary scheduling (SCHED_FIFO refused: {e.strerror})"


class Stream:
    """The FC side: a UDP sender of SERVO_OUTPUT_RAW and the Maestro emulator recording Set Targets."""

    def __init__(self) -> None:
        self.arrivals: list[tuple[float, float]] = []
        self.lock = threading.Lock()
        self.emu = MaestroEmulator(on_target=self._on_target)
        self.path = self.emu.start()
        self.port = free_udp_port()
        self.fc = mavutil.mavlink_connection(f"udpout:127.0.0.1:{self.port}", source_system=1, source_component=1)

    def _on_target(self, ch: int, q: int) -> None:
        if ch == 0:
            with self.lock:
                self.arrivals.append((time.perf_counter(), q / 4))

    def heartbeat(self) -> None:
        self.fc.mav.heartbeat_send(mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0)

    def warm_up(self, proc: subprocess.Popen, timeout: float = 120.0) -> None:
        """Neutral messages until the process writes to the servo, then 1 s more."""
        t_ready, end = None, time.monotonic() + timeout
        while time.monotonic() < end and (t_ready is None or time.monotonic() < t_ready + 1.0):
            if proc.poll() is not None:
                raise RuntimeError(f"the process exited: {proc.stderr.read() if proc.stderr else ''}")
            self.heartbeat()
            self.fc.mav.servo_output_raw_send(0, 0, 1500, 1500, 0, 0, 0, 0, 0, 0)
            time.sleep(0.02)
            if t_ready is None and self.arrivals:
                t_ready = time.monotonic()
        if t_ready is None:
            raise RuntimeError("the process never wrote to the servo")

    def send(self, rate: float, seconds: float) -> tuple[np.ndarray, np.ndarray, float]:
        """Messages at ``rate`` for ``seconds``: (aileron per message, send time per message, t0)."""
        with self.lock:
            self.arrivals.clear()
        n = int(rate * seconds)
        seq, sent = aileron_sequence(n), np.zeros(n)
        period = 1.0 / rate
        t0 = next_hb = time.perf_counter()
        for k in range(n):
            target = t0 + k * period
            while (now := time.perf_counter()) < target - 0.0005:
                time.sleep(max(0.0, target - now - 0.0005))
            while time.perf_counter() < target:
                pass
            if target >= next_hb:
                next_hb += 1.0
                self.heartbeat()
            sent[k] = time.perf_counter()
            self.fc.mav.servo_output_raw_send(k & 0xFFFFFFFF, 0, int(seq[k]), 1500, 0, 0, 0, 0, 0, 0)
        time.sleep(0.3)
        for _ in range(int(0.5 * rate)):  # back to neutral between streams, so the next starts from it
            self.fc.mav.servo_output_raw_send(0, 0, 1500, 1500, 0, 0, 0, 0, 0, 0)
            time.sleep(period)
        return seq, sent, t0

    def latencies(self, seq: np.ndarray, sent: np.ndarray, kind: str) -> np.ndarray:
        """Per message: seconds to the first Set Target of its pulse after it was sent (NaN: never)."""
        with self.lock:
            arr = [a for a in self.arrivals]
        lat = np.full(len(seq), np.nan)
        j = 0
        for k in range(len(seq)):
            want = expected_pulse(seq[k], kind)
            while j < len(arr) and arr[j][0] < sent[k]:
                j += 1
            for t, p in arr[j:]:
                if t > sent[k] + MATCH_S:
                    break  # skipped: a later message's pulse was written instead
                if abs(p - want) < 0.13:
                    lat[k] = t - sent[k]
                    break
        return lat

    def close(self) -> None:
        self.fc.close()
        self.emu.stop()


def tick_stats(log: Path, t_from: float, t_to: float) -> tuple[int, int, int]:
    """From a bridge cycle log, over log times [t_from, t_to]: (ticks, missed, late > LATE_S).

    The first cycle in each loop period is its tick; a period with none was skipped."""
    with open(log) as f:
        t = np.array([float(r["t"]) for r in csv.DictReader(f)])
    t = t[(t >= t_from) & (t <= t_to)]
    if t.size == 0:
        return 0, 0, 0
    k = np.floor(t * LOOP_HZ + 1e-9).astype(np.int64)
    first = np.ones(t.size, dtype=bool)
    first[1:] = k[1:] != k[:-1]
    ticks = int(np.count_nonzero(first))
    missed = int(k[-1] - k[0] + 1) - ticks
    late = int(np.count_nonzero(t[first] - k[first] / LOOP_HZ > LATE_S))
    return ticks, missed, late


def run_variant(kind: str, load: str, rates: list[float], seconds: float, workdir: Path, bridge_core: int) -> dict:
    stream = Stream()
    env = dict(os.environ, PYTHONPATH=str(REPO))
    name = f"{kind.replace(' ', '-')}-{load}"
    pin = bridge_core if load == "shared" else None  # the hog's core; in "both" the bridge is free
    if kind == "baseline":
        cmd = [sys.executable, "-c", BASELINE, str(stream.port), stream.path]
    else:
        extra = f'realtime = "{kind.split()[1]}"' + (f"\ncpu = {pin}" if pin is not None else "")
        cfg = workdir / f"{name}.toml"
        cfg.write_text(config(stream.port, stream.path, wake=True, loop_extra=extra, log_name=name))
        cmd = [sys.executable, "-m", "warpbridge.bridge.cli", "run", "--config", str(cfg)]

    # the pin is the environment (like systemd's CPUAffinity=), whatever the bridge's own settings
    log_path = workdir / f"{name}.stderr"
    with open(log_path, "w") as err:
        proc = subprocess.Popen(cmd, cwd=workdir, env=env, stderr=err,
                                preexec_fn=child_setup(ALL_CPUS if pin is None else {pin}))
    hogs: list[subprocess.Popen] = []
    out: dict = {}
    try:
        stream.warm_up(proc)
        hogs = start_hogs(load, bridge_core)
        time.sleep(1.0)
        for rate in rates:
            seq, sent, _ = stream.send(rate, seconds)
            out[rate] = {"lat": stream.latencies(seq, sent, "baseline" if kind == "baseline" else "bridge")}
    finally:
        stop(hogs)
        proc.send_signal(15)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
        stream.close()
    out["log"] = log_path.read_text(errors="replace")
    if kind != "baseline":
        for rate, seg in zip(rates, streams_in_log(workdir / f"{name}-cycles.csv"), strict=False):
            out[rate]["ticks"] = tick_stats(workdir / f"{name}-cycles.csv", *seg)
    return out


def streams_in_log(log: Path) -> list[tuple[float, float]]:
    """(first, last) log time of each message stream: the runs of cycles whose left setpoint is off
    neutral (every message of a stream is; half a second of neutral separates the streams)."""
    with open(log) as f:
        rows = [(float(r["t"]), float(r["left_setpoint"])) for r in csv.DictReader(f)]
    t = np.array([x for x, sp in rows if sp != NEUTRAL_DEG])
    if t.size == 0:
        return []
    cut = np.flatnonzero(np.diff(t) > 0.2)
    starts, ends = np.r_[0, cut + 1], np.r_[cut, t.size - 1]
    return [(float(t[a]), float(t[b])) for a, b in zip(starts, ends, strict=True)]


GC_PROBE = """
import gc, json, time
import warpbridge.bridge.cmd_run  # what `warpbridge run` imports before its loop
def full():
    t = time.perf_counter(); gc.collect(); return time.perf_counter() - t
n = len(gc.get_objects())
before = sorted(full() for _ in range(5))[2]
gc.freeze()
after = sorted(full() for _ in range(5))[2]
print(json.dumps({"objects": n, "before": before, "after": after}))
"""


def gc_pause() -> dict:
    """Median time of a full garbage collection in a process that imported the bridge, before and after
    ``gc.freeze`` (what ``[loop] realtime`` does before the loop)."""
    out = subprocess.run([sys.executable, "-c", GC_PROBE], capture_output=True, text=True, check=True,
                         preexec_fn=child_setup())
    return json.loads(out.stdout)


def realtime_lines(text: str) -> str:
    lines = [ln.split("real time: ", 1)[1] for ln in text.splitlines() if "real time: " in ln]
    return "; ".join(lines) or "-"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="seconds of messages per rate (default 10)")
    ap.add_argument("--rates", default="100,400", help="message rates, Hz (default 100,400)")
    ap.add_argument("--loads", default="idle,shared,both", help="idle, shared, both (default all three)")
    ap.add_argument("--variants", default="baseline,rt off,rt auto")
    args = ap.parse_args()
    rates = [float(r) for r in args.rates.split(",")]
    loads = [x.strip() for x in args.loads.split(",")]
    variants = [x.strip() for x in args.variants.split(",")]
    bridge_core, _ = cores()
    harness = make_fast()
    print(f"{os.cpu_count()} cores; bridge core {bridge_core}; {harness}; load average before: "
          f"{' '.join(open('/proc/loadavg').read().split()[:3])}", flush=True)
    results: dict = {}
    with tempfile.TemporaryDirectory() as d:
        for load in loads:
            for kind in variants:
                print(f"  {load:<6} {kind:<8} ...", flush=True)
                results[(load, kind)] = run_variant(kind, load, rates, args.seconds, Path(d), bridge_core)
    print(f"\nSERVO_OUTPUT_RAW -> Set Target on the pty, {args.seconds:g} s per rate; loop {LOOP_HZ:g} Hz; "
          f"late: tick > {1e3 * LATE_S:g} ms after its deadline; load average after: "
          f"{' '.join(open('/proc/loadavg').read().split()[:3])}")
    print(f"{'load':<7}{'variant':<10}{'Hz':>5}{'msgs':>6}{'skip':>6}{'p50 ms':>9}{'p99 ms':>9}{'max ms':>9}"
          f"{'ticks':>7}{'missed':>7}{'late':>6}{'p99 x base':>11}")
    for load in loads:
        for rate in rates:
            base = results.get((load, "baseline"), {}).get(rate)
            b99 = np.nanpercentile(base["lat"], 99) if base is not None and np.isfinite(base["lat"]).any() else None
            for kind in variants:
                r = results[(load, kind)].get(rate)
                lat = r["lat"] * 1e3
                ok = np.isfinite(lat)
                if not ok.any():
                    print(f"{load:<7}{kind:<10}{rate:>5g}{lat.size:>6}{lat.size:>6}  no message reached the servo")
                    continue
                p50, p99, mx = np.percentile(lat[ok], 50), np.percentile(lat[ok], 99), lat[ok].max()
                ticks, missed, late = r.get("ticks", ("-", "-", "-"))
                ratio = f"{p99 / (1e3 * b99):.1f}" if b99 else "-"
                print(f"{load:<7}{kind:<10}{rate:>5g}{lat.size:>6}{np.count_nonzero(~ok):>6}{p50:>9.3f}{p99:>9.3f}"
                      f"{mx:>9.2f}{ticks:>7}{missed:>7}{late:>6}{ratio:>11}")
    g = gc_pause()
    print(f"\nfull garbage collection in a process that imported the bridge ({g['objects']} objects): "
          f"{1e3 * g['before']:.1f} ms; after gc.freeze: {1e6 * g['after']:.0f} us (medians of 5)")
    print("\nreal-time settings as the bridge logged them:")
    for kind in variants:
        if kind != "baseline":
            for load in loads:
                print(f"  {kind} / {load}: {realtime_lines(results[(load, kind)]['log'])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
