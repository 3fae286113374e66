"""Latency from a SERVO_OUTPUT_RAW datagram on loopback to the Maestro bytes, and CPU per cycle.

``python benchmarks/bench_latency.py [--messages 10000] [--rate 400]`` sends SERVO_OUTPUT_RAW
(plus a 1 Hz HEARTBEAT) from this process to UDP 127.0.0.1, with the aileron ramping so every
message asks for a different pulse (a pulse not written within 0.5 s is counted unmatched: the
bridge had a later message first), and times when the matching Set Target (0x84) bytes arrive
on a Maestro emulator's pty. The same stream goes, one after the other, to:

- ``baseline``: a plain pymavlink recv -> Maestro write loop, no control (a separate process);
- ``bridge``: ``warpbridge run`` (open mode, no sensor), waking on each message (the default),
  with ``[loop] realtime`` as ``--realtime`` says (default auto);
- ``bridge-tick``: the same with ``wake_on_message = false``: the message waits for the 100 Hz tick.

It prints p50/p99/max latency, CPU per message or control cycle (from the process's rusage), and
the ratios to the baseline measured in the same run. Target: bridge p99 under 2 ms at 400 Hz.
"""

from __future__ import annotations

import argparse
import csv
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from warpbridge.bridge.controller import straight_line  # noqa: E402
from warpbridge.model.boucwen import BoucWenParams  # noqa: E402
from warpbridge.sitl.maestro_emu import MaestroEmulator  # noqa: E402

mavlink = mavutil.mavlink
PULSE_ZERO, MM_PER_US = 1200.0, 0.02

BASELINE = r'''
import os, sys
os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil
import serial
port = serial.Serial(sys.argv[2], 115200, timeout=0.02)
mav = mavutil.mavlink_connection(f"udpin:127.0.0.1:{sys.argv[1]}", source_system=1, source_component=191)
n = 0
while True:
    m = mav.recv_match(type="SERVO_OUTPUT_RAW", blocking=True, timeout=3)
    if m is None:
        break
    q = round(m.servo1_raw * 4)
    port.write(bytes([0x84, 0, q & 0x7F, (q >> 7) & 0x7F]))
    n += 1
print(n, file=sys.stderr)
'''


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def config(port: int, maestro: str, wake: bool, loop_extra: str = "", log_name: str | None = None) -> str:
    """The bridge's TOML: open mode, no sensor, both wings on FC output 1; ``loop_extra``: more [loop] keys."""
    wing = """
[wing.{name}]
source_channel = 1
reverse = {rev}
servo_channel = {ch}
bias_deg = 2.0
max_warp_deg = 8.0
[wing.{name}.servo]
pulse_zero_us = 1200
mm_per_us = 0.02
[wing.{name}.control]
mode = "open"
"""
    return f"""
[link]
connection = "udpin:127.0.0.1:{port}"
servo_rate_hz = 400
pwm_jitter_us = 0
[loop]
rate_hz = 100
failsafe_timeout_s = 0.5
wake_on_message = {"true" if wake else "false"}
log = "{log_name or ('bridge' if wake else 'bridge-tick')}-cycles.csv"
{loop_extra}
[telemetry]
rate_hz = 10
[params]
file = "params.json"
[servo]
backend = "maestro:{maestro}"
[sensor]
backend = "none"
""" + wing.format(name="left", rev="false", ch=0) + wing.format(name="right", rev="true", ch=1)


MATCH_S = 0.5  # a message's pulse is looked for this long after it was sent; the same pulse recurs 1 s later


def aileron_sequence(n: int) -> np.ndarray:
    """A sawtooth 1501 -> 1900 us in 1 us steps, again and again: each message a new pulse on the left
    wing (0.5 us apart, above the Maestro's 0.25 us), the same one again only 400 messages later."""
    return 1501 + np.arange(n) % 400


def expected_pulse(aileron: float, kind: str) -> float:
    if kind == "baseline":
        return round(aileron * 4) / 4
    slope, offset = straight_line(BoucWenParams.paper(), 8.0)
    a = (aileron - 1500) / 400
    w = 2.0 + a * 6.0 if a >= 0 else 2.0 * (1 + a)
    p = PULSE_ZERO + (slope * w + offset) / MM_PER_US
    return round(min(2000, max(1000, p)) * 4) / 4


