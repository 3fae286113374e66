"""Small helpers shared by the tests: free loopback ports, a hand-advanced clock, an independent two-stage filter."""

from __future__ import annotations

import subprocess
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from warpbridge.sitl.cmd_sitl import free_udp_port  # noqa: F401  (the tests' loopback ports: one picker)

# the loop-back servo and two wings on aileron output 1, the right one reversed: the tail of a test config
LOOP_SERVO_WINGS = """[servo]
backend = "loop:"
[wing.left]
source_channel = 1
servo_channel = 0
[wing.right]
source_channel = 1
reverse = true
servo_channel = 1
"""


def wait_for(cond: Callable[[], Any], timeout: float, step: float = 0.05) -> Any:
    """Poll ``cond`` until it is truthy or ``timeout`` (s) has passed; its last value."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        got = cond()
        if got:
            return got
        time.sleep(step)
    return cond()


def stop_process(proc: subprocess.Popen, grace_s: float = 10.0) -> int:
    """SIGTERM, then SIGKILL after ``grace_s``; the exit status."""
    if proc.poll() is not None:
        return proc.returncode
    proc.terminate()
    try:
        return proc.wait(grace_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait(5)


def stop_flight(bridge, err, emu, gcs, autopilot) -> None:
    """Tear a real-autopilot flight down, whatever of it got started: the bridge process, its stderr file, the
    servo emulator, the ground station, then the autopilot."""
    if bridge is not None:
        stop_process(bridge)
    if err is not None:
        err.close()
    if emu is not None:
        emu.stop()
    if gcs is not None:
        gcs.close()
    autopilot.stop()


def sitl_bridge_toml(connection: str, servo_backend: str, wings: str) -> str:
    """A bridge config for the real-autopilot tests: 50 Hz servo outputs asked, a 100 Hz loop, 10 Hz
    telemetry, no sensor, then the wings' tables (``sitl_wing_toml``)."""
    return f"""
[link]
connection = "{connection}"
servo_rate_hz = 50
[loop]
rate_hz = 100
[telemetry]
rate_hz = 10
[params]
file = "params.json"
[servo]
backend = "{servo_backend}"
[sensor]
backend = "none"
""" + wings


def sitl_wing_toml(name: str, source: int, reverse: bool, servo_channel: int, mode: str,
                   pwm: tuple[int, int, int] = (1100, 1500, 1900), pulse_zero_us: float = 1200.0,
                   mm_per_us: float = 0.02) -> str:
    """A wing's tables of a bridge config for the real-autopilot tests: no sensor, 0..8 deg with a 2 deg bias."""
    return f"""
[wing.{name}]
source_channel = {source}
reverse = {"true" if reverse else "false"}
pwm_min = {pwm[0]}
pwm_trim = {pwm[1]}
pwm_max = {pwm[2]}
max_warp_deg = 8.0
bias_deg = 2.0
servo_channel = {servo_channel}
[wing.{name}.servo]
pulse_min_us = 1000
pulse_max_us = 2000
pulse_zero_us = {pulse_zero_us:g}
mm_per_us = {mm_per_us:g}
[wing.{name}.control]
mode = "{mode}"
"""


class GroundStation:
    """A ground station on a pymavlink connection to a real autopilot's SITL, on its own thread: each turn it
    calls ``periodic(now)`` (what it sends) and ``take(m)`` for each message; what component 191 (the bridge)
    says, named values and texts (MAVLink 2 STATUSTEXT chunks joined), is kept. Subclasses set their own
    fields, then call ``start()``."""

    def __init__(self, mav: Any) -> None:
        self.mav = mav
        self.lock = threading.Lock()
        self.floats: list[tuple[float, str, float]] = []
        self.texts: list[tuple[float, str]] = []
        self._last_chunk = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def periodic(self, now: float) -> None:
        """Sends due at ``now`` (monotonic s)."""

    def take(self, m: Any) -> None:
        """One received message."""

    def _run(self) -> None:
        while not self._stop.is_set():
            self.periodic(time.monotonic())
            try:
                self.mav.select(0.02)
                while (m := self.mav.recv_msg()) is not None:
                    self.take(m)
                    if m.get_srcComponent() == 191:
                        self._keep(m)
            except Exception:  # noqa: BLE001 - the autopilot went away at the end
                if self._stop.is_set():
                    return
                time.sleep(0.05)

    def _keep(self, m: Any) -> None:
        t = m.get_type()
        with self.lock:
            if t == "NAMED_VALUE_FLOAT":
                self.floats.append((time.monotonic(), m.name, m.value))
            elif t == "STATUSTEXT":  # MAVLink 2 chunks of a long text share an id: joined here
                chunk_id = getattr(m, "id", 0)
                if chunk_id and self.texts and self._last_chunk == chunk_id:
                    self.texts[-1] = (self.texts[-1][0], self.texts[-1][1] + m.text)
                else:
                    self.texts.append((time.monotonic(), m.text))
                self._last_chunk = chunk_id

    def latest(self, name: str, since: float = 0.0) -> float | None:
        with self.lock:
            vals = [v for t, n, v in self.floats if n == name and t >= since]
        return vals[-1] if vals else None

    def text(self, fragment: str, since: float = 0.0) -> str | None:
        with self.lock:
            return next((x for t, x in self.texts if fragment in x and t >= since), None)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.mav.close()


