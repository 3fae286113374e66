"""``warpbridge sitl``: the whole system simulated, over real UDP and a real pty.

Three parts run at once: the mock autopilot (a subprocess streaming the
scenario's aileron PWM over MAVLink UDP to the bridge, with a ground-station
port), the virtual servo board (a Pololu Maestro emulator on a pty, in this
process, whose servo channels drive the two simulated wings and whose analog
inputs return their flex sensors), and the bridge itself (a subprocess,
``warpbridge run --config <generated toml>``). The bridge starts first (in
failsafe, wings neutral); then the mock, whose roll clock starts with it: a
1 s neutral hold, then the scenario for ``--duration`` s, so the bridge starts
following the FC without a step. Then the children are stopped and each
cycle-log row is joined to the sensor read the bridge made in that cycle (by
time and by the counts it logged), giving the wing's true warp then; the log
is put on the scenario's clock by matching its setpoints to the reference.
The same stretch of the scenario is flown in lock-step (``sitl.lockstep``:
the bridge's own cycle on a simulated clock) at the real-time run's cycle
times, sensor-read and servo-write instants, and once more at the nominal
schedule ("ideal timing"); RMS of setpoint - true warp over the same cycles
is compared, and the table and a plot are written. Everything (config, roll file, logs, PNG, summary) stays in
``--out``. ``--lockstep`` instead prints the lock-step comparison table of all
controller modes, calm and in gusts (seconds, no sockets).

Examples::

    warpbridge sitl                                   # 20 s of the paper's random reference
    warpbridge sitl --scenario gust12 --duration 30
    warpbridge sitl --effects 'delay=0.03,backlash=0.2' --model MODEL.json
    warpbridge sitl --lockstep
"""

from __future__ import annotations

import argparse
import csv
import difflib
import json
import logging
import math
import os
import random
import signal
import socket
import subprocess
import sys
import time
import tomllib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np

from warpbridge.bridge.commands.effects_spec import parse_effects
from warpbridge.bridge.config import parse_config
from warpbridge.bridge.controller import MODES
from warpbridge.bridge.errors import UserError
from warpbridge.model.boucwen import BoucWenParams
from warpbridge.model.effect_registry import EFFECT_FIELDS
from warpbridge.model.effects import Effects
from warpbridge.model.modelfile import ModelFile
from warpbridge.model.plant import Plant
from warpbridge.sitl.lockstep import (
    MERGE_S,
    SETTLE_S,
    RunResult,
    Schedule,
    WingBoard,
    compare,
    make_wings,
    rig_config,
    run_lockstep,
)
from warpbridge.sitl.maestro_emu import MaestroEmulator
from warpbridge.sitl.mock_autopilot import gcs_output_string
from warpbridge.sitl.report import comparison_table, plot_run, run_table
from warpbridge.sitl.scenarios import GAIN_SETS, SCENARIO_NAMES, WINGS, Rig, Scenario, make_scenario
from warpbridge.sitl.wing import SITL_AERO_LOAD, SimWing, WingSpec

log = logging.getLogger(__name__)

HOLD_S = 1.0  # neutral roll before the scenario: the bridge starts following the FC without a step
STARTUP_MARGIN_S = 10.0  # roll file beyond the run
STARTUP_TIMEOUT_S = 30.0  # CPU seconds (or seconds without any) for each child to come up
MOCK_START_MAX_S = 10.0  # longest the mock autopilot's process may take from launch to its roll clock's start
END_MARGIN_S = 0.2  # rig time flown beyond the scenario's stretch
AGREE_TOLERANCE = 0.20
EMULATED_BOARD_TIMEOUT_S = 0.5  # the bridge's read timeout on the Maestro emulator (a real board's: 0.02)
COARSE_MATCH_S = 30.0  # log stretch the coarse search of the scenario offset looks at


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenario", choices=SCENARIO_NAMES, default=None,
                        help="what the FC commands (default: random; --lockstep: random, gust7, gust12)")
    parser.add_argument("--duration", type=float, default=20.0, metavar="S",
                        help="seconds of control to run (default 20; Ctrl-C stops a real-time run early and "
                             "compares the part flown)")
    parser.add_argument("--out", type=Path, default=None,
                        help="output directory (default ./sitl-run-<time>)")
    parser.add_argument("--lockstep", action="store_true",
                        help="print the lock-step comparison of all controller modes instead (fast)")
    parser.add_argument("--effects", default="",
                        help="unmodelled effects of the simulated wing, e.g. 'delay=0.03,backlash=0.2' "
                             f"(names: {', '.join(EFFECT_FIELDS)}; effects with several parameters take a:b[:c...]; "
                             "or one parameter by its name, e.g. aero_deg_per_kpa=2)")
    parser.add_argument("--model", type=Path, default=None,
                        help="MODEL.json the simulated wing follows (params and effects; default: the paper's)")
    parser.add_argument("--plant", choices=("bouc-wen", "sheath"), default="bouc-wen",
                        help="the simulated wing: bouc-wen (the paper's model, or --model's; the bridge's own model "
                             "class) or sheath (a tendon in a sheath from the mechanics, re-rigged after its bench "
                             "identification; not the model's class)")
    parser.add_argument("--bridge-model", default=None,
                        help="model the bridge's feed-forward uses: 'paper', a MODEL.json, or 'identify' (record a "
                             "bench log of the un-rigged sheath wing and identify it first, as a user would). "
                             "Default: paper with --plant bouc-wen, identify with --plant sheath")
    parser.add_argument("--autopilot", choices=("ardupilot", "px4"), default="ardupilot",
                        help="the flight controller the mock imitates: its messages, streams and parameter "
                             "encoding (default ardupilot)")
    parser.add_argument("--mode", choices=MODES, default="ff+pi", help="bridge controller mode (real-time run)")
    parser.add_argument("--gains", choices=GAIN_SETS, default="default",
                        help="PI gain set: default (the bridge's, kp {:g} mm/deg, ki {:g} mm/(deg s)), paper-horn "
                             "(the paper's Kp = 7, Ki = 1 as degrees of servo horn per degree on the rig's 10 mm horn: "
                             "1.22, 0.175), paper-mm (7 and 1 taken as mm/deg)".format(*Rig().gains("default")))
    parser.add_argument("--kp", type=float, default=None, help="PI gain, mm of tendon per deg (overrides --gains)")
    parser.add_argument("--ki", type=float, default=None,
                        help="PI gain, mm of tendon per deg*s (overrides --gains)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the reference, gusts and noise")
    parser.add_argument("--no-plot", action="store_true", help="skip the PNG")
    parser.add_argument("--gcs", action="append", default=None, metavar="OUTPUT",
                        help=f"ground-station output of the simulated autopilot, repeatable (default {GCS_DEFAULT}, "
                             "where QGroundControl, Mission Planner and MAVProxy listen): udp:HOST:PORT sends there "
                             "and replies to whoever answers, udpin:HOST:PORT listens; the bridge is component 191")
    parser.add_argument("--no-gcs", action="store_true", help="no ground-station output")


