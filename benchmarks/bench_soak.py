"""Soak: the bridge run lock-step for the equivalent of hours of flight, FC stream at 400 Hz.

The bridge (``bridge.app.Bridge``, in-process, simulated clock) reads an FC on real loopback UDP
sending SERVO_OUTPUT_RAW at 400 Hz (4 messages per 10 ms control cycle), VFR_HUD at 10 Hz and a
heartbeat at 1 Hz, drives the ``loop:`` servo backend with a jittering flex sensor, sends its
telemetry and writes its cycle log; a ground station reads one parameter a minute and sets one every
ten. Prints, per window of simulated time: resident memory, median and 99th-percentile tick time,
log rows. Checks at the end: memory growth after warm-up under ``--max-growth-mb`` (default 5), the
last window's median tick time within 1.5x of the first one after warm-up, and the cycle log complete
(one row per cycle, time strictly increasing). Exit status 1 if a check fails.

    python benchmarks/bench_soak.py                 # 2 h of flight (720 000 cycles)
    python benchmarks/bench_soak.py --hours 0.1     # a quick look
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import random
import select
import socket
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from warpbridge.bridge.app import Bridge  # noqa: E402
from warpbridge.bridge.config import load_config  # noqa: E402
from warpbridge.bridge.mavlink_env import mavlink  # noqa: E402
from warpbridge.hw.loop import LoopBackend  # noqa: E402

RATE_HZ = 100
SERVO_HZ = 400
WARMUP_S = 300.0

CONFIG = """
[link]
connection = "udpin:127.0.0.1:{port}"
source_system = 1
servo_rate_hz = 400
[loop]
rate_hz = 100
log = "soak-cycles.csv"
[params]
file = "params.json"
[servo]
backend = "loop:"
[sensor]
backend = "loop:"
[wing.left]
source_channel = 1
servo_channel = 0
sensor_channel = 4
[wing.right]
source_channel = 1
reverse = true
servo_channel = 1
sensor_channel = 5
"""


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=2.0, help="flight time to simulate (default 2)")
    ap.add_argument("--window-s", type=float, default=600.0, help="simulated seconds per table row")
    ap.add_argument("--max-growth-mb", type=float, default=5.0)
    args = ap.parse_args(argv)

    folder = Path(tempfile.mkdtemp(prefix="wb-soak-"))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    (folder / "wb.toml").write_text(CONFIG.format(port=port))
    clock = Clock()
    rng = random.Random(1)
    bridge_ref: list[Bridge] = []

    def counts(channel: int) -> float:  # the wing follows its setpoint, the sensor jitters a count
        wing = bridge_ref[0].wings["left" if channel == 4 else "right"]
        return 1023 * (wing.setpoint + 0.2) / 30 + rng.choice((-1, 0, 1))

    hw = LoopBackend(counts=counts, clock=clock)
    bridge = Bridge(load_config(folder / "wb.toml"), servo=hw, sensor=hw, clock=clock)
    bridge_ref.append(bridge)
    bridge.link.open()
    fd = bridge.link.mav.port.fileno()
    fc = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    fc.connect(("127.0.0.1", port))
    fc.setblocking(False)
    enc = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)

    cycles_total = int(args.hours * 3600 * RATE_HZ)
    per_window = int(args.window_s * RATE_HZ)
    per_tick = SERVO_HZ // RATE_HZ
    print(f"soak: {args.hours:g} h of flight = {cycles_total} cycles at {RATE_HZ} Hz, "
          f"{cycles_total * per_tick} servo messages at {SERVO_HZ} Hz; files in {folder}")
    print(f"{'sim time':>9} {'wall s':>7} {'RSS MB':>7} {'tick med us':>11} {'tick p99 us':>11} "
          f"{'log rows':>9} {'servo msgs':>10}")
    rows = []
    tick_times: list[float] = []
    wall0 = time.perf_counter()
    msg_i = 0
    for k in range(cycles_total):
        t = k / RATE_HZ
        for j in range(per_tick):
            msg_i += 1
            pwm = 1500 + int(350 * math.sin(2 * math.pi * 0.3 * (t + j / SERVO_HZ)))
            fc.send(mavlink.MAVLink_servo_output_raw_message(msg_i & 0xFFFFFFFF, 0, pwm, 1500, 1100, 1500,
                                                             0, 0, 0, 0).pack(enc))
        if k % 10 == 0:
            fc.send(mavlink.MAVLink_vfr_hud_message(14.0 + math.sin(t / 30), 15.0, 90, 50, 100, 0).pack(enc))
        if k % 100 == 0:
            fc.send(mavlink.MAVLink_heartbeat_message(1, 3, 128, 0, 4, 3).pack(enc))
        if k % 6000 == 3000:
            fc.send(mavlink.MAVLink_param_request_read_message(1, 191, b"WB_KP", -1).pack(gcs))
        if k % 60000 == 30000:
            fc.send(mavlink.MAVLink_param_set_message(1, 191, b"WB_KI", 1.0 + (k // 60000) % 2 * 0.5,
                                                      mavlink.MAV_PARAM_TYPE_REAL32).pack(gcs))
        select.select([fd], [], [], 0.01)
        clock.t = t
        t0 = time.perf_counter()
        bridge.tick()
        tick_times.append(time.perf_counter() - t0)
        while True:  # the FC drains what the bridge sends (telemetry)
            try:
                fc.recv(65536)
            except (BlockingIOError, ConnectionRefusedError):
                break
        if len(hw.history) > 10000:
            del hw.history[:]  # the test backend's own record, not the bridge's memory
        if (k + 1) % per_window == 0 or k + 1 == cycles_total:
            log_rows = bridge.log.rows_written + bridge.log.pending if bridge.log else 0
            tick_times.sort()
            row = (clock.t + 1 / RATE_HZ, time.perf_counter() - wall0, rss_mb(),
                   1e6 * statistics.median(tick_times), 1e6 * tick_times[int(0.99 * (len(tick_times) - 1))],
                   log_rows, bridge.link.counters.servo_messages)
            rows.append(row)
            tick_times = []
            print(f"{row[0] / 60:8.1f}m {row[1]:7.1f} {row[2]:7.1f} {row[3]:11.0f} {row[4]:11.0f} "
                  f"{row[5]:9d} {row[6]:10d}", flush=True)
    cycles = bridge.cycles
    servo_msgs = bridge.link.counters.servo_messages
    sent_servo = cycles_total * per_tick
    bridge.close()
    fc.close()

    log_path = bridge.log.path
    n_rows, last_t, monotone = 0, -math.inf, True
    with open(log_path, newline="") as f:
        for r in csv.DictReader(f):
            n_rows += 1
            t = float(r["t"])
            monotone &= t > last_t
            last_t = t
    after = [r for r in rows if r[0] > WARMUP_S] or rows
    growth = rows[-1][2] - after[0][2]
    slow = rows[-1][3] / after[0][3]
    checks = {
        f"memory growth after warm-up {growth:+.1f} MB (<= {args.max_growth_mb:g})": growth <= args.max_growth_mb,
        f"tick time, last/first window after warm-up {slow:.2f} (<= 1.5)": slow <= 1.5,
        f"log rows {n_rows} == cycles {cycles}, time increasing": n_rows == cycles and monotone,
        f"servo messages read {servo_msgs} of {sent_servo} sent": servo_msgs >= 0.99 * sent_servo,
    }
    print(f"\nmemory: {rows[0][2]:.1f} MB after the first window, {after[0][2]:.1f} MB after warm-up, "
          f"{rows[-1][2]:.1f} MB at the end; wall time {rows[-1][1]:.0f} s for {cycles / RATE_HZ / 3600:.2f} h")
    for text, ok in checks.items():
        print(f"{'ok  ' if ok else 'FAIL'} {text}")
    log_path.unlink(missing_ok=True)
    return 0 if all(checks.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