class ManualClock:
    """A clock the test advances by assigning ``t`` (seconds)."""

    def __init__(self, t: float = 0.0) -> None:
        self.t = float(t)

    def __call__(self) -> float:
        return self.t


def drain_mavlink(sock, parser) -> list:
    """Every MAVLink message waiting on a non-blocking UDP socket, parsed (BAD_DATA dropped)."""
    out: list = []
    while True:
        try:
            data = sock.recv(65536)
        except (BlockingIOError, ConnectionRefusedError):
            return out
        out.extend(m for m in (parser.parse_buffer(data) or []) if m.get_type() != "BAD_DATA")


def cpu_seconds(pid: int) -> float | None:
    """CPU time (user + system, s) process ``pid`` has used so far (Linux /proc); None if unknown."""
    import os
    from pathlib import Path

    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def wait_while_working(cond, pid: int, cpu_s: float = 20.0, idle_s: float = 20.0, step: float = 0.02):
    """Wait until ``cond()`` holds while process ``pid`` works towards it; return ``cond()``.

    For what a process does once it has started (imports, compiling): a busy machine makes that take
    several times longer in wall time but not in CPU time. So give up only once ``pid`` has exited,
    has used ``cpu_s`` s of CPU since the wait began, or none for ``idle_s`` s (blocked: hung).
    Without /proc, after ``cpu_s`` s of wall time."""
    import time

    t0 = last_change = time.monotonic()
    cpu0 = last = cpu_seconds(pid)
    while True:
        v = cond()
        if v:
            return v
        now, cpu = time.monotonic(), cpu_seconds(pid)
        if cpu is None or cpu0 is None:
            if cpu is None and cpu0 is not None:  # exited
                return cond()
            if now - t0 > cpu_s:
                return cond()
        else:
            if cpu != last:
                last, last_change = cpu, now
            if cpu - cpu0 > cpu_s or now - last_change > idle_s:
                return cond()
        time.sleep(step)


def run_to_end(cmd: list[str], **kwargs):
    """``subprocess.run(cmd, capture_output=True, text=True, **kwargs)`` without a wall-clock timeout:
    the process may take as long as it keeps working (``wait_while_working``; a busy machine slows
    its start-up), and is killed once it stalls. Returns the ``CompletedProcess``."""
    import subprocess
    import tempfile

    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, text=True, **kwargs)
        if not wait_while_working(lambda: proc.poll() is not None, proc.pid, cpu_s=60.0):
            proc.kill()
            proc.wait()
            raise AssertionError(f"{cmd} stalled or kept running; killed")
        out.seek(0)
        err.seek(0)
        return subprocess.CompletedProcess(cmd, proc.returncode, out.read(), err.read())


def two_stage_lag(t: np.ndarray, w: np.ndarray, tau1: float, tau2: float, substeps: int = 20) -> np.ndarray:
    """Two first-order stages (a servo's position loop, then a sensor), Euler-integrated finely in plain Python:
    bench dynamics written independently of the model's own lag operator."""
    y1 = y2 = float(w[0])
    out = np.empty_like(w)
    for k in range(w.size):
        h = (t[k] - t[k - 1]) / substeps if k else 0.0
        for _ in range(substeps if k else 0):
            y1 += h * (w[k] - y1) / tau1
            y2 += h * (y1 - y2) / tau2
        out[k] = y2
    return out


def play_written_out(x: np.ndarray, r: float) -> np.ndarray:
    """A play (backlash) operator of half-width r written out in plain Python, independent of the model's kernel."""
    out, p = np.empty_like(x), float(x[0])
    for k, v in enumerate(x):
        p = min(max(p, v - r), v + r)
        out[k] = p
    return out


SHEATH_PLAYS = ((0.25, 0.05), (0.12, 0.12), (0.06, 0.25))  # (weight deg/mm, half-width as a share of the span)


def spread_friction(x: np.ndarray, span: float, friction: float = 1.0) -> np.ndarray:
    """Warp (deg) of friction spread along a sheath, which one Bouc-Wen state cannot hold: a Prandtl-Ishlinskii
    stack of plays on the tendon travel. Each stretch of sheath slips at a force in proportion to its friction, so
    a ``friction`` change scales every play's width (and with it what each can hold)."""
    return sum(c * (x - play_written_out(x, friction * f * span)) for c, f in SHEATH_PLAYS)


def feedforward_rms(params, wing_effects, model_effects, seed: int = 2, skip: int = 200) -> float:
    """RMS (deg) of setpoint minus true warp when a feed-forward built on ``model_effects`` drives a wing with
    ``wing_effects`` (both on Bouc-Wen ``params``) along a 12 s random warp setpoint at 100 Hz, after ``skip``
    samples."""
    from warpbridge.model.compensation import Compensator
    from warpbridge.model.excitation import filtered_random
    from warpbridge.model.plant import Plant, PlantStepper

    t = np.arange(0, 12, 0.01)
    w_sp = filtered_random(t, 1.0, 3.0, offset=7.0, seed=seed)
    comp = Compensator(Plant(params, model_effects), w0=w_sp[0])
    wing = PlantStepper(Plant(params, wing_effects), t[0], comp.step(w_sp[0]))
    err = [wing.step(t[k], comp.step(w_sp[k]))[0] - w_sp[k] for k in range(1, t.size)]
    return float(np.sqrt(np.mean(np.square(err[skip:]))))