# ------------------------------------------------------------------ options


def chosen_gains(args: argparse.Namespace) -> tuple[float, float]:
    """(kp, ki) in mm/deg and mm/(deg s): the named set, with --kp / --ki over it."""
    kp, ki = Rig().gains(args.gains)
    return (kp if args.kp is None else args.kp), (ki if args.ki is None else args.ki)


GCS_DEFAULT = "udp:127.0.0.1:14550"  # where ArduPilot's and PX4's SITL send: ground stations listen there


def gcs_outputs(args: argparse.Namespace) -> list[str]:
    """The ground-station outputs asked for (``--gcs``, default 14550; none with ``--no-gcs``), checked."""
    if args.no_gcs:
        if args.gcs:
            raise UserError("--gcs and --no-gcs contradict each other")
        return []
    out = []
    for spec in args.gcs or [GCS_DEFAULT]:
        try:
            full = gcs_output_string(spec)
        except ValueError as e:
            raise UserError(f"--gcs {e}") from None
        kind, _, address = full.partition(":")
        if kind == "udpin":  # a port we listen on must be free now, not fail inside the child later
            host, _, port = address.rpartition(":")
            try:
                with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
                    probe.bind((host, int(port)))
            except OSError as e:
                raise UserError(f"--gcs {full}: cannot listen there: {e.strerror or e}") from None
        out.append(full)
    return out


def _read_model(path: Path, what: str) -> ModelFile:
    try:
        return ModelFile.from_dict(json.loads(path.read_text(encoding="utf-8")))
    except OSError as e:
        raise UserError(f"{what}: cannot read {path}: {e.strerror or e}") from None
    except ValueError as e:
        raise UserError(f"{what}: {path}: {e}") from None


def wing_spec(model: Path | None, effects: Effects, plant: str = "bouc-wen") -> WingSpec:
    """The simulated wing: the paper's (or MODEL.json's) plant, SITL aero load, plus ``effects``; or the
    re-rigged sheath wing."""
    if plant == "sheath":
        if model is not None:
            raise UserError("--model sets the Bouc-Wen wing's parameters; it does not apply to --plant sheath")
        from warpbridge.sitl.like_for_like import bench_params, rigged, sheath_spec

        try:
            return sheath_spec(rigged(bench_params())).with_effects(effects)
        except ValueError as e:
            raise UserError(f"--effects: {e}") from None
    if model is None:
        plant = Plant(BoucWenParams.paper(), SITL_AERO_LOAD)
    else:
        mf = _read_model(model, "--model")
        plant = Plant(mf.params, SITL_AERO_LOAD.merged(mf.effects))
    return WingSpec(plant=plant).with_effects(effects)


def _effects_dict(spec: WingSpec) -> dict:
    return spec.plant.effects.to_dict() if isinstance(spec.plant, Plant) else {}


def resolve_bridge_model(args: argparse.Namespace, out: Path) -> str:
    """'paper' or a MODEL.json path; with 'identify', the bench sheath's log identified into ``out``."""
    choice = args.bridge_model or ("identify" if args.plant == "sheath" else "paper")
    if choice != "identify":
        return choice
    if args.plant != "sheath":
        raise UserError("--bridge-model identify needs --plant sheath")
    from warpbridge.sitl.like_for_like import bench_params, identify_bench

    print(f"sitl: recording a bench log of the sheath wing and identifying it into {out} ...", flush=True)
    return str(identify_bench(bench_params(), out, seed=args.seed).resolve())


# ------------------------------------------------------------------ the real-time run


_HANDED_OUT: set[int] = set()


