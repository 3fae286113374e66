"""Lock-step SITL: the bridge's own control cycle flying the simulated wings on a simulated clock.

Faster than real time and deterministic, and the same code as the real-time run:
``bridge.app.Bridge`` (mixer, controllers, parameters, telemetry) built from the
same TOML the real-time run gives the bridge (``Rig.config_toml``), with three
things injected: a simulated clock, ``SimLink`` (the FC's MAVLink stream as
``FcLink`` presents it: SERVO_OUTPUT_RAW at the configured rate, quantised to
1 us with +-1 us jitter as an autopilot sends it, VFR_HUD, HEARTBEAT) and
``WingBoard`` (the servo board: tendon servos and flex sensors wired to the two
``SimWing`` s, whose plant is sub-stepped at 1 kHz up to each access).

The cycle schedule is the real-time bridge's (``bridge.app.run_bridge``): fixed
ticks at the loop rate and, with ``[loop] wake_on_message``, one more cycle
whenever a message arrives between two ticks; the controller integrates over
the clock time between cycles. ``Schedule`` says where the ticks and the
FC's messages fall (``warpbridge sitl`` measures that on the real-time run and
replays it here).

The tracking error is the bridge's setpoint minus the wing's true warp when the
bridge read that wing's sensor in the same cycle, RMS over the cycles in a
stretch of the scenario. ``compare`` runs every controller mode on calm and
gusty scenarios and gives the rows of the comparison table.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from warpbridge.bridge.app import Bridge
from warpbridge.bridge.config import Config, WingConfig, parse_config
from warpbridge.bridge.controller import MODES, WingController
from warpbridge.model.boucwen import BoucWenParams
from warpbridge.sitl.gust import Gust, GustSpec
from warpbridge.sitl.scenarios import WINGS, Rig, Scenario, make_scenario
from warpbridge.sitl.sim_link import SimLinkBase
from warpbridge.sitl.wing import Flow, SimWing, SteadyFlow, WingSpec

log = logging.getLogger(__name__)

SETTLE_S = 1.0  # the scenario's ramp-in; excluded from the RMS
PAPER_BENCH_RMS = {"open": 1.727, "pi": 2.04, "ff+pi": 0.285}  # deg, Lee et al. (2017), sec. 5.2
MERGE_S = 2e-4  # a message arriving this close before a tick is read by that tick (no cycle of its own)


@dataclass
class RunResult:
    """One run: per-cycle traces (time in scenario seconds) and the RMS tracking error per wing (deg)."""

    scenario: str
    mode: str
    t: np.ndarray
    airspeed: np.ndarray  # at the wing (m/s)
    setpoint: dict[str, np.ndarray]
    warp: dict[str, np.ndarray]  # true warp when the bridge read the sensor
    measured: dict[str, np.ndarray]  # what the bridge read
    u_cmd: dict[str, np.ndarray]  # tendon command (mm)
    u: dict[str, np.ndarray]  # tendon travel at the servo (mm)
    flying: np.ndarray | None = None  # the bridge followed the FC (not failsafe) in that cycle
    rms: dict[str, float] = field(default_factory=dict)
    stretch: tuple[float, float] = (math.nan, math.nan)  # scenario time the RMS covers
    cycles: int = 0  # cycles in that stretch

    def window(self, t_from: float, t_to: float = math.inf) -> np.ndarray:
        """Mask of the cycles in [t_from, t_to]."""
        return (self.t >= t_from) & (self.t <= t_to)

    def compute_rms(self, settle_s: float = SETTLE_S, t_from: float | None = None, t_to: float | None = None,
                    ) -> dict[str, float]:
        """RMS per wing after ``settle_s`` (or over [t_from, t_to] when given)."""
        lo = self.t[0] + settle_s if t_from is None else t_from
        hi = math.inf if t_to is None else t_to
        keep = self.window(lo, hi)
        self.rms = {w: rms_error(self.setpoint[w][keep], self.warp[w][keep]) for w in self.setpoint}
        self.stretch = (float(lo), float(min(hi, self.t[-1])))
        self.cycles = int(np.count_nonzero(keep))
        return self.rms


def rms_error(setpoint: np.ndarray, warp: np.ndarray) -> float:
    """RMS of setpoint - warp over the samples where both are finite (deg)."""
    e = np.asarray(setpoint, float) - np.asarray(warp, float)
    e = e[np.isfinite(e)]
    return float(np.sqrt(np.mean(e * e))) if e.size else math.nan


def rig_config(rig: Rig, mode: str = "ff+pi", kp: float | None = None, ki: float | None = None,
               extra_control: dict[str, float] | None = None, model_file: str = "paper") -> Config:
    """The bridge configuration of ``rig`` (the real-time run's TOML), parsed; no parameter file."""
    import tomllib
    from pathlib import Path

    kw = {} if kp is None else {"kp": kp}
    if ki is not None:
        kw["ki"] = ki
    text = rig.config_toml(connection="udpin:127.0.0.1:0", servo_backend="loop:", sensor_backend="loop:",
                           mode=mode, extra_control=extra_control, model_file=model_file, **kw)
    cfg = parse_config(tomllib.loads(text), Path("."), origin="sitl rig")
    return replace(cfg, params_file=None)  # type: ignore[arg-type]  # ParamStore(None): in memory only


def make_controller(wing: WingConfig, params: BoucWenParams, mode: str | None = None) -> WingController:
    """A WingController set up from a wing's configuration, as the bridge does."""
    c = wing.control
    lo, hi = wing.servo.mm_limits
    return WingController(
        params, mode=mode or c.mode, kp=c.kp, ki=c.ki, i_max=c.i_max_mm,
        u_min=lo if c.u_min_mm is None else c.u_min_mm, u_max=hi if c.u_max_mm is None else c.u_max_mm,
        w_max=wing.max_warp_deg, deadband=c.deadband_deg, w0=wing.bias_deg,
    )


class ShiftedFlow:
    """``flow`` seen ``shift_s`` later: a wing on another clock flies through the same air."""

    def __init__(self, flow: Flow, shift_s: float) -> None:
        self.flow, self.shift_s = flow, float(shift_s)

    def airspeed(self, t):
        return self.flow.airspeed(np.asarray(t, dtype=np.float64) + self.shift_s)

    def buffet_deg(self, t, airspeed=None):
        return self.flow.buffet_deg(np.asarray(t, dtype=np.float64) + self.shift_s, airspeed)


def make_wings(scenario: Scenario, spec: WingSpec, w0_deg: float, seed: int = 0, record: bool = False,
               flow_shift_s: float = 0.0, t0: float = 0.0, grid: bool = False) -> dict[str, SimWing]:
    """Both simulated wings for a scenario: each in its own realisation of the scenario's flow.

    ``flow_shift_s``: the flow's time at the wings' time 0 (to meet the same gusts as another run);
    ``t0``: the wings' start time; ``grid``: sub-steps on a grid anchored at the flow's time 0
    (``SimWing`` ``grid_origin``), the same for a real-time run and its replay."""
    wings = {}
    for i, name in enumerate(WINGS):
        flow: Flow
        if scenario.gust is not None:
            g = scenario.gust
            flow = Gust(GustSpec(g.mean_ms, g.intensity, g.shedding_hz, g.shedding_share, g.shedding_width_hz,
                                 g.length_scale_m, g.buffet_deg_per_kpa, g.seed + 17 * i))
        else:
            flow = SteadyFlow(scenario.airspeed_ms)
        if flow_shift_s:
            flow = ShiftedFlow(flow, flow_shift_s)
        wings[name] = SimWing(spec, flow, t0=t0, w0_deg=w0_deg, seed=seed + 101 * (i + 1), record=record,
                              grid_origin=-flow_shift_s if grid else None)
    return wings


class FcOutputs:
    """The autopilot's servo output stream: the scenario's PWM sampled every 1 / ``rate_hz`` from
    ``phase`` periods on, rounded to 1 us with a uniform +-``jitter_us`` of noise."""

    def __init__(self, scenario: Scenario, rate_hz: float, jitter_us: float = 1.0, seed: int = 0,
                 phase: float = 0.37, start_s: float = 0.0) -> None:
        self.scenario = scenario
        self.period = 1.0 / rate_hz
        self.jitter_us = jitter_us
        self._rng = np.random.default_rng(seed)
        first = phase * self.period
        if start_s > first:  # the first send time at or after start_s on the same grid
            first += math.ceil((start_s - first) / self.period - 1e-9) * self.period
        self._k = 0
        self._first = first
        self.pwm: dict[int, float] = {}
        self.sent = 0

    @property
    def next_time(self) -> float:
        """Send time of the next message."""
        return self._first + self._k * self.period

    def send(self) -> dict[int, float]:
        """The next message's PWM by channel (and advance to the one after)."""
        t = self.next_time
        out = {ch: float(v) for ch, v in self.scenario.pwm_at(t).items()}
        j = self._rng.uniform(-self.jitter_us, self.jitter_us, len(out)) if self.jitter_us > 0 else [0.0] * len(out)
        self.pwm = {ch: float(round(v + jj)) for (ch, v), jj in zip(out.items(), j, strict=True)}
        self._k += 1
        self.sent += 1
        return self.pwm

    def poll(self, t: float) -> dict[int, float]:
        """The latest message's PWM by channel at time t ({} before the first)."""
        while self.next_time <= t + 1e-12:
            self.send()
        return self.pwm


@dataclass(frozen=True)
class Schedule:
    """When things happen in a lock-step run (scenario seconds).

    Fixed ticks at ``tick_offset_s`` + k / loop rate; the FC's servo messages sent at
    ``msg_offset_s`` + j / stream rate from ``stream_start_s`` on (the FC streams once asked),
    arriving ``latency_s`` later; VFR_HUD with every n-th servo message (n = stream rate / 10 Hz)
    and the FC's HEARTBEAT at 1 Hz from ``heartbeat_offset_s``. ``wake_on_message`` None: the
    config's ``[loop] wake_on_message``. ``cycle_times``: run the cycles exactly then instead
    (a real-time run's, from its cycle log: its scheduling gaps included), with ``io_delays`` per
    cycle: (left sensor read, left servo target, right read, right target) after the cycle's start,
    ``answers`` per cycle and wing: None = the board reads the wing, else what the real-time bridge
    got instead (NaN: no answer in time; counts: a late answer to an earlier query), and ``fc_pwm``
    per cycle: the aileron PWM the real-time bridge had from the FC then (its messages' own timing),
    ``rig_read`` per cycle and wing: whether the rig's sensor took a reading then (whatever the
    bridge got), so that the replay's sensors draw the same noise in the same order."""

    tick_offset_s: float = 0.0
    msg_offset_s: float = 0.0037
    stream_start_s: float = 0.0
    latency_s: float = 0.0003
    heartbeat_offset_s: float = 0.5
    airspeed_rate_hz: float = 10.0
    wake_on_message: bool | None = None
    cycle_times: tuple[float, ...] | None = None
    io_delays: tuple[tuple[float, float, float, float], ...] | None = None
    answers: tuple[tuple[float | None, float | None], ...] | None = None
    fc_pwm: tuple[float, ...] | None = None
    rig_read: tuple[tuple[bool, bool], ...] | None = None


class SimLink(SimLinkBase):
    """The flight controller as ``Bridge`` sees an ``FcLink``, driven by a simulated clock.

    ``deliver(t)`` makes the messages sent up to ``t - latency`` pending; ``poll()`` consumes them the
    way ``FcLink.poll`` does (servo outputs, airspeed, heartbeat) and returns nothing for the
    parameter server. Whatever the bridge sends is counted."""

    def __init__(self, scenario: Scenario, fc: FcOutputs, schedule: Schedule, clock: Callable[[], float]) -> None:
        super().__init__()
        self.scenario, self.fc, self.schedule, self.clock = scenario, fc, schedule, clock
        self.servo_messages = 0
        self._pending: list[tuple[str, object]] = []
        self._every = max(1, round(1.0 / (fc.period * schedule.airspeed_rate_hz)))
        self._next_hb = schedule.heartbeat_offset_s
        self.pwm_override: dict[int, float] | None = None  # replays: the PWM a real-time cycle had

    def next_arrival(self) -> float:
        """When the next message (servo output or heartbeat) reaches the bridge."""
        return min(self.fc.next_time, self._next_hb) + self.schedule.latency_s

    def deliver(self, t: float) -> None:
        """Queue every message that has arrived by ``t``."""
        lat = self.schedule.latency_s
        while self.fc.next_time + lat <= t + 1e-12:
            self._pending.append(("servo", self.fc.send()))
            if (self.fc.sent - 1) % self._every == 0:
                self._pending.append(("airspeed", float(self.scenario.airspeed_ms)))
        while self._next_hb + lat <= t + 1e-12:
            self._pending.append(("heartbeat", None))
            self._next_hb += 1.0

    def poll(self) -> list:
        now = self.clock()
        for kind, value in self._pending:
            if kind == "servo":
                assert isinstance(value, dict)
                self.servo_raw = dict(value)
                self.servo_pwm = dict(value)
                self.servo_time = now
                self.servo_messages += 1
            elif kind == "airspeed":
                self.airspeed, self.airspeed_time = float(value), now  # type: ignore[arg-type]
        self._pending.clear()
        if self.pwm_override is not None and self.servo_time is not None:
            self.servo_raw = dict(self.pwm_override)
            self.servo_pwm = dict(self.pwm_override)
        return self.take_replies()


Read = tuple[float, int, float, float, float]  # (t, counts, true warp, tendon mm, airspeed)


class WingBoard:
    """The servo board of the rig wired to the simulated wings (``hw`` ServoOutput and WarpSensor).

    Every servo target and every sensor read first advances the wings to ``clock()``; each read is
    recorded with the wing's true warp and tendon travel at that instant (``reads``, ``last_read``).
    Pulses are clamped to the channel's calibrated range and set in 0.25 us steps, as a Maestro does.
    ``inject(wing, t)``: tendon travel (mm) added to every servo target (a test signal for measuring
    the loop's frequency response; None: nothing added)."""

    def __init__(self, rig: Rig, wings: dict[str, SimWing], clock: Callable[[], float],
                 inject: Callable[[str, float], float] | None = None) -> None:
        self.rig, self.wings, self.clock = rig, wings, clock
        self.inject = inject
        self.servo_of = dict(zip(rig.servo_channels, WINGS, strict=True))
        self.sensor_of = dict(zip(rig.sensor_channels, WINGS, strict=True))
        s = rig.servo
        self.limits = (s.pulse_min_us, s.pulse_max_us)
        self.reads: dict[str, list[Read]] = {w: [] for w in WINGS}
        self.last_read: dict[str, Read | None] = {w: None for w in WINGS}
        self.targets = 0
        self.target_log: dict[str, list[tuple[float, float]]] = {w: [] for w in WINGS}
        self.delays: dict[str, tuple[float, float]] = {}  # wing -> (read, target) delay after clock()
        self.answers: dict[str, float | None] = {}  # wing -> what the next read answers instead (replays)
        self.drawn: dict[str, bool] = {}  # wing -> whether such a read still took the sensor's reading

    def set_target(self, channel: int, pulse_us: float) -> None:
        wing = self.servo_of.get(channel)
        if wing is None:
            return
        t = self.clock() + self.delays.get(wing, (0.0, 0.0))[1]
        if self.inject is not None:
            pulse_us += self.inject(wing, t) / self.rig.servo.mm_per_us
        self.wings[wing].advance(t)
        self.wings[wing].set_pulse(pulse_us)
        self.targets += 1
        self.target_log[wing].append((t, pulse_us))

    def set_pulse(self, channel: int, pulse_us: float) -> None:
        if not math.isfinite(pulse_us):
            raise ValueError("pulse is not a number")
        lo, hi = self.limits
        self.set_target(channel, round(min(hi, max(lo, pulse_us)) * 4) / 4)

    def read_counts(self, channel: int) -> float | None:
        wing = self.sensor_of.get(channel)
        if wing is None:
            return None
        if self.answers.get(wing) is not None:  # a replayed answer: no answer (NaN) or someone else's
            self.wings[wing].sensor.skip(int(self.drawn.get(wing, True)))  # the same noise sequence as the rig
            counts = self.answers[wing]
            return None if not math.isfinite(counts) else counts
        t = self.clock() + self.delays.get(wing, (0.0, 0.0))[0]
        w = self.wings[wing]
        w.advance(t)
        counts = w.read_counts()
        rec = (t, counts, w.w_true, w.u_mm, w.airspeed)
        self.reads[wing].append(rec)
        self.last_read[wing] = rec
        return counts

    def advance(self) -> None:
        """Bring the wings' time up to the clock."""
        t = self.clock()
        for w in self.wings.values():
            w.advance(t)

    def poll_errors(self) -> int:
        return 0

    def error_names(self, bits: int) -> list[str]:
        return []

    def close(self) -> None:
        pass


class SimClock:
    """A clock that only moves when told: ``clock()`` is the time, ``clock.t = ...`` sets it."""

    def __init__(self, t: float = 0.0) -> None:
        self.t = float(t)

    def __call__(self) -> float:
        return self.t


def run_lockstep(scenario: Scenario, *, mode: str = "ff+pi", spec: WingSpec | None = None,
                 config: Config | None = None, controller_params: BoucWenParams | None = None,
                 kp: float | None = None, ki: float | None = None, seed: int = 0,
                 record_wings: bool = False, schedule: Schedule | None = None,
                 t_end: float | None = None, flow_shift_s: float = 0.0,
                 inject: Callable[[str, float], float] | None = None,
                 progress: Callable[[float], None] | None = None,
                 ) -> tuple[RunResult, dict[str, SimWing]]:
    """Fly ``scenario`` in lock-step with the bridge's own cycle in ``mode``, up to ``t_end``
    (default: the scenario's end).

    ``spec`` is the simulated wing (default: the paper's plant with the SITL's small aero
    load); ``controller_params`` the model the bridge uses (default: the config's, the paper's),
    so a wing that differs from the bridge's model is ``spec.with_effects(...)``; ``schedule``
    where the ticks and messages fall (default: ``Schedule()``); ``inject(wing, t)`` tendon mm added to
    each servo target (``WingBoard``); ``progress(t)`` is called with the simulated time about every
    simulated second."""
    spec = spec or WingSpec()
    sched = schedule or Schedule()
    cfg = config or rig_config(scenario.rig, mode, kp, ki)
    if cfg.params_file is not None:
        cfg = replace(cfg, params_file=None)  # type: ignore[arg-type]  # never touch a parameter file
    if cfg.loop.log is not None:
        cfg = replace(cfg, loop=replace(cfg.loop, log=None))
    wake = cfg.loop.wake_on_message if sched.wake_on_message is None else sched.wake_on_message
    # a replay starts where the real-time run's log does (the bridge's start, before the scenario's)
    t0 = min(0.0, min(sched.cycle_times, default=0.0)) if sched.cycle_times is not None else 0.0
    clock = SimClock(t0)
    fc = FcOutputs(scenario, cfg.link.servo_rate_hz, seed=seed + 7,
                   phase=(sched.msg_offset_s * cfg.link.servo_rate_hz) % 1.0, start_s=sched.stream_start_s)
    link = SimLink(scenario, fc, sched, clock)
    rig = scenario.rig
    wings = make_wings(scenario, spec, w0_deg=rig.bias_deg, seed=seed, record=record_wings,
                       flow_shift_s=flow_shift_s, t0=t0, grid=sched.cycle_times is not None)
    board = WingBoard(rig, wings, clock, inject)
    bridge = Bridge(cfg, servo=board, sensor=board, link=link, clock=clock)
    try:
        for w in bridge.wings.values():
            w.ctl.set_mode(mode)
            if kp is not None or ki is not None:
                w.ctl.set_gains(kp=kp, ki=ki)
            if controller_params is not None:
                w.ctl.set_model(controller_params)
        if controller_params is not None:
            bridge.model = controller_params
        return _fly(scenario, mode, bridge, link, board, clock, cfg, sched, wake,
                    scenario.duration_s if t_end is None else t_end, progress), wings
    finally:
        bridge.close()


def _fly(scenario: Scenario, mode: str, bridge: Bridge, link: SimLink, board: WingBoard, clock: SimClock,
         cfg: Config, sched: Schedule, wake: bool, t_end: float,
         progress: Callable[[float], None] | None = None) -> RunResult:
    """The event loop of ``run_bridge``: ticks at the loop rate plus a cycle per arriving message."""
    period = 1.0 / cfg.loop.rate_hz
    k = math.ceil((0.0 - sched.tick_offset_s) / period - 1e-9)
    given = None
    if sched.cycle_times is not None:
        n = len(sched.cycle_times)
        delays = sched.io_delays or ((0.0, 0.0, 0.0, 0.0),) * n
        answers = sched.answers or ((None,) * len(WINGS),) * n
        pwm = sched.fc_pwm or (math.nan,) * n
        drawn = sched.rig_read or ((True,) * len(WINGS),) * n
        given = iter(sorted(zip(sched.cycle_times, delays, answers, pwm, drawn, strict=True), key=lambda e: e[0]))
    rows: list[tuple] = []
    next_report = 1.0
    while True:
        if given is not None:
            t, d, a, p, took = next(given, (math.inf, (0.0,) * 4, (None,) * len(WINGS), math.nan, (True,) * 2))
            link.pwm_override = {cfg.wings["left"].source_channel: p} if math.isfinite(p) else None
            board.delays = {w: (max(0.0, d[2 * i]), max(0.0, d[2 * i], d[2 * i + 1])) for i, w in enumerate(WINGS)}
            board.answers = dict(zip(WINGS, a, strict=True))
            board.drawn = dict(zip(WINGS, took, strict=True))
        else:
            t_tick = sched.tick_offset_s + k * period
            t_msg = link.next_arrival()
            if wake and t_msg < t_tick - MERGE_S:
                t = t_msg
            else:
                t, k = t_tick, k + 1
        if t > t_end + 1e-12:
            break
        if progress is not None and t >= next_report:
            progress(t)
            next_report = t + 1.0
        clock.t = t
        link.deliver(t)
        board.last_read = {w: None for w in WINGS}
        bridge.tick()
        row = [t, float(link.airspeed or 0.0), not bridge.failsafe]
        for w in WINGS:
            last = bridge.wings[w].last
            rd = board.last_read[w]
            row += [_f(last.get("setpoint")), _f(last.get("warp")), _f(last.get("u")),
                    rd[2] if rd is not None else math.nan, rd[3] if rd is not None else math.nan,
                    rd[4] if rd is not None else math.nan]
        rows.append(tuple(row))
    a = np.array(rows, dtype=np.float64).reshape(-1, 3 + 6 * len(WINGS))
    col = {w: 3 + 6 * i for i, w in enumerate(WINGS)}
    res = RunResult(
        scenario.name, mode, a[:, 0], a[:, 3 + 5],
        setpoint={w: a[:, col[w]] for w in WINGS}, warp={w: a[:, col[w] + 3] for w in WINGS},
        measured={w: a[:, col[w] + 1] for w in WINGS}, u_cmd={w: a[:, col[w] + 2] for w in WINGS},
        u={w: a[:, col[w] + 4] for w in WINGS}, flying=a[:, 2] > 0.5,
    )
    res.compute_rms()
    return res


def _f(v: float | None) -> float:
    return math.nan if v is None else float(v)


@dataclass(frozen=True)
class CompareRow:
    """One line of the comparison table: a mode on a scenario over a stretch, one RMS per seed."""

    scenario: str
    mode: str
    rms: tuple[float, ...]  # per seed: RMS of setpoint - true warp over the window, mean of both wings (deg)
    paper: float | None = None  # the paper's bench figure for this mode, where it has one
    window: tuple[float, float] = (SETTLE_S, math.inf)  # scenario seconds the RMS covers
    label: str = ""  # what else distinguishes the row (e.g. the gain set)

    @property
    def rms_mean(self) -> float:
        return float(np.mean(self.rms))

    @property
    def rms_min(self) -> float:
        return float(np.min(self.rms))

    @property
    def rms_max(self) -> float:
        return float(np.max(self.rms))


def _one_run(job: tuple) -> tuple:
    """Worker of ``compare``: one lock-step run, the RMS (mean of both wings) per window."""
    name, mode, seed, duration_s, windows, spec, rig, kp, ki, model_file, controller_params = job
    sc = make_scenario(name, duration_s, rig=rig, seed=seed)
    cfg = rig_config(sc.rig, mode, kp, ki, model_file=model_file)
    res, _ = run_lockstep(sc, mode=mode, spec=spec, config=cfg, controller_params=controller_params, seed=seed)
    out = []
    for lo, hi in windows:
        r = res.compute_rms(t_from=lo, t_to=hi)
        out.append(0.5 * (r["left"] + r["right"]))
    return name, mode, seed, tuple(out)


def compare(scenarios=("random", "gust7", "gust12"), modes=MODES, *, duration_s: float = 30.0,
            windows: tuple[tuple[float, float], ...] | None = None, spec: WingSpec | None = None,
            controller_params: BoucWenParams | None = None, model_file: str = "paper",
            kp: float | None = None, ki: float | None = None, seeds=(0,), rig: Rig | None = None,
            label: str = "", workers: int = 1, progress=None) -> list[CompareRow]:
    """RMS tracking error of every mode on every scenario (lock-step) over ``seeds`` (the reference, the
    gusts and the sensor noise), beside the paper's bench figures; one row per window, scenario and mode.

    ``windows``: stretches of scenario time (s) to score, each from the same runs (default: from the
    ramp-in's end to the end). ``model_file``: the bridge's model ("paper" or a MODEL.json path);
    ``controller_params`` overrides it in the controllers. ``workers`` > 1 runs in that many processes;
    ``progress(done, total)`` after each run."""
    windows = windows or ((SETTLE_S, math.inf),)
    jobs = [(name, mode, seed, duration_s, windows, spec, rig, kp, ki, model_file, controller_params)
            for name in scenarios for mode in modes for seed in seeds]
    results: dict[tuple[str, str, int], tuple[float, ...]] = {}

    def done(r: tuple) -> None:
        name, mode, seed, rms = r
        results[(name, mode, seed)] = rms
        log.info("%s %s seed %d: RMS %s deg", name, mode, seed, ", ".join(f"{x:.3f}" for x in rms))
        if progress is not None:
            progress(len(results), len(jobs))

    if workers > 1 and len(jobs) > 1:
        import concurrent.futures as cf
        import multiprocessing as mp

        with cf.ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn")) as ex:
            for fut in cf.as_completed([ex.submit(_one_run, j) for j in jobs]):
                done(fut.result())
    else:
        for j in jobs:
            done(_one_run(j))
    rows = []
    for k, win in enumerate(windows):
        for name in scenarios:
            for mode in modes:
                rms = tuple(results[(name, mode, seed)][k] for seed in seeds)
                paper = PAPER_BENCH_RMS.get(mode) if name == "random" else None
                rows.append(CompareRow(name, mode, rms, paper, win, label))
    return rows
