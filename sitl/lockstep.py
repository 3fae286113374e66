"""Lock-step SITL: the bridge's mixer and controllers flying the simulated wings, no sockets.

Faster than real time and deterministic. Each control cycle (the bridge's loop
rate, 100 Hz) advances both ``SimWing`` s to the cycle time (their plant
sub-stepped at 1 kHz), takes the FC's latest servo output message (sent at the
configured stream rate, quantised to 1 us with +-1 us jitter, as an autopilot
does), runs it through ``bridge.mixer.Mixer``, reads each flex sensor through
the configured ``hw.calibration.SensorCalibration``, steps each
``bridge.controller.WingController`` and sends the command through the
``hw.calibration.ServoCalibration`` (0.25 us steps) to the wing's servo. The
configuration is the same TOML the real-time run gives the bridge
(``Rig.config_toml``), parsed by ``bridge.config``.

The tracking error is the bridge's setpoint minus the wing's true warp at the
same instant (the cycle's start, before the new command acts), RMS over the
run after a settling time. ``compare`` runs every controller mode on calm and
gusty scenarios and gives the rows of the comparison table.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from bridge.config import Config, WingConfig, parse_config
from bridge.controller import MODES, WingController
from bridge.mixer import Mixer
from hw.calibration import SensorCalibration, ServoCalibration
from model.boucwen import BoucWenParams
from sitl.gust import Gust, GustSpec
from sitl.scenarios import WINGS, Rig, Scenario, make_scenario
from sitl.wing import SimWing, SteadyFlow, WingSpec

log = logging.getLogger(__name__)

SETTLE_S = 1.0  # the scenario's ramp-in; excluded from the RMS
PAPER_BENCH_RMS = {"open": 1.727, "pi": 2.04, "ff+pi": 0.285}  # deg, Lee et al. (2017), sec. 5.2


@dataclass
class RunResult:
    """One lock-step run: per-cycle traces and the RMS tracking error per wing (deg)."""

    scenario: str
    mode: str
    t: np.ndarray
    airspeed: np.ndarray  # at the wing (m/s)
    setpoint: dict[str, np.ndarray]
    warp: dict[str, np.ndarray]  # true warp at the cycle time
    measured: dict[str, np.ndarray]  # what the bridge read
    u_cmd: dict[str, np.ndarray]  # tendon command (mm)
    u: dict[str, np.ndarray]  # tendon travel at the servo (mm)
    rms: dict[str, float] = field(default_factory=dict)

    def compute_rms(self, settle_s: float = SETTLE_S, t_from: float | None = None, t_to: float | None = None,
                    ) -> dict[str, float]:
        """RMS per wing after ``settle_s`` (or over [t_from, t_to] when given)."""
        lo = self.t[0] + settle_s if t_from is None else t_from
        hi = np.inf if t_to is None else t_to
        keep = (self.t >= lo) & (self.t <= hi)
        self.rms = {w: rms_error(self.setpoint[w][keep], self.warp[w][keep]) for w in self.setpoint}
        return self.rms


def rms_error(setpoint: np.ndarray, warp: np.ndarray) -> float:
    """RMS of setpoint - warp over the samples where both are finite (deg)."""
    e = np.asarray(setpoint, float) - np.asarray(warp, float)
    e = e[np.isfinite(e)]
    return float(np.sqrt(np.mean(e * e))) if e.size else math.nan


def rig_config(rig: Rig, mode: str = "ff+pi", kp: float | None = None, ki: float | None = None,
               extra_control: dict[str, float] | None = None) -> Config:
    """The bridge configuration of ``rig`` (the real-time run's TOML), parsed."""
    import tomllib
    from pathlib import Path

    kw = {} if kp is None else {"kp": kp}
    if ki is not None:
        kw["ki"] = ki
    text = rig.config_toml(connection="udpin:127.0.0.1:0", servo_backend="loop:", sensor_backend="loop:",
                           mode=mode, extra_control=extra_control, **kw)
    return parse_config(tomllib.loads(text), Path("."), origin="sitl rig")


def make_controller(wing: WingConfig, params: BoucWenParams, mode: str | None = None) -> WingController:
    """A WingController set up from a wing's configuration, as the bridge does."""
    c = wing.control
    lo, hi = wing.servo.mm_limits
    return WingController(
        params, mode=mode or c.mode, kp=c.kp, ki=c.ki, i_max=c.i_max_mm,
        u_min=lo if c.u_min_mm is None else c.u_min_mm, u_max=hi if c.u_max_mm is None else c.u_max_mm,
        w_max=wing.max_warp_deg, deadband=c.deadband_deg, w0=wing.bias_deg,
    )


def make_wings(scenario: Scenario, spec: WingSpec, w0_deg: float, seed: int = 0, record: bool = False,
               ) -> dict[str, SimWing]:
    """Both simulated wings for a scenario: each in its own realisation of the scenario's flow."""
    wings = {}
    for i, name in enumerate(WINGS):
        if scenario.gust is not None:
            g = scenario.gust
            flow = Gust(GustSpec(g.mean_ms, g.intensity, g.shedding_hz, g.shedding_share, g.shedding_width_hz,
                                 g.length_scale_m, g.buffet_deg_per_kpa, g.seed + 17 * i))
        else:
            flow = SteadyFlow(scenario.airspeed_ms)
        wings[name] = SimWing(spec, flow, w0_deg=w0_deg, seed=seed + 101 * (i + 1), record=record)
    return wings


class FcOutputs:
    """The autopilot's servo output stream: the scenario's PWM sampled at ``rate_hz``,
    rounded to 1 us with a uniform +-``jitter_us`` of noise."""

    def __init__(self, scenario: Scenario, rate_hz: float, jitter_us: float = 1.0, seed: int = 0,
                 phase: float = 0.37) -> None:
        self.scenario = scenario
        self.period = 1.0 / rate_hz
        self.jitter_us = jitter_us
        self._rng = np.random.default_rng(seed)
        self._next = phase * self.period
        self.pwm: dict[int, float] = {}

    def poll(self, t: float) -> dict[int, float]:
        """The latest message's PWM by channel at time t ({} before the first)."""
        while self._next <= t + 1e-12:
            sent = {ch: float(v) for ch, v in self.scenario.pwm_at(self._next).items()}
            j = self._rng.uniform(-self.jitter_us, self.jitter_us, len(sent)) if self.jitter_us > 0 else [0] * len(sent)
            self.pwm = {ch: float(round(v + jj)) for (ch, v), jj in zip(sent.items(), j, strict=True)}
            self._next += self.period
        return self.pwm


def run_lockstep(scenario: Scenario, *, mode: str = "ff+pi", spec: WingSpec | None = None,
                 config: Config | None = None, controller_params: BoucWenParams | None = None,
                 kp: float | None = None, ki: float | None = None, seed: int = 0,
                 record_wings: bool = False) -> tuple[RunResult, dict[str, SimWing]]:
    """Fly ``scenario`` in lock-step with the bridge's mixer and controllers in ``mode``.

    ``spec`` is the simulated wing (default: the paper's plant with the SITL's small aero
    load); ``controller_params`` the model the bridge uses (default: the paper's), so a
    wing that differs from the bridge's model is ``spec.with_effects(...)``."""
    spec = spec or WingSpec()
    cfg = config or rig_config(scenario.rig, mode, kp, ki)
    params = controller_params or BoucWenParams.paper()
    mixer = Mixer(cfg)
    ctl = {w: make_controller(cfg.wings[w], params, mode) for w in WINGS}
    if kp is not None or ki is not None:
        for c in ctl.values():
            c.set_gains(kp=kp, ki=ki)
    scal = {w: ServoCalibration(c.servo.pulse_min_us, c.servo.pulse_max_us, c.servo.pulse_zero_us,
                                c.servo.mm_per_us) for w, c in cfg.wings.items()}
    ical = {w: SensorCalibration(c.sensor.counts, c.sensor.deg) for w, c in cfg.wings.items()}
    w0 = {w: mixer.neutral()[w] for w in WINGS}
    wings = make_wings(scenario, spec, w0_deg=w0["left"], seed=seed, record=record_wings)
    fc = FcOutputs(scenario, cfg.link.servo_rate_hz, seed=seed + 7)

    dt = 1.0 / cfg.loop.rate_hz
    n = int(math.floor(scenario.duration_s / dt)) + 1
    t = np.arange(n) * dt
    tr = {k: {w: np.full(n, np.nan) for w in WINGS} for k in ("sp", "w", "m", "uc", "u")}
    v = np.zeros(n)
    for k in range(n):
        tk = float(t[k])
        for w in WINGS:
            wings[w].advance(tk)
        sp = mixer.setpoints(fc.poll(tk))
        v[k] = wings["left"].airspeed
        for w in WINGS:
            wing = wings[w]
            setpoint = sp[w] if sp[w] is not None else w0[w]
            measured = ical[w].deg_for_counts(wing.read_counts())
            cmd = ctl[w].step(setpoint, measured, dt)
            wing.set_pulse(scal[w].pulse_for_mm(cmd.u_cmd))
            tr["sp"][w][k], tr["w"][w][k], tr["m"][w][k] = setpoint, wing.w_true, measured
            tr["uc"][w][k], tr["u"][w][k] = cmd.u_cmd, wing.u_mm
    res = RunResult(scenario.name, mode, t, v, tr["sp"], tr["w"], tr["m"], tr["uc"], tr["u"])
    res.compute_rms()
    return res, wings


@dataclass(frozen=True)
class CompareRow:
    """One line of the comparison table."""

    scenario: str
    mode: str
    rms_left: float
    rms_right: float
    paper: float | None

    @property
    def rms_mean(self) -> float:
        return 0.5 * (self.rms_left + self.rms_right)


def compare(scenarios=("random", "gust7", "gust12"), modes=MODES, *, duration_s: float = 30.0,
            spec: WingSpec | None = None, controller_params: BoucWenParams | None = None,
            kp: float | None = None, ki: float | None = None, seed: int = 0, rig: Rig | None = None,
            progress=None) -> list[CompareRow]:
    """RMS tracking error of every mode on every scenario (lock-step), beside the paper's bench figures."""
    rows = []
    for name in scenarios:
        sc = make_scenario(name, duration_s, rig=rig, seed=seed)
        for mode in modes:
            res, _ = run_lockstep(sc, mode=mode, spec=spec, controller_params=controller_params, kp=kp, ki=ki,
                                  seed=seed)
            paper = PAPER_BENCH_RMS.get(mode) if name == "random" else None
            rows.append(CompareRow(name, mode, res.rms["left"], res.rms["right"], paper))
            log.info("%s %s: RMS left %.3f right %.3f deg", name, mode, res.rms["left"], res.rms["right"])
            if progress is not None:
                progress(rows[-1])
    return rows