def _ephemeral_low() -> int:
    """The first port of the kernel's ephemeral range (32768 where it cannot be read)."""
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range", encoding="ascii") as f:
            return int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that nothing is bound to now, never the same one twice in a process.

    Drawn below the kernel's ephemeral range: a port from that range (what binding port 0 gives) can be
    handed by the kernel to any socket that sends before binding, between this check and the moment the
    program meant to listen on it binds it, and that program then cannot listen."""
    low = _ephemeral_low()
    rng = random.SystemRandom()
    for _ in range(500):
        port = rng.randrange(max(1024, low - 12000), low) if low > 2048 else 0
        if port in _HANDED_OUT:
            continue
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            port = int(s.getsockname()[1])
        if port not in _HANDED_OUT:
            _HANDED_OUT.add(port)
            return port
    raise OSError("no free UDP port on 127.0.0.1")


class VirtualRig(WingBoard):
    """The two simulated wings behind the Maestro emulator, on the wall clock (rig time, s).

    ``on_target``/``read_analog`` are the emulator's callbacks; like ``WingBoard`` each advances the
    wings to now first and each sensor read is recorded with the wing's true warp at that instant.
    ``tick`` keeps them current in between, to the last sub-step grid point (``SimWing``
    ``grid_origin``), so the lock-step replay, which advances its wings only at those instants,
    integrates them on the same sub-steps."""

    def __init__(self, rig: Rig, wings: dict[str, SimWing], clock=time.monotonic) -> None:
        self.t0 = clock()
        super().__init__(rig, wings, lambda: clock() - self.t0)

    def now(self) -> float:
        return self.clock()

    def on_target(self, channel: int, quarter_us: int) -> None:
        self.set_target(channel, quarter_us / 4.0)

    def read_analog(self, channel: int) -> int | None:
        counts = self.read_counts(channel)
        return None if counts is None else int(counts)  # None: a servo channel, the emulator answers its target

    def tick(self) -> None:
        """Keep the wings' time current between the bridge's calls (whose own work stays small)."""
        for w in self.wings.values():
            h, o = w.spec.substep_s, w.grid_origin or 0.0
            w.advance(o + h * math.floor((self.clock() - o) / h))



def _tail(path: Path, n: int = 15) -> str:
    try:
        return "\n".join(path.read_text(encoding="utf-8", errors="replace").splitlines()[-n:])
    except OSError:
        return "(no log)"


def _stop_child(proc: subprocess.Popen | None, name: str, sig: int = signal.SIGTERM) -> None:
    if proc is None or proc.poll() is not None:
        return
    try:
        proc.send_signal(sig)
        proc.wait(timeout=5.0)
    except subprocess.TimeoutExpired:
        log.warning("%s did not stop; killing it", name)
        proc.kill()
        proc.wait(timeout=5.0)
    except ProcessLookupError:
        pass


def read_cycle_log(path: Path) -> dict[str, np.ndarray]:
    """The bridge's cycle log as columns (``mode`` as a string array)."""
    with path.open(newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise UserError(f"the bridge wrote no cycles to {path}")
    out: dict[str, np.ndarray] = {"mode": np.array([r["mode"] for r in rows])}
    for k in rows[0]:
        if k != "mode":
            out[k] = np.array([float(r[k]) for r in rows])
    return out


def join_reads(log_t: np.ndarray, logged_deg: np.ndarray, reads: list, deg_of_counts,
               ) -> tuple[np.ndarray, float]:
    """Match each cycle-log row to the sensor read the bridge made in that cycle.

    ``reads``: the rig's records (rig time, counts, ...) in order. The bridge reads each sensor at
    most once per cycle and the board answers in order, so rows and reads are aligned in order on
    the warp each gives (the logged warp; the read's counts through the calibration, as the log
    writes it), as a diff aligns two texts: a row without a warp (no answer in time) or with a
    wrong one (a late answer to an earlier query) matches nothing, and a read nobody took (the
    answer came too late) is skipped. However late the board answered on a busy machine, times play
    no part. Returns the index of the read per row (-1: none) and the rig time of log time 0, the
    smallest read-minus-cycle delay over the first matched rows."""
    n = len(log_t)
    idx = np.full(n, -1, dtype=np.int64)
    if not reads or n == 0:
        return idx, math.nan
    rec = np.asarray(reads, dtype=np.float64)
    rt, deg = rec[:, 0], np.asarray(deg_of_counts(rec[:, 1]), dtype=np.float64)
    rows = [f"{v:.6g}" if math.isfinite(v) else object() for v in np.asarray(logged_deg, dtype=np.float64)]
    seen = [f"{v:.6g}" for v in deg]
    for a, b, size in difflib.SequenceMatcher(None, rows, seen, autojunk=False).get_matching_blocks():
        idx[a:a + size] = np.arange(b, b + size)
    ok = np.flatnonzero(idx >= 0)[:50]
    offset = float(np.min(rt[idx[ok]] - log_t[ok])) if ok.size else math.nan
    return idx, offset


def realtime_result(scenario: Scenario, mode: str, cyc: dict[str, np.ndarray], vrig: VirtualRig,
                    ) -> tuple[RunResult, float, dict[str, np.ndarray]]:
    """The bridge's cycle log joined with the wings' true warp at each of its sensor reads.

    Times stay the log's (seconds since the bridge started); also returns the rig time of log time 0
    and per wing the read whose answer each row got (-1: none, or a late answer to another query):
    placed by the servo targets (``row_reads``) when there is one per row, else ``join_reads``."""
    t = cyc["t"]
    sensor = scenario.rig.sensor
    cols: dict[str, dict[str, np.ndarray]] = {"warp": {}, "u": {}, "airspeed": {}}
    offset = math.nan
    read_idx = {}
    for w in WINGS:
        idx, off = join_reads(t, cyc[f"{w}_warp"], vrig.reads[w], sensor.deg_of_counts)
        rec = np.asarray(vrig.reads[w], dtype=np.float64).reshape(-1, 5)
        targets = np.asarray(vrig.target_log[w], dtype=np.float64).reshape(-1, 2)[:, 0]
        if 0 < targets.size <= t.size:  # placed by the targets: an answer is the row's own only if it matches
            own = row_reads(idx, rec[:, 0], targets)
            got = np.asarray(sensor.deg_of_counts(rec[np.maximum(own, 0), 1]), dtype=np.float64)
            logged = cyc[f"{w}_warp"]
            idx = np.where((own >= 0) & (np.abs(got - logged) <= 1e-4 * np.maximum(1.0, np.abs(logged))), own, -1)
        read_idx[w] = idx
        if w == "left":
            offset = off
        ok = idx >= 0
        for name, c in (("warp", 2), ("u", 3), ("airspeed", 4)):
            col = np.full(t.size, np.nan)
            col[ok] = rec[idx[ok], c]
            cols[name][w] = col
        missed = 1.0 - np.count_nonzero(ok) / max(1, np.count_nonzero(np.isfinite(cyc[f"{w}_warp"])))
        if missed > 0.02:
            log.warning("%s wing: %.0f %% of cycle-log rows match no sensor read; they are left out",
                        w, 100 * missed)
    flying = cyc["mode"] != "failsafe"
    if not flying.any():
        raise UserError("the bridge never left failsafe: it heard no servo outputs from the mock autopilot")
    res = RunResult(
        scenario=scenario.name, mode=mode, t=t, airspeed=cols["airspeed"]["left"],
        setpoint={w: cyc[f"{w}_setpoint"] for w in WINGS}, warp=cols["warp"],
        measured={w: cyc[f"{w}_warp"] for w in WINGS}, u_cmd={w: cyc[f"{w}_u"] for w in WINGS},
        u=cols["u"], flying=flying,
    )
    return res, offset, read_idx


def scenario_offset(scenario: Scenario, t: np.ndarray, setpoint: np.ndarray, lo: float, hi: float) -> float:
    """Scenario time at log time 0, in [lo, hi]: the shift that best matches the logged setpoint
    (flying cycles only) to the scenario's reference."""
    ok = np.isfinite(setpoint)
    t, sp = t[ok], setpoint[ok]
    coarse = t <= t[0] + COARSE_MATCH_S if t.size else ok  # the shift is one number: a stretch finds it
    best = lo
    for step, span, keep in ((0.005, None, coarse), (0.0002, 0.006, slice(None))):
        a, b = (lo, hi) if span is None else (best - span, best + span)
        tt, ss = t[keep], sp[keep]
        best_err = math.inf
        for tau in np.arange(a, b + step / 2, step):
            err = float(np.mean((scenario.reference(tt + tau)["left"] - ss) ** 2))
            if err < best_err:
                best, best_err = float(tau), err
    return best


def measured_schedule(t: np.ndarray, flying: np.ndarray, tau: float, loop_hz: float, servo_hz: float,
                      wake: bool) -> Schedule:
    """The real-time run's cycle schedule in scenario time (``t``: log times, ``tau``: scenario time
    at log time 0): the fixed ticks' grid, where the FC's messages fell in it, when they began.

    The first cycle after each deadline is that tick; the cycles in between were woken by messages."""
    period, speriod = 1.0 / loop_hz, 1.0 / servo_hz
    k = np.floor(t / period + 1e-9).astype(np.int64)
    first = np.ones(t.size, dtype=bool)
    first[1:] = k[1:] != k[:-1]
    late = t[first] - k[first] * period
    tick_off = tau + float(np.median(late))
    woken = ~first & flying
    start = tau + float(t[np.argmax(flying)])
    lat = Schedule().latency_s
    if wake and np.count_nonzero(woken) > 0.1 * np.count_nonzero(first & flying):
        ph = 2 * np.pi * (((tau + t[woken]) % speriod) / speriod)
        mean = math.atan2(float(np.mean(np.sin(ph))), float(np.mean(np.cos(ph))))
        msg_off = (mean / (2 * np.pi)) * speriod % speriod - lat
    else:  # messages read by the ticks themselves: they arrive just before (or at) a tick
        msg_off = tick_off - lat - 0.5 * MERGE_S
    return Schedule(tick_offset_s=tick_off % period, msg_offset_s=msg_off % speriod,
                    stream_start_s=start - lat - 0.25 * speriod, wake_on_message=wake)


def row_reads(read_idx: np.ndarray, read_t: np.ndarray, target_t: np.ndarray) -> np.ndarray:
    """Each row's read in the rig, also for rows whose answer the bridge did not get (-1: none).

    The bridge reads a wing's sensor and then sets its servo once per cycle, and the rig handles
    both in order: the read between the targets of rows j - 1 and j is row j's (the rig may have
    stopped before handling the last rows' bytes: the targets it handled are the first rows').
    Without targets ``read_idx`` (the answered reads, ``join_reads``) plus, in each gap between
    two answered rows, the reads the rig took there given in order to the gap's first rows."""
    n = len(read_idx)
    if 0 < len(target_t) <= n:  # the rig stopped before it had handled the last cycles' bytes: a prefix
        idx = np.full(n, -1, dtype=np.int64)
        row = np.searchsorted(np.asarray(target_t, dtype=np.float64), np.asarray(read_t, dtype=np.float64))
        ok = row < len(target_t)
        idx[row[ok]] = np.flatnonzero(ok)
        return idx
    idx = np.array(read_idx, dtype=np.int64)
    known = np.flatnonzero(idx >= 0)
    bounds = [(-1, -1)] + [(int(j), int(idx[j])) for j in known] + [(n, len(read_t))]
    for (r0, q0), (r1, q1) in zip(bounds, bounds[1:], strict=False):
        for row_j, q in zip(range(r0 + 1, r1), range(q0 + 1, q1), strict=False):
            idx[row_j] = q
    return idx


def io_delays(log_t: np.ndarray, rig_at_log0: float, vrig: VirtualRig, read_idx: dict[str, np.ndarray],
              ) -> tuple[tuple[float, ...], ...]:
    """Per cycle-log row: when the bridge's sensor read and servo target of each wing reached the rig,
    after the cycle's start (s; (left read, left target, right read, right target)).

    The bridge reads each sensor and then sets each servo once per cycle, and the board handles them
    in order: the j-th target is the j-th row's, and a row's read is the one ``row_reads`` places
    before it (answered or not; the median delay where none: a read the driver did not send).
    Delays are kept however long: on a busy machine the board may take several cycles to answer,
    and the replay must see that."""
    cols = []
    start = log_t + rig_at_log0
    for w in WINGS:
        rd = np.asarray(vrig.reads[w], dtype=np.float64).reshape(-1, 5)[:, 0]
        tg = np.asarray(vrig.target_log[w], dtype=np.float64).reshape(-1, 2)[:, 0]
        idx = row_reads(read_idx[w], rd, tg)
        ok = idx >= 0
        r = np.full(log_t.size, np.nan)
        r[ok] = rd[idx[ok]] - start[ok]
        r[~ok] = np.median(r[ok]) if ok.any() else 0.0
        if 0 < tg.size <= log_t.size:  # the j-th target is the j-th row's (the last rows': never handled)
            g = np.full(log_t.size, np.nan)
            g[:tg.size] = tg - start[:tg.size]
            g[tg.size:] = np.median(g[:tg.size])
        else:
            j = np.searchsorted(tg, start + r)
            g = np.full(log_t.size, np.nan)
            g[j < tg.size] = tg[j[j < tg.size]] - start[j < tg.size]
            g[~np.isfinite(g)] = np.median(g[np.isfinite(g)]) if np.isfinite(g).any() else 0.0
        cols += [np.maximum(r, 0.0), np.maximum(g, 0.0)]
    return tuple(zip(*(c.tolist() for c in cols), strict=True))


def fc_pwm_of(setpoint_left: np.ndarray, flying: np.ndarray, rig: Rig) -> tuple[float, ...]:
    """The FC's aileron PWM (us) each cycle of the real-time run had, from the left wing's logged
    setpoint (the rig's mix inverted; the FC sends whole microseconds); NaN before it followed the FC."""
    w, bias, top = np.asarray(setpoint_left, dtype=np.float64), rig.bias_deg, rig.max_warp_deg
    a = np.where(w >= bias, (w - bias) / (top - bias), w / bias - 1.0)
    pwm = np.round(rig.pwm_of(a))
    return tuple(np.where(flying & np.isfinite(pwm), pwm, np.nan).tolist())


def rig_reads(vrig: VirtualRig, read_idx: dict[str, np.ndarray]) -> tuple[tuple[bool, ...], ...]:
    """Per cycle-log row and wing: whether the rig's sensor took a reading in that cycle (``row_reads``),
    answered in time or not."""
    took = []
    for w in WINGS:
        rd = np.asarray(vrig.reads[w], dtype=np.float64).reshape(-1, 5)[:, 0]
        tg = np.asarray(vrig.target_log[w], dtype=np.float64).reshape(-1, 2)[:, 0]
        took.append((row_reads(read_idx[w], rd, tg) >= 0).tolist())
    return tuple(zip(*took, strict=True))


def board_answers(logged_deg: dict[str, np.ndarray], read_idx: dict[str, np.ndarray], counts_of_deg,
                  ) -> tuple[tuple[float | None, ...], ...]:
    """Per cycle-log row and wing (left, right): what the lock-step board answers the bridge's read.

    None where the bridge got its own read's answer (the replay reads its simulated wing); otherwise
    what the bridge got instead: NaN when no answer came in time, or the counts of the answer it took
    (a late answer to an earlier query, on a board starved of CPU)."""
    cols = []
    for w in WINGS:
        got = np.asarray(logged_deg[w], dtype=np.float64)
        counts = np.where(np.isfinite(got), np.round(counts_of_deg(np.nan_to_num(got))), np.nan)
        cols.append([None if i >= 0 else float(c) for i, c in zip(read_idx[w], counts, strict=True)])
    return tuple(zip(*cols, strict=True))


def run_realtime(args: argparse.Namespace, out: Path, spec: WingSpec, gcs: list[str]) -> int:
    rig = Rig()
    name = args.scenario or "random"
    scenario = make_scenario(name, HOLD_S + args.duration + STARTUP_MARGIN_S, rig=rig, seed=args.seed,
                             hold_s=HOLD_S)
    roll_csv = scenario.write_csv(out / "roll.csv")
    fc_port = free_udp_port()
    wings = make_wings(scenario, spec, w0_deg=rig.bias_deg, seed=args.seed, grid=True)
    vrig = VirtualRig(rig, wings)
    emu = MaestroEmulator(on_target=vrig.on_target, read_analog=vrig.read_analog)
    mock = bridge = None
    interrupted: float | None = None  # s of flight when Ctrl-C stopped the run
    bridge_log = out / "bridge-cycles.csv"
    t_start = time.monotonic()
    model_file = "paper" if args.bridge_model == "paper" else str(Path(args.bridge_model).resolve())
    kp, ki = chosen_gains(args)
    kw = {"kp": kp, "ki": ki}
    toml = rig.config_toml(connection=f"udpin:127.0.0.1:{fc_port}", servo_backend="maestro:PTY",
                           sensor_backend="maestro:", mode=args.mode, model_file=model_file, log=bridge_log.name,
                           params_file="params.json", **kw)
    cfg = parse_config(tomllib.loads(toml), out, origin="sitl")
    print(f"sitl: {scenario.name} ({scenario.description}), {args.duration:g} s after a {HOLD_S:g} s neutral "
          f"hold; output in {out}", flush=True)
    try:
        pty = emu.start()
        cfg_path = out / "warpbridge-sitl.toml"
        # the emulated board answers once this process gets the CPU, on a busy machine far later than a
        # real board's millisecond: the bridge waits for it (its lateness is in the cycle log, and replayed)
        cfg_path.write_text(toml.replace("maestro:PTY", f"maestro:{pty},timeout={EMULATED_BOARD_TIMEOUT_S:g}"),
                            encoding="utf-8")
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        # the bridge first (listening, in failsafe), then the FC: its roll clock starts with its process
        print(f"sitl: starting the bridge (Maestro emulator on {pty}) ...", flush=True)
        with (out / "bridge.log").open("w") as blog:
            bridge = subprocess.Popen(
                [sys.executable, "-m", "warpbridge.bridge.cli", "run", "--config", str(cfg_path)],
                stdout=blog, stderr=subprocess.STDOUT, env=env, start_new_session=True)
        children = ((bridge, "bridge", "bridge.log"),)
        _wait_until(lambda: bool(vrig.reads["left"]), vrig, children, out, "the bridge to start its loop")
        print(f"sitl: bridge running ({vrig.now():.1f} s); starting the mock {args.autopilot} "
              f"(to the bridge on UDP {fc_port}) ...", flush=True)
        print(f"sitl: ground station: {gcs_banner(gcs)}", flush=True)
        t_mock = vrig.now()
        with (out / "mock-autopilot.log").open("w") as mlog:
            mock = subprocess.Popen(
                [sys.executable, "-m", "warpbridge.sitl.mock_autopilot", "--fc-port", str(fc_port),
                 *(a for g in gcs for a in ("--gcs", g)),
                 "--autopilot", args.autopilot, "--roll-file", str(roll_csv), "--seed", str(args.seed), "-v"],
                stdout=mlog, stderr=subprocess.STDOUT, env=env, start_new_session=True)
        children = ((mock, "mock autopilot", "mock-autopilot.log"), (bridge, "bridge", "bridge.log"))
        mock_log = out / "mock-autopilot.log"
        _wait_until(lambda: "message 36 interval set" in _text(mock_log), vrig, children, out,
                    "the mock autopilot to stream servo outputs to the bridge")
        t_stream = vrig.now()
        print(f"sitl: FC streaming to the bridge ({t_stream - t_mock:.1f} s); flying "
              f"{HOLD_S + args.duration:g} s in real time (Ctrl-C: stop and compare the part flown) ...",
              flush=True)
        try:
            _fly(HOLD_S + args.duration + END_MARGIN_S, vrig, t_stream, children, out)
        except Terminated:
            raise
        except KeyboardInterrupt:  # Ctrl-C: the part flown is compared (a second one quits)
            interrupted = vrig.now() - t_stream
            print(f"\nsitl: stopped after {interrupted:.1f} s of flight; comparing the part flown "
                  "(Ctrl-C again to quit) ...", flush=True)
    finally:
        _stop_child(bridge, "bridge", signal.SIGTERM)  # the bridge closes its log on SIGTERM as on Ctrl-C
        _stop_child(mock, "mock autopilot", signal.SIGTERM)
        emu.stop()
    log.info("real-time run took %.1f s", time.monotonic() - t_start)

    if not bridge_log.exists():
        raise UserError(f"the bridge wrote no cycle log; see {out / 'bridge.log'}:\n{_tail(out / 'bridge.log')}")
    print(f"sitl: joining the bridge's {_count_lines(bridge_log)} logged cycles to the wings' true warp ...",
          flush=True)
    cyc = read_cycle_log(bridge_log)
    np.savez_compressed(out / "rig.npz", **{f"{w}_{k}": np.asarray(v, dtype=np.float64) for w in WINGS for k, v in
                                           (("reads", vrig.reads[w]), ("targets", vrig.target_log[w]))})
    rt, rig_at_log0, read_idx = realtime_result(scenario, args.mode, cyc, vrig)
    # log time -> scenario time: the scenario started with the mock's process, after the bridge's log
    guess = rig_at_log0 - t_mock
    fl = rt.flying if rt.flying is not None else np.ones(rt.t.size, dtype=bool)
    tau = scenario_offset(scenario, rt.t[fl], rt.setpoint["left"][fl], guess - MOCK_START_MAX_S, guess + 0.05)
    rt.t = rt.t + tau
    # the same stretch of the same scenario in lock-step, with the real-time run's cycle schedule
    sched = measured_schedule(cyc["t"], fl, tau, cfg.loop.rate_hz, cfg.link.servo_rate_hz,
                              cfg.loop.wake_on_message)
    t_from = max(HOLD_S, float(rt.t[np.argmax(fl)])) + SETTLE_S
    t_to = min(HOLD_S + args.duration, float(rt.t[-1]))
    if t_to - t_from < 1.0:
        if interrupted is not None:  # the user's stop, not a failure: the exit code says interrupted
            print(f"sitl: stopped after {interrupted:.1f} s of flight, too early to compare (the scenario starts "
                  f"after a {HOLD_S:g} s neutral hold); logs: {out}", file=sys.stderr)
            return 130
        raise UserError(f"the bridge followed the FC for only {max(0.0, t_to - t_from + SETTLE_S):.1f} s")
    print("sitl: flying the same stretch in lock-step (the bridge's cycle on a simulated clock) ...", flush=True)
    runs = {}
    table_counts, table_deg = rig.sensor.calibration_table()
    answers = board_answers({w: cyc[f"{w}_warp"] for w in WINGS}, read_idx,
                            lambda d: np.interp(d, table_deg, table_counts))
    replay = replace(sched, cycle_times=tuple(rt.t), io_delays=io_delays(cyc["t"], rig_at_log0, vrig, read_idx),
                     answers=answers, fc_pwm=fc_pwm_of(cyc["left_setpoint"], fl, rig),
                     rig_read=rig_reads(vrig, read_idx))
    stages = (("lock-step", replay), ("ideal timing", sched))
    for i, (label, sch) in enumerate(stages, start=1):
        with stage_progress(f"sitl: lock-step {i}/{len(stages)} ({label})", t_to + 0.05) as progress, \
                simulated_bridges_quiet():
            runs[label], _ = run_lockstep(
                scenario, mode=args.mode, spec=spec,
                config=rig_config(rig, args.mode, kw["kp"], kw["ki"], model_file=model_file), seed=args.seed,
                schedule=sch, t_end=t_to + 0.05, flow_shift_s=rig_at_log0 - tau, progress=progress)
        runs[label].compute_rms(t_from=t_from, t_to=t_to)
    ls, ideal = runs["lock-step"], runs["ideal timing"]
    rt.compute_rms(t_from=t_from, t_to=t_to)
    print()
    print(run_table({"real time": rt, **runs}))
    print("lock-step: the bridge's cycle at the real-time run's cycle times; ideal timing: at its nominal "
          "schedule (no scheduling gaps).")
    rel = {w: abs(rt.rms[w] - ls.rms[w]) / ls.rms[w] for w in WINGS}
    changed = params_set_in_run(out / "params.json")
    agree = all(v <= AGREE_TOLERANCE for v in rel.values()) if not changed else None
    verdict = ("not compared: " + ", ".join(changed) + " set in the run, which the lock-step replay does not "
               "fly" if changed else f"{'agree' if agree else 'DISAGREE'} within {100 * AGREE_TOLERANCE:.0f} %")
    print(f"scenario {t_from:.2f} .. {t_to:.2f} s; real time vs lock-step: "
          f"{', '.join(f'{w} {100 * v:.0f} %' for w, v in rel.items())} apart ({verdict})")
    if changed:
        print("  (parameters set from a ground station, a calibration, or a reused --out: the lock-step replay flies "
              "the configuration's starting values, so the two runs are not like for like)")
    if abs(rt.cycles - ls.cycles) > 0.05 * ls.cycles:
        log.warning("the real-time bridge ran %d cycles on that stretch, lock-step %d: the machine was busy",
                    rt.cycles, ls.cycles)
    summary = {"scenario": name, "mode": args.mode, "duration_s": args.duration, "autopilot": args.autopilot,
               "gcs": gcs,
               "effects": _effects_dict(spec), "plant": args.plant, "scenario_offset_s": tau, "hold_s": HOLD_S,
               "stretch_s": [t_from, t_to],
               "schedule": {"tick_offset_s": sched.tick_offset_s, "msg_offset_s": sched.msg_offset_s,
                            "stream_start_s": sched.stream_start_s, "wake_on_message": sched.wake_on_message},
               "rms_deg": {"realtime": rt.rms, "lockstep": ls.rms, "lockstep_ideal_timing": ideal.rms},
               "rel_diff": rel, "agree": agree, "params_set_in_run": changed,
               "cycles": int(rt.cycles), "cycles_lockstep": int(ls.cycles), "cycles_logged": int(cyc["t"].size),
               "stopped_after_s": interrupted}
    (out / "summary.json").write_text(json.dumps(summary, indent=2), encoding="utf-8")
    if not args.no_plot:
        png = plot_run(rt, out / "sitl.png", title=f"SITL real time: {name}, {args.mode}", other=ls)
        print(f"plot: {png}")
    print(f"logs: {out}")
    if interrupted is not None:
        print(f"sitl: the run was stopped after {interrupted:.1f} s of the {HOLD_S + args.duration:g} s asked for; "
              f"the figures cover {t_from:.2f} .. {t_to:.2f} s")
        return 130
    return 0


def params_set_in_run(path: Path) -> list[str]:
    """The parameters the run's store holds that a user set (the adaptation's own estimates left out): what
    the lock-step replay, flying the configuration, does not."""
    from warpbridge.bridge.calibrate import FieldTuning

    try:
        stored = json.loads(path.read_text(encoding="utf-8")).get("params", {})
    except (OSError, ValueError, AttributeError):
        return []
    return sorted(k for k in stored if not FieldTuning.is_estimate(k))


def gcs_banner(gcs: list[str]) -> str:
    """One line telling a user where to attach a ground station."""
    if not gcs:
        return "none (--no-gcs)"
    where = []
    for g in gcs:
        kind, _, address = g.partition(":")
        where.append(f"listening on {address}" if kind in ("udpin", "tcpin") else f"sending to {address}")
    usual = any(g.partition(":")[0] == "udp" and g.rsplit(":", 1)[-1] == "14550" for g in gcs)
    return (f"{', '.join(where)} ({', '.join(gcs)}); the autopilot is component 1, the bridge component 191"
            + (" (QGroundControl, Mission Planner, MAVProxy listen on 14550)" if usual else ""))


def _count_lines(path: Path) -> int:
    with path.open("rb") as f:
        return max(0, sum(1 for _ in f) - 1)


def _text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return ""


def _check_children(children, out: Path) -> None:
    for proc, name, logf in children:
        if proc.poll() is not None:
            raise UserError(f"the {name} exited with status {proc.returncode}; {out / logf}:\n{_tail(out / logf)}")


def _cpu_seconds(pid: int) -> float | None:
    """CPU time (user + system) a process has used so far, from /proc; None where there is none."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def _wait_until(done, vrig: VirtualRig, children, out: Path, what: str) -> None:
    """Wait until ``done()``; fail if a child dies or gets nowhere.

    On a busy machine a child's start-up (imports, compiled kernels) takes several times longer in
    wall time but not in CPU time, so the children may use ``STARTUP_TIMEOUT_S`` s of CPU, or sit
    that long without using any (blocked: hung), before this gives up (where /proc tells CPU time;
    else after that long in wall time)."""
    t0 = time.monotonic()
    cpu = [_cpu_seconds(p.pid) for p, _, _ in children]
    cpu0, last, last_change = cpu, cpu, t0
    while not done():
        vrig.tick()
        _check_children(children, out)
        now, cpu = time.monotonic(), [_cpu_seconds(p.pid) for p, _, _ in children]
        if any(c is None for c in cpu + cpu0):
            stuck = now - t0 > STARTUP_TIMEOUT_S
        else:
            last_change = now if cpu != last else last_change
            stuck = sum(cpu) - sum(cpu0) > STARTUP_TIMEOUT_S or now - last_change > STARTUP_TIMEOUT_S
        last = cpu
        if stuck:
            logs = "\n".join(f"{out / f}:\n{_tail(out / f)}" for _, _, f in children)
            raise UserError(f"gave up waiting for {what} after {now - t0:.0f} s\n{logs}")
        time.sleep(0.02)


@contextmanager
def stage_progress(label: str, total_s: float) -> Iterator[Callable[[float], None]]:
    """A progress callback over ``total_s`` simulated seconds: a tqdm bar on a terminal, else a line
    when the stage starts and one when it ends (with its wall time)."""
    t0 = time.monotonic()
    quiet = logging.getLogger("warpbridge.bridge.telemetry")  # the replayed bridge's status lines, again
    level = quiet.level
    quiet.setLevel(max(logging.WARNING, quiet.getEffectiveLevel()))
    try:
        yield from _stage_bar(label, total_s)
    finally:
        quiet.setLevel(level)
    print(f"{label}: done in {time.monotonic() - t0:.1f} s", flush=True)


def _stage_bar(label: str, total_s: float) -> Iterator[Callable[[float], None]]:
    from tqdm import tqdm

    if sys.stderr.isatty():
        with tqdm(total=round(total_s, 1), unit="s", desc=label, leave=False) as bar:
            def update(t: float) -> None:
                bar.n = round(min(t, total_s), 1)
                bar.refresh()

            yield update
    else:
        print(f"{label}: {total_s:.0f} s simulated ...", flush=True)
        yield lambda t: None


def _fly(seconds: float, vrig: VirtualRig, t0: float, children, out: Path) -> None:
    """Fly for ``seconds`` of rig time from ``t0``, with progress; fail if a child dies."""
    from tqdm import tqdm

    tty = sys.stderr.isatty()
    next_line = 5.0
    with tqdm(total=round(seconds, 1), unit="s", desc="sitl", leave=False, disable=not tty) as bar:
        while (flown := vrig.now() - t0) < seconds:
            vrig.tick()
            bar.n = round(min(flown, seconds), 1)
            bar.refresh()
            if not tty and flown >= next_line:
                print(f"sitl: {next_line:g} / {seconds:.0f} s", flush=True)
                next_line += 5.0
            _check_children(children, out)
            time.sleep(0.02)


# ------------------------------------------------------------------ entry point


MAX_DURATION_S = 3600.0  # an hour of flight; the lock-step replay of it takes tens of minutes


def check_options(args: argparse.Namespace) -> None:
    """Refuse option values that would fail deep inside the run, with one line each."""
    if not 0 < args.duration <= MAX_DURATION_S:
        raise UserError(f"--duration must be within 0..{MAX_DURATION_S:g} s (got {args.duration:g})")
    if args.seed < 0:
        raise UserError("--seed must be 0 or more")
    for name in ("kp", "ki"):
        v = getattr(args, name)
        if v is not None and not 0 <= v <= 100:
            raise UserError(f"--{name} must be within 0..100 (got {v:g})")
    if args.bridge_model == "identify" and args.plant != "sheath":
        raise UserError("--bridge-model identify needs --plant sheath")
    if args.bridge_model not in (None, "paper", "identify"):  # read before anything starts, named as given
        from warpbridge.bridge.commands.modelio import load_model

        try:
            load_model(args.bridge_model)
        except UserError as e:
            raise UserError(f"--bridge-model: {e}") from None


@contextmanager
def simulated_bridges_quiet() -> Iterator[None]:
    """The lock-step runs' bridges log errors only (unless -v): a dozen simulated start-ups (the failsafe until
    the FC's first output, the output check) would bury the runs' own progress and the table."""
    bridge_log = logging.getLogger("warpbridge.bridge")
    before = bridge_log.level
    if logging.getLogger().getEffectiveLevel() > logging.DEBUG:
        bridge_log.setLevel(logging.ERROR)
    try:
        yield
    finally:
        bridge_log.setLevel(before)


def main(args: argparse.Namespace) -> int:
    check_options(args)
    spec = wing_spec(args.model, parse_effects(args.effects), args.plant)
    out = args.out or Path(f"sitl-run-{time.strftime('%Y%m%d-%H%M%S')}")
    if args.lockstep:
        if args.bridge_model == "identify" or (args.bridge_model is None and args.plant == "sheath"):
            out.mkdir(parents=True, exist_ok=True)
        args.bridge_model = resolve_bridge_model(args, out)
        scenarios = (args.scenario,) if args.scenario else ("random", "gust7", "gust12")
        kp, ki = chosen_gains(args)
        gains = f"set {args.gains}" if args.kp is None and args.ki is None else "given"
        print(f"lock-step, {args.duration:g} s per run; PI gains kp = {kp:.3g} mm/deg, ki = {ki:.3g} mm/(deg s) "
              f"({gains}); simulated wing: {args.plant}, effects: {_effects_dict(spec) or 'none'}; bridge model: "
              f"{args.bridge_model}")
        with simulated_bridges_quiet():
            rows = compare(scenarios, duration_s=args.duration, spec=spec, kp=kp, ki=ki, seeds=(args.seed,),
                           model_file=args.bridge_model)
        exact = args.plant == "bouc-wen" and args.bridge_model == "paper" and not args.model \
            and not args.effects.strip()
        print(comparison_table(rows, note=(
            "The controller knows this wing's hysteresis exactly (the paper's plant and model; only the wing's small "
            "aerodynamic load, 4 % of the warp at 12 m/s, is not in its model): an upper bound, not a like-for-like "
            "comparison; --plant sheath flies a wing identified on the bench and re-rigged.") if exact else None))
        return 0
    gcs = gcs_outputs(args)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UserError(f"--out {out}: cannot make the folder ({e.strerror or e})") from None
    args.bridge_model = resolve_bridge_model(args, out)
    # Ctrl-C and SIGTERM both unwind through run_realtime's clean-up (even where SIGINT was ignored)
    old = {s: signal.signal(s, _raise_interrupt) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        return run_realtime(args, out, spec, gcs)
    finally:
        for s, h in old.items():
            signal.signal(s, h)


class Terminated(KeyboardInterrupt):
    """SIGTERM: the run stops and nothing is compared."""


def _raise_interrupt(signum, frame) -> None:
    raise Terminated if signum == signal.SIGTERM else KeyboardInterrupt
