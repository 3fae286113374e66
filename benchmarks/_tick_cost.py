"""One ``Bridge.tick``'s cost with interpreted or compiled kernels: ``python _tick_cost.py interpreted|compiled``.

Both wings with flex sensors (``loop:`` backend reading the setpoint + 0.3 deg + noise), ff+pi, the
pre-tension estimator on, the FC's aileron a 0.5 Hz sine with +-1 us jitter; 3000 cycles on a
simulated 100 Hz clock after 100 not counted. Prints median, mean and p99 in ms. Run by
``bench_startup.py``; the mode must be chosen before the kernels are imported, hence a process each.
"""

from __future__ import annotations

import math
import random
import sys
import tempfile
import time
from pathlib import Path

from warpbridge.model import _jit

if sys.argv[1:] == ["interpreted"]:
    _jit.interpret()

from warpbridge.bridge.app import Bridge  # noqa: E402
from warpbridge.bridge.config import load_config  # noqa: E402
from warpbridge.hw.loop import LoopBackend  # noqa: E402
from warpbridge.sitl.field_tuning import SimLink  # noqa: E402

WING = """
[wing.{name}]
source_channel = 1
reverse = {rev}
servo_channel = {servo}
sensor_channel = {sensor}
bias_deg = 2
[wing.{name}.sensor]
counts = [0, 1000]
deg = [0, 20]
"""


def main() -> None:
    folder = Path(tempfile.mkdtemp(prefix="wb-tick-"))
    (folder / "wb.toml").write_text(
        '[link]\nconnection = "udpin:127.0.0.1:1"\n[params]\nfile = "p.json"\n[servo]\nbackend = "loop:"\n'
        '[sensor]\nbackend = "loop:"\n' + WING.format(name="left", rev="false", servo=0, sensor=5)
        + WING.format(name="right", rev="true", servo=1, sensor=6))
    t = [0.0]
    rnd = random.Random(1)
    box: dict = {}

    def counts(ch: int) -> float:
        sp = box["bridge"].wings["left" if ch == 5 else "right"].setpoint
        return max(0.0, min(1000.0, (sp + 0.3) * 50.0 + rnd.gauss(0.0, 1.0)))

    loop = LoopBackend(counts=counts, clock=lambda: t[0])
    link = SimLink()
    box["bridge"] = bridge = Bridge(load_config(folder / "wb.toml"), servo=loop, sensor=loop, link=link,
                                    clock=lambda: t[0])
    costs = []
    for i in range(3100):
        t[0] += 0.01
        link.servo_pwm = {1: 1500 + 300 * math.sin(2 * math.pi * 0.5 * t[0]) + rnd.choice((-1, 0, 1))}
        link.servo_time = t[0]
        a = time.perf_counter()
        bridge.tick()
        if i >= 100:
            costs.append(time.perf_counter() - a)
    bridge.close()
    costs.sort()
    print(1e3 * costs[len(costs) // 2], 1e3 * sum(costs) / len(costs), 1e3 * costs[int(0.99 * len(costs))])


if __name__ == "__main__":
    main()