def run(kind: str, n: int, rate: float, workdir: Path, realtime: str = "auto") -> dict:
    arrivals: list[tuple[float, float]] = []
    lock = threading.Lock()

    def on_target(ch: int, q: int) -> None:
        if ch == 0:
            with lock:
                arrivals.append((time.perf_counter(), q / 4))

    emu = MaestroEmulator(on_target=on_target)
    path = emu.start()
    port = free_udp_port()
    env = dict(os.environ, PYTHONPATH=str(REPO))
    if kind == "baseline":
        cmd = [sys.executable, "-c", BASELINE, str(port), path]
    else:
        cfg = workdir / f"{kind}.toml"
        cfg.write_text(config(port, path, wake=(kind == "bridge"), loop_extra=f'realtime = "{realtime}"'))
        cmd = [sys.executable, "-m", "warpbridge.bridge.cli", "run", "--config", str(cfg)]
    proc = subprocess.Popen(cmd, cwd=workdir, env=env, stderr=subprocess.PIPE, text=True)
    fc = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1)
    seq = aileron_sequence(n)
    period = 1.0 / rate
    sent = np.zeros(n)

    def heartbeat() -> None:
        fc.mav.heartbeat_send(mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0)

    # warm up until the process writes to the servo, then 1 s more (imports, model compile, FC learned)
    t_ready = None
    t_end = time.monotonic() + 60.0
    while time.monotonic() < t_end and (t_ready is None or time.monotonic() < t_ready + 1.0):
        heartbeat()
        fc.mav.servo_output_raw_send(0, 0, 1500, 1500, 0, 0, 0, 0, 0, 0)
        time.sleep(0.02)
        if t_ready is None and arrivals:
            t_ready = time.monotonic()
    with lock:
        arrivals.clear()
    cpu0 = cpu_seconds(proc.pid)
    t0 = time.perf_counter()
    next_hb = t0
    for k in range(n):
        target = t0 + k * period
        while (now := time.perf_counter()) < target - 0.0005:
            time.sleep(max(0.0, target - now - 0.0005))
        while time.perf_counter() < target:
            pass
        if target >= next_hb:
            next_hb += 1.0
            heartbeat()
        sent[k] = time.perf_counter()
        fc.mav.servo_output_raw_send(k & 0xFFFFFFFF, 0, int(seq[k]), 1500, 0, 0, 0, 0, 0, 0)
    time.sleep(0.2)
    cpu = cpu_seconds(proc.pid) - cpu0
    window = time.perf_counter() - t0
    proc.send_signal(15)
    _, err = proc.communicate(timeout=20)
    fc.close()
    emu.stop()
    cycles = count_cycles(workdir / f"{kind}-cycles.csv") if kind != "baseline" else n

    # match each message to the first write of its pulse after it was sent
    with lock:
        arr = list(arrivals)
    lat = []
    j = 0
    for k in range(n):
        want = expected_pulse(seq[k], kind)
        while j < len(arr) and arr[j][0] < sent[k]:
            j += 1
        for t, p in arr[j:]:
            if t > sent[k] + MATCH_S:
                break  # never written: the bridge had a later message before it ran a cycle for this one
            if abs(p - want) < 0.13:
                lat.append(t - sent[k])
                break
    return {"lat": np.array(lat), "matched": len(lat), "n": n, "cycles": cycles, "cpu": cpu, "window": window,
            "err": err}


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def count_cycles(log: Path) -> int | None:
    """Control cycles in the measured window: cycle-log rows from the first one off neutral."""
    if not log.exists():
        return None
    with open(log) as f:
        rows = list(csv.DictReader(f))
    first = next((i for i, r in enumerate(rows) if r["left_setpoint"] not in ("2", "2.0")), None)
    return None if first is None else len(rows) - first


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--messages", type=int, default=10000)
    ap.add_argument("--rate", type=float, default=400.0)
    ap.add_argument("--only", choices=["baseline", "bridge", "bridge-tick"], action="append")
    ap.add_argument("--realtime", choices=["auto", "off"], default="auto",
                    help="the bridge's [loop] realtime (auto: SCHED_FIFO etc. where permitted)")
    args = ap.parse_args()
    kinds = args.only or ["baseline", "bridge", "bridge-tick"]
    rows = {}
    with tempfile.TemporaryDirectory() as d:
        for kind in kinds:
            n = args.messages if kind != "bridge-tick" else min(args.messages, 4000)
            r = run(kind, n, args.rate, Path(d), args.realtime)
            rows[kind] = r
            if r["matched"] < 0.9 * r["n"]:
                print(f"{kind}: only {r['matched']}/{r['n']} messages matched; stderr tail:\n{r['err'][-800:]}")
    print(f"\nSERVO_OUTPUT_RAW at {args.rate:g} Hz on loopback UDP -> Maestro Set Target on a pty "
          f"(bridge [loop] realtime = {args.realtime})")
    print(f"{'variant':<12} {'msgs':>6} {'matched':>8} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8} "
          f"{'cycles':>7} {'CPU us/cycle':>13} {'CPU %':>6} {'p50 x':>6} {'p99 x':>6}")
    base = rows.get("baseline")
    for kind, r in rows.items():
        lat = r["lat"] * 1e3
        if lat.size == 0:
            print(f"{kind:<12} no matches")
            continue
        p50, p99, mx = np.percentile(lat, 50), np.percentile(lat, 99), lat.max()
        cpu = r["cpu"]
        per = f"{1e6 * cpu / r['cycles']:.0f}" if r["cycles"] else "-"
        pct = f"{100 * cpu / r['window']:.0f}"
        ratio50 = ratio99 = "-"
        if base is not None and base["lat"].size:
            ratio50 = f"{p50 / (1e3 * statistics.median(base['lat'])):.1f}"
            ratio99 = f"{p99 / (1e3 * np.percentile(base['lat'], 99)):.1f}"
        print(f"{kind:<12} {r['n']:>6} {r['matched']:>8} {p50:>8.3f} {p99:>8.3f} {mx:>8.2f} "
              f"{r['cycles'] or '-':>7} {per:>13} {pct:>6} {ratio50:>6} {ratio99:>6}")
    print("CPU: user+system time of the process during the measured window / cycles (messages for the"
          " baseline) in it; CPU % of one core. Ratios: to the baseline's p50 / p99 in this run.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
