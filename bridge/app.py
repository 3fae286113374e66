"""The running bridge: link -> mixer -> controller per wing -> servo, sensor back in, taps on the side.

``Bridge(config)`` owns every part; ``tick()`` runs one control cycle:
``link.poll()`` (non-blocking) and the parameter server, the mixer turns the FC's
aileron PWM into a warp setpoint per wing, the sensor counts become degrees,
each ``WingController`` gives a tendon travel, the servo calibration a pulse,
and telemetry and the cycle log take their copies. The link can be handed in
(``Bridge(config, link=...)``: anything with ``FcLink``'s interface, e.g. the
lock-step SITL's), as can the servo and sensor objects.

``run_bridge(config)`` runs ticks at the loop rate with absolute deadlines until
stopped; with ``[loop] wake_on_message`` (default) it also runs a cycle as soon
as anything arrives on the link between two ticks, so a servo message reaches
the servo without waiting for the next tick. The fixed-rate ticks happen
regardless, so the failsafe timer and the telemetry never depend on the FC.
The controller integrates over the real time between cycles.

Failsafes (each reported once by STATUSTEXT when the link can carry it, cleared
when over): no servo message yet, or none for ``WB_FS_TMO`` s -> every wing to
its neutral warp (bias); a wing's PWM invalid for that long -> that wing to
neutral; sensor missing, outside its calibration table or frozen (same raw
reading for ``sensor_frozen_s`` while the command moves) -> that wing on
feed-forward only, integrator held; servo port lost -> keep running, reopen with
back-off; servo board error bits (Maestro Get Errors, FC refusing DO_SET_SERVO /
DO_SET_ACTUATOR) -> one STATUSTEXT until the board reports no error again. No
subsystem's exception stops the loop.
"""

from __future__ import annotations

import logging
import math
import select
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from warpbridge.bridge.calibrate import FieldTuning
from warpbridge.bridge.config import WINGS, Config, WingConfig, backend_has_sensor
from warpbridge.bridge.controller import MODES, WingController
from warpbridge.bridge.cyclelog import CycleLog
from warpbridge.bridge.errors import UserError
from warpbridge.bridge.link import FcLink
from warpbridge.bridge.loop_timer import LoopTimer, TimerStats
from warpbridge.bridge.mavlink_env import mavlink
from warpbridge.bridge.mixer import Mixer
from warpbridge.bridge.outputcheck import OutputFunctionCheck, SourceWatch, Verdict
from warpbridge.bridge.param_server import ParamServer
from warpbridge.bridge.params import ParamSpec, ParamStore
from warpbridge.bridge.signing import policy_from_config
from warpbridge.bridge.startup import (
    load_model,
    load_model_file,
    servo_calibration,
    servo_limits,
    tendon_limits,
)
from warpbridge.bridge.telemetry import MODE_CODES, Telemetry
from warpbridge.hw import DeviceError, open_sensor, open_servo, sensor_on_servo_port
from warpbridge.hw.calibration import SensorCalibration, ServoCalibration
from warpbridge.model.boucwen import BoucWenParams
from warpbridge.model.effects import core_params
from warpbridge.model.initial_state import algebraic_z0

log = logging.getLogger(__name__)

SEV_CRITICAL, SEV_ERROR, SEV_WARNING, SEV_NOTICE, SEV_INFO = (
    mavlink.MAV_SEVERITY_CRITICAL, mavlink.MAV_SEVERITY_ERROR, mavlink.MAV_SEVERITY_WARNING,
    mavlink.MAV_SEVERITY_NOTICE, mavlink.MAV_SEVERITY_INFO)
SERVO_BACKOFF_S = (0.5, 1.0, 2.0, 4.0, 8.0)
SENSOR_MOVE_MM = 0.3  # the command must move this much for an unchanged reading to count as frozen
ERROR_POLL_S = 1.0
DT_MAX_S = 0.1  # the controller never integrates over a longer gap than this
DISARMED_MARGIN_US = 50.0  # disarmed, an output this far below pwm_min is the FC's disarmed value
ACK_COMMANDS = (mavlink.MAV_CMD_DO_SET_SERVO, mavlink.MAV_CMD_DO_SET_ACTUATOR)
TAG = {"left": "L", "right": "R"}
# the model parameters in MAVLink order: WB_BW_<suffix> -> BoucWenParams field (b as B1..B6)
BW_FIELDS = ("A1", "A2", "A3", "AZ", "A", "N", "B1", "B2", "B3", "B4", "B5", "B6")
SENSOR_MODES = ("pi", "ff+pi")  # modes that close the loop on the warp sensor
__all__ = ["Bridge", "RunResult", "load_model", "load_model_file", "run_bridge", "servo_limits"]


def _bw_values(p: BoucWenParams) -> list[float]:
    return [p.a1, p.a2, p.a3, p.az, p.A, p.n, *p.b]


def param_specs(config: Config, model: BoucWenParams, apply: Callable[[str, float], None]) -> list[ParamSpec]:
    """The WB_* parameters; defaults come from the config (left wing) and the model file.

    Once set (persisted value differs from the default) a parameter applies to both wings."""
    c, w = config.left.control, config.left

    def spec(name: str, default: float, lo: float, hi: float, doc: str, integer: bool = False) -> ParamSpec:
        return ParamSpec(name, default, min(lo, default), max(hi, default), doc, integer, apply)

    specs = [
        spec("WB_MODE", MODES.index(c.mode), 0, 3, "control mode: 0 open, 1 pi, 2 ff, 3 ff+pi", True),
        spec("WB_KP", c.kp, 0.0, 50.0, "PI proportional gain, mm of tendon per deg of warp error"),
        spec("WB_KI", c.ki, 0.0, 50.0, "PI integral gain, mm of tendon per deg*s of warp error"),
        spec("WB_I_MAX", c.i_max_mm, 0.0, 20.0, "integrator limit in ff+pi (trim authority), mm"),
        spec("WB_MAXWARP", w.max_warp_deg, 0.5, 30.0, "warp at full aileron, deg"),
        spec("WB_BIAS", w.bias_deg, 0.0, 30.0, "pre-warp held at neutral aileron (capped at WB_MAXWARP), deg"),
        spec("WB_TLM_HZ", config.telemetry_rate_hz, 0.0, 50.0, "NAMED_VALUE_FLOAT rate per value, Hz; 0 off"),
        spec("WB_FS_TMO", config.loop.failsafe_timeout_s, 0.05, 10.0,
             "no servo message for this long -> neutral warp, s"),
        spec("WB_SRV_HZ", config.link.servo_rate_hz, 1.0, 400.0, "servo output message rate asked of the FC, Hz"),
    ]
    bw_doc = {"A1": "a1, mm/deg^2", "A2": "a2, mm/deg", "A3": "a3, mm", "AZ": "az, mm per unit z",
              "A": "A, z per deg", "N": "exponent n (>= 1)"}
    for suffix, v in zip(BW_FIELDS, _bw_values(model), strict=True):
        lo, hi = (1.0, 10.0) if suffix == "N" else (-1000.0, 1000.0)
        doc = bw_doc[suffix] if suffix in bw_doc else f"beta{suffix[1:]}, z^(1-n) per deg"
        specs.append(spec(f"WB_BW_{suffix}", v, lo, hi, f"Bouc-Wen model {doc}"))
    return specs


@dataclass
class WingState:
    """What the app tracks per wing between cycles."""

    cfg: WingConfig
    ctl: WingController
    servo_cal: ServoCalibration
    sensor_cal: SensorCalibration | None
    setpoint: float = 0.0
    pwm_time: float | None = None  # last time this wing's PWM was valid
    raw_last: float | None = None  # sensor: last raw reading, when it changed, command then
    raw_since: float = 0.0
    u_at_change: float = 0.0
    frozen: bool = False  # latched until the raw reading changes (a frozen sensor does not flap)
    last: dict[str, float | None] = field(default_factory=dict)


@dataclass
class RunResult:
    cycles: int
    timer: TimerStats | None
    failsafe_entries: int
    log_path: str | None


class Bridge:
    """All parts of the running bridge; ``tick()`` is one control cycle."""

    def __init__(self, config: Config, *, servo: Any = None, sensor: Any = None, link: Any = None,
                 clock: Callable[[], float] = time.monotonic, connect_timeout: float = 0.0,
                 opened_servo: Any = None) -> None:
        """``servo``/``sensor``/``link`` replace the configured ones (the caller keeps owning them);
        ``opened_servo`` is the configured servo backend already open (``startup.command_neutral``),
        handed over to the bridge, which then owns it."""
        self.config, self.clock = config, clock
        self._starting = True
        model_file = load_model_file(config)
        self.model = core_params(model_file.params, model_file.effects)
        self.ff_effects = model_file.effects.only(("aero_load", "backlash", "friction", "servo_lag"))  # per step
        self.has_sensor = backend_has_sensor(config.sensor_backend) or sensor is not None
        self.fs_timeout = config.loop.failsafe_timeout_s
        self.dt = 1.0 / config.loop.rate_hz
        self._owns_link = link is None
        if link is None:
            link = FcLink(config.link.connection, servo_rate_hz=config.link.servo_rate_hz,
                          rerequest_s=config.link.rerequest_s, source_system=config.link.source_system,
                          signing=policy_from_config(config.link), clock=clock)
        self.link = link
        self.telemetry = Telemetry(self.link, config.telemetry_rate_hz, clock=clock)
        self.mixer = Mixer(config.wings)
        self.wings: dict[str, WingState] = {}
        self._sensor_keys: dict[str, set[str]] = {}  # each wing's sensor faults' status keys since it was good
        for name in WINGS:
            wc = config.wings[name]
            scal = servo_calibration(wc)
            try:
                ecal = SensorCalibration(wc.sensor.counts, wc.sensor.deg) if wc.sensor_channel is not None else None
            except ValueError as e:
                raise UserError(f"[wing.{name}] calibration: {e}") from None
            c = wc.control
            u_min, u_max = tendon_limits(wc)
            ctl = WingController(self.model, mode=c.mode, kp=c.kp, ki=c.ki, i_max=c.i_max_mm,
                                 u_min=u_min, u_max=u_max, w_max=wc.max_warp_deg,
                                 deadband=self._deadband(name), w0=self.mixer.wings[name].neutral_deg)
            ctl.set_effects(self.ff_effects)
            self.wings[name] = WingState(wc, ctl, scal, ecal, setpoint=self.mixer.wings[name].neutral_deg)
        self.servo, self.sensor = servo, sensor
        self._owns_devices = servo is None
        self.log = None
        channels = {name: w.cfg.source_channel for name, w in self.wings.items()}
        self.outputs = OutputFunctionCheck(self.link, channels)
        self.watch = SourceWatch(channels, on_still=self._source_still)
        self.tuning = FieldTuning(
            self.wings, self.link, self.telemetry, base_model=lambda: self.model, params_file=config.params_file,
            clock=clock, loop_hz=config.loop.rate_hz, allowed_gcs=config.link.gcs_sysid_allow,
            has_sensor=lambda n: self.has_sensor and self.wings[n].sensor_cal is not None,
            max_warp=lambda n: self.mixer.wings[n].max_warp_deg)
        for name, w in self.wings.items():  # each wing flies its own calibration of the model
            w.ctl.set_model(self.tuning.wing_model(name))
        self.store = ParamStore(param_specs(config, self.model, self._apply_param)
                                + self.tuning.param_specs(self._apply_param), config.params_file)
        try:
            self.params = ParamServer(self.store, self.link, allowed_gcs=config.link.gcs_sysid_allow, clock=clock)
            stored = []
            for name in self.store.names:  # values set earlier over MAVLink override the config
                if self.store.get(name) != self.store.specs[name].default:
                    self._apply_param(name, self.store.get(name))
                    was = self.store.specs[name].default
                    stored.append(f"{name} {self.store.get(name):.4g} (configured {was:.4g})")
            if stored:
                log.info("parameters set earlier (%s) override the configuration: %s", config.params_file,
                         ", ".join(stored))
            self.tuning.attach(self.store, lambda n: self.params.send_value(self.store.index(n)))
            if connect_timeout > 0:
                self.link.connect(connect_timeout)
            self._servo_down_since: float | None = None
            self._servo_lost_text = ""  # the STATUSTEXT while it is down (raised again until the link carries it)
            self._servo_retry_at = 0.0
            self._servo_tries = 0
            if servo is None:
                self._open_devices(initial=True, opened=opened_servo)
            self.log = CycleLog(config.loop.log) if config.loop.log is not None else None
        except BaseException:
            if opened_servo is not None and self.servo is None:
                opened_servo.close()
            self.close()
            raise
        self._start_from_sensor()
        self._starting = False
        self._announced = False
        self._mode_ran: dict[str, str] = {}
        self.start = clock()
        self.failsafe = True  # until the first servo message
        self.failsafe_entries = 0
        self._fs_since = self.start  # when the current failsafe began
        self._parked: set[str] = set()  # wings held neutral on the FC's disarmed output value
        self.cycles = 0
        self._last_tick: float | None = None
        self._next_error_poll = 0.0
        self._load_report = self.store.load_report  # sent once the link can carry it

    def _deadband(self, name: str) -> float:
        """The wing's setpoint play: +-``pwm_jitter_us`` through its deg-per-us scaling."""
        return self.mixer.wings[name].jitter_deadband(self.config.link.pwm_jitter_us)

    # ------------------------------------------------------------------ devices

    def _open_devices(self, initial: bool = False, opened: Any = None) -> None:
        cfg = self.config
        try:
            self.servo = opened if opened is not None else open_servo(
                cfg.servo_backend, mavlink_sender=self.link, limits=servo_limits(cfg),
                **({"target_system": self.link.system_id or 1} if is_fc_backend(cfg.servo_backend) else {}))
        except ValueError as e:
            raise UserError(f"[servo] backend: {e}") from None
        except DeviceError as e:
            if not initial:
                raise
            self._servo_lost(e)
        try:
            if not initial and self.sensor is not None and not sensor_on_servo_port(cfg.sensor_backend,
                                                                                    cfg.servo_backend):
                return  # a sensor on its own device stayed open while the servo was away
            if self.servo is None and sensor_on_servo_port(cfg.sensor_backend, cfg.servo_backend):
                # the sensor is read on the servo's Maestro: it comes back with it (``_servo_retry``)
                log.warning("sensor: on the servo's Maestro, which is not open; feed-forward only until it returns")
                self.sensor = None
                return
            self.sensor = open_sensor(cfg.sensor_backend, shared_servo=self.servo)
        except ValueError as e:
            raise UserError(f"[sensor] backend: {e}") from None
        except DeviceError as e:
            log.warning("sensor: %s; running feed-forward only until it returns", e)
            self.sensor = None

    def _servo_lost(self, e: Exception) -> None:
        now = self.clock()
        if self._servo_down_since is None:
            self._servo_down_since = now
            self._servo_tries = 0
            self._servo_lost_text = f"WB servo lost: {e}"[:100]
            self.telemetry.status(SEV_CRITICAL, self._servo_lost_text, key="servo")
        delay = SERVO_BACKOFF_S[min(self._servo_tries, len(SERVO_BACKOFF_S) - 1)]
        self._servo_tries += 1
        self._servo_retry_at = now + delay

    def _servo_retry(self, now: float) -> None:
        # lost before the link could carry it (a board absent at start): sent once it can (keyed: once)
        self.telemetry.status(SEV_CRITICAL, self._servo_lost_text, key="servo")
        if now < self._servo_retry_at:
            return
        try:
            reopen = getattr(self.servo, "reopen", None)
            if self.servo is not None and reopen is not None:
                reopen()
            else:
                self._open_devices()
        except DeviceError as e:
            self._servo_lost(e)
            return
        log.warning("servo output back after %.1f s", now - (self._servo_down_since or now))
        self._servo_down_since = None
        self.telemetry.clear("servo")
        self.telemetry.status(SEV_NOTICE, "WB servo output back")

    # ------------------------------------------------------------------ parameters

    def _apply_param(self, name: str, v: float) -> None:
        """Apply a WB_* value live to both wings (raises ValueError to refuse it)."""
        ctls = [w.ctl for w in self.wings.values()]
        if name == "WB_MODE":
            mode = MODES[int(v)]
            blind = [n for n in self.wings if not self._wing_has_sensor(n)]
            if mode in SENSOR_MODES and len(blind) == len(self.wings) and not self._starting:
                raise ValueError(f"{mode} needs a warp sensor and none is configured; mode stays "
                                 f"{ctls[0].mode}")
            for c in ctls:
                c.set_mode(mode)
            if not self._starting:
                self.telemetry.status(SEV_INFO, f"WB mode {mode}{self._mode_note(mode)}")
                log.info("mode %s asked%s", mode, self._mode_note(mode))
        elif name in ("WB_KP", "WB_KI", "WB_I_MAX"):
            key = {"WB_KP": "kp", "WB_KI": "ki", "WB_I_MAX": "i_max"}[name]
            for c in ctls:
                c.set_gains(**{key: v})
        elif name in ("WB_MAXWARP", "WB_BIAS"):
            self.mixer.retune(**{"WB_MAXWARP": {"max_warp_deg": v}, "WB_BIAS": {"bias_deg": v}}[name])
            for wname, w in self.wings.items():
                w.ctl.set_model(self.tuning.wing_model(wname), w_max=self.mixer.wings[wname].max_warp_deg)
                w.ctl.set_deadband(self._deadband(wname))
            if not self._starting:  # a bias above the range is held at its top: the wing holds full warp
                asked = v if name == "WB_BIAS" else self.store.get("WB_BIAS")
                held = max(m.bias_deg for m in self.mixer.wings.values())
                if held < asked - 1e-6:
                    self.telemetry.status(SEV_NOTICE, f"WB bias {asked:g} capped at WB_MAXWARP {held:g} deg")
        elif name == "WB_TLM_HZ":
            self.telemetry.rate_hz = v
            self.telemetry.period = 1.0 / v if v > 0 else math.inf
        elif name == "WB_FS_TMO":
            self.fs_timeout = v
        elif name == "WB_SRV_HZ":
            self.link.set_servo_rate(v)  # asks the FC at once (both messages on PX4)
        elif name.startswith("WB_BW_"):
            vals = dict(zip(BW_FIELDS, _bw_values(self.model), strict=True))
            vals[name[len("WB_BW_"):]] = v
            p = [vals[k] for k in BW_FIELDS]
            model = BoucWenParams(a1=p[0], a2=p[1], a3=p[2], az=p[3], A=p[4], n=p[5], b=tuple(p[6:]))
            self.model = model
            self.tuning.base_changed()  # each wing: its calibration applied to the new base model
        elif FieldTuning.owns(name):
            self.tuning.apply_param(name, v)

    # ------------------------------------------------------------------ what runs, and telling the user

    def _wing_has_sensor(self, name: str) -> bool:
        """Whether the wing has a warp sensor configured (a working one or not)."""
        return self.has_sensor and self.wings[name].sensor_cal is not None

    def _mode_note(self, mode: str) -> str:
        """``""`` when every wing can run ``mode``; else what runs instead, e.g. ``" (ff runs: no sensor)"``."""
        if mode not in SENSOR_MODES:
            return ""
        blind = [n for n in self.wings if not self._wing_has_sensor(n)]
        if not blind:
            return ""
        if len(blind) == len(self.wings):
            return " (ff runs: no sensor)"
        return f" ({', '.join(blind)}: ff, no sensor)"

    def _start_from_sensor(self) -> None:
        """With a sensor, start each wing's feed-forward state where the wing is: the measured warp and the
        tendon position give the hysteretic state algebraically (``model.initial_state.algebraic_z0``)."""
        for name, w in self.wings.items():
            if not self._wing_has_sensor(name) or self.sensor is None or self.servo is None:
                continue
            try:
                raw = self.sensor.read_counts(w.cfg.sensor_channel)
                pulse = tendon_pulse(self.servo, w.cfg.servo_channel)
                if raw is None or pulse is None or not math.isfinite(raw):
                    log.info("%s wing: feed-forward starts at rest (no %s to start from)", name,
                             "sensor reading" if raw is None else "tendon position")
                    continue
                lo, hi = min(w.sensor_cal.counts), max(w.sensor_cal.counts)
                if not lo <= raw <= hi:
                    log.warning("%s wing: sensor reading %g outside its calibration; feed-forward starts at rest",
                                name, raw)
                    continue
                warp = self.tuning.measurement(name, w.sensor_cal.deg_for_counts(raw))
                u = w.servo_cal.mm_for_pulse(pulse)
                est = self.tuning.est[name].estimate  # the model flies under the pre-tension estimate
                u_model = (u - est.offset) * est.gain
                z0 = algebraic_z0(self.tuning.wing_model(name), [u_model], [warp])
                w.ctl.start_state(warp, z0)
                log.info("%s wing: feed-forward starts from the measured warp %.2f deg at tendon %.2f mm "
                         "(pulse %.0f us): z0 = %.3f", name, warp, u, pulse, z0)
            except Exception as e:  # noqa: BLE001 - a device that fails here is handled by the cycle
                log.warning("%s wing: cannot read the start state (%s); feed-forward starts at rest", name, e)

    def _announce(self) -> None:
        """Once the link can carry them: the start message, and what runs when a mode needs a missing sensor."""
        if self._announced:
            return
        mode = next(iter(self.wings.values())).ctl.mode
        note = self._mode_note(mode)
        sensor = self.config.sensor_backend.split(":")[0] if self.has_sensor else "no sensor"
        text = f"WB started: {mode}{note}, {sensor}, {self.config.loop.rate_hz:g} Hz"
        if self.telemetry.status(SEV_INFO, text, key="start"):
            self._announced = True
            if note:
                self.telemetry.status(SEV_WARNING, f"WB mode {mode} needs a warp sensor{note}", key="mode-sensor")

    def _report_outputs(self, verdicts: list[Verdict]) -> None:
        """The FC's answer about each wing's source output: logged, and a STATUSTEXT unless it is an aileron."""
        for v in verdicts:
            key = f"out-{v.wing}"
            self.telemetry.clear(key)
            if v.kind == "aileron":
                log.info("%s", v.text())
                continue
            log.warning("%s", v.text())
            self.telemetry.status(SEV_NOTICE if v.kind == "mixed" else SEV_WARNING, v.status(), key=key,
                                  log_it=False)

    def _source_still(self, wing: str, channel: int, pwm: float, seconds: float) -> None:
        log.warning("%s wing: FC output %d has not moved (%.0f us) in %.0f s of armed flight: "
                    "is it the aileron output?", wing, channel, pwm, seconds)
        self.telemetry.status(SEV_WARNING, f"WB {TAG[wing]} out {channel} still {seconds:.0f} s in flight: "
                                           f"aileron?", key=f"still-{wing}", log_it=False)

    # ------------------------------------------------------------------ the cycle

    def _measure(self, name: str, w: WingState, now: float) -> float | None:
        """The wing's warp (deg) or None, with missing / out-of-range / frozen reported once."""
        problem, kind, raw = None, None, None
        if w.sensor_cal is None or w.cfg.sensor_channel is None or not self.has_sensor:
            return None
        if self.sensor is None:
            problem = "no sensor"
        else:
            try:
                raw = self.sensor.read_counts(w.cfg.sensor_channel)
            except DeviceError as e:
                problem = f"read failed ({e})"
        if problem is None:
            lo, hi = min(w.sensor_cal.counts), max(w.sensor_cal.counts)
            if raw is None or not math.isfinite(raw):
                problem = "no reading"
            elif not lo <= raw <= hi:
                problem, kind = f"reading {raw:g} out of range", "out of range"
            elif raw != w.raw_last:
                w.raw_last, w.raw_since, w.u_at_change = raw, now, w.ctl.last_u
                w.frozen = False
            elif w.frozen or (now - w.raw_since > self.config.loop.sensor_frozen_s and
                              abs((w.ctl.last_u) - w.u_at_change) > SENSOR_MOVE_MM):
                w.frozen = True
                problem = "frozen"
        # one key per kind of fault: the same fault flapping is held off, another kind is said at once
        back = f"sensor-back-{name}"
        if problem is not None:
            key = f"sensor-{name}-{kind or problem.split(' (')[0]}"
            self._sensor_keys.setdefault(name, set()).add(key)
            self.telemetry.clear(back)
            self.telemetry.status(SEV_WARNING, f"WB {name} sensor {problem}: ff only", key=key)
            return None
        keys = self._sensor_keys.pop(name, ())  # the control loop's path: nothing built when the sensor is good
        if any(self.telemetry.active(k) for k in keys):
            # keyed too, so a flapping sensor reports "back" at most once per key hold-off
            for k in keys:
                self.telemetry.clear(k)
            self.telemetry.status(SEV_NOTICE, f"WB {name} sensor back", key=back)
        return w.sensor_cal.deg_for_counts(raw)

    def _disarmed_values(self, link: FcLink) -> set[str]:
        """Wings whose aileron output sits below its flying range while the FC is disarmed: that is the
        output's disarmed value (PX4 sends PWM_MAIN_DISn, 900 us by default, on every output until it arms),
        which would read as full aileron; such a wing holds its neutral warp. Logged when it starts and ends."""
        parked = set()
        if not link.armed:
            for name, w in self.wings.items():
                pwm = link.servo_pwm.get(w.cfg.source_channel)
                if pwm is not None and pwm < w.cfg.pwm_min - DISARMED_MARGIN_US:
                    parked.add(name)
        if parked != self._parked:
            for name in sorted(parked - self._parked):
                log.info("%s wing: FC disarmed and output %d at %.0f us, below its range: its disarmed value, "
                         "wing neutral", name, self.wings[name].cfg.source_channel,
                         link.servo_pwm[self.wings[name].cfg.source_channel])
            for name in sorted(self._parked - parked):
                log.info("%s wing: following output %d again", name, self.wings[name].cfg.source_channel)
            self._parked = parked
        return parked

    def _setpoints(self, now: float) -> dict[str, float]:
        link = self.link
        silent = link.servo_time is None or now - link.servo_time > self.fs_timeout
        if silent and not self.failsafe:
            self.failsafe_entries += 1
            self._fs_since = now
        if not silent and self.failsafe:
            log.info("servo outputs from the FC %s after %.1f s: following the FC",
                     "back" if self.failsafe_entries else "arrived", now - self._fs_since)
            for key in ("fs-start", "fs"):
                if self.telemetry.active(key):
                    self.telemetry.clear(key)
                    self.telemetry.status(SEV_NOTICE, "WB servo outputs back, following FC", log_it=False)
        self.failsafe = silent
        neutral = self.mixer.neutral()
        if silent:  # keyed: sent once, as soon as the link knows the FC (retried until then)
            if link.servo_time is None:
                self.telemetry.status(SEV_WARNING, "WB failsafe: no servo outputs yet, wings neutral", key="fs-start")
            else:
                self.telemetry.status(SEV_CRITICAL, "WB failsafe: no servo outputs, wings neutral", key="fs")
            return neutral
        out = {}
        parked = self._disarmed_values(link)
        for name, sp in self.mixer.setpoints(link.servo_pwm).items():
            w = self.wings[name]
            if name in parked:  # the FC's disarmed value, not an aileron command
                w.pwm_time, w.setpoint = now, neutral[name]
            elif sp is not None:
                w.pwm_time, w.setpoint = now, sp
            elif w.pwm_time is None or now - w.pwm_time > self.fs_timeout:
                w.setpoint = neutral[name]  # invalid for too long: neutral; briefly: hold the last
            out[name] = w.setpoint
        return out

    def _fc_servo_sync(self) -> None:
        """``fc:`` servo backend: follow the FC's system id and autopilot, hand it the FC's ACKs."""
        servo, link = self.servo, self.link
        if servo is None or not is_fc_backend(self.config.servo_backend):
            return
        if link.system_id is not None and getattr(servo, "target_system", None) != link.system_id:
            servo.target_system = link.system_id
        if self.config.servo_backend.strip().lower() == "fc:" and link.autopilot in ("ardupilot", "px4") \
                and getattr(servo, "autopilot", None) != link.autopilot:
            log.info("fc servo outputs: autopilot is %s", link.autopilot)
            servo.autopilot = link.autopilot
        handle_ack = getattr(servo, "handle_ack", None)
        acks = getattr(link, "acks", None)
        if handle_ack is None or acks is None:
            return
        for command in ACK_COMMANDS:
            result = acks.pop(command, None)
            if result is not None:
                handle_ack(mavlink.MAVLink_command_ack_message(command, result))

    def tick(self) -> None:
        """One control cycle; catches and reports every subsystem's failure."""
        now = self.clock()
        dt = self.dt if self._last_tick is None else min(max(now - self._last_tick, 0.0), DT_MAX_S)
        self._last_tick = now
        self.cycles += 1
        try:
            messages, verdicts = self.outputs.take(self.link.poll(), now)
            self.params.poll(self.tuning.handle_messages(messages))
            self._fc_servo_sync()
            self._report_outputs(verdicts)
            self._announce()
        except Exception:  # noqa: BLE001 - the link or a GCS request must not stop the loop
            log.exception("link/parameter handling failed")
        if self._load_report and self.telemetry.status(SEV_WARNING, self._load_report, key="params-load"):
            self._load_report = None
        try:
            setpoints = self._setpoints(now)
        except Exception:  # noqa: BLE001
            log.exception("mixer failed; wings neutral")
            setpoints = self.mixer.neutral()
        if self._servo_down_since is not None:
            self._servo_retry(now)
        if not self.failsafe:
            self.watch.update(self.link.servo_pwm, self.link.armed, self.link.airspeed, dt)
        rows: dict[str, dict[str, float | None]] = {}
        modes = []
        t_read = self.clock()  # the log's time: the sensors' reads, after the link's messages however long they took
        for name, w in self.wings.items():
            row: dict[str, float | None] = {"setpoint": setpoints[name]}
            try:
                t_ask = self.clock()
                measured = self._measure(name, w, now)
                if measured is not None:  # the read's middle: when in its round trip the sensor was sampled is unknown
                    row["read"] = 0.5 * (t_ask + self.clock()) - t_read
                sp = row["setpoint"] = self.tuning.setpoint(name, now, setpoints[name])  # calibration excitation
                self.tuning.before_step(name)  # pre-tension estimate into the feed-forward
                cmd = w.ctl.step(sp, self.tuning.measurement(name, measured), dt, airspeed=self.link.airspeed)
                self.tuning.after_step(name, now, cmd.u_cmd, measured, dt)
                pulse = w.servo_cal.pulse_for_mm(cmd.u_cmd)
                row.update(ff=cmd.ff, pi=cmd.pi, u=cmd.u_cmd, warp=measured, pulse=pulse)
                modes.append(cmd.mode)
                if self._mode_ran.get(name) != cmd.mode:
                    if name in self._mode_ran or cmd.mode != w.ctl.mode:
                        log.info("%s wing runs %s%s", name, cmd.mode,
                                 "" if cmd.mode == w.ctl.mode else f" ({w.ctl.mode} asked)")
                    self._mode_ran[name] = cmd.mode
                if self._servo_down_since is None and self.servo is not None:
                    self.servo.set_pulse(w.cfg.servo_channel, pulse)
                    row["u_sent"] = self.clock() - t_read  # when the command left, for a model of the servo
            except DeviceError as e:
                self._servo_lost(e)
            except Exception:  # noqa: BLE001
                log.exception("%s wing cycle failed", name)
            rows[name] = row
            w.last = row
        try:
            self.tuning.poll(now)  # calibration interlock, progress and results; adaptation telemetry
        except Exception:  # noqa: BLE001
            log.exception("field tuning failed")
        mode = "failsafe" if self.failsafe else ("/".join(dict.fromkeys(modes)) or "none")
        self._taps(now, mode, rows, t_read)

    def _mode_code(self, mode: str) -> float:
        """``WB_mode``: what runs. When the wings differ, the mode a wing fell back to (e.g. ff for a wing
        that lost its sensor), since that is what limits the aircraft."""
        if mode in MODE_CODES:
            return MODE_CODES[mode]
        asked = next(iter(self.wings.values())).ctl.mode
        ran = [m for m in mode.split("/") if m != asked] or [asked]
        return MODE_CODES.get(ran[0], -1.0)

    def _taps(self, now: float, mode: str, rows: dict[str, dict[str, float | None]], t_read: float) -> None:
        try:
            t = self.telemetry
            for name, r in rows.items():
                for key, field_ in (("sp", "setpoint"), ("warp", "warp"), ("cmd", "u"), ("ff", "ff"),
                                    ("pi", "pi")):
                    v = r.get(field_)
                    if v is not None and math.isfinite(v):
                        t.named_float(f"{TAG[name]}_{key}", v)
            t.named_float("WB_mode", self._mode_code(mode))
            if self.link.airspeed is not None:
                t.named_float("WB_aspd", self.link.airspeed)
            if self.link.servo_time is not None:
                t.named_float("WB_lat", 1000.0 * max(0.0, self.clock() - self.link.servo_time))
        except Exception:  # noqa: BLE001
            log.exception("telemetry failed")
        try:
            self.telemetry.poll()  # every cycle: values held back by the rate limit go out when due
            if now >= self._next_error_poll and self._servo_down_since is None and self.servo is not None:
                self._next_error_poll = now + ERROR_POLL_S
                self._poll_servo_errors()
        except DeviceError as e:
            self._servo_lost(e)
        except Exception:  # noqa: BLE001
            log.exception("telemetry failed")
        if self.log is not None:
            try:
                self.log.write(t_read - self.start, mode, self.link.airspeed, rows,
                               fc_t=getattr(self.link, "servo_fc_time", None))
            except Exception:  # noqa: BLE001
                log.exception("cycle log write failed; logging stopped")
                self.log = None

    def _poll_servo_errors(self) -> None:
        """Board error bits -> one STATUSTEXT per episode (until a poll reads no error)."""
        bits = self.servo.poll_errors()
        if bits:
            names = ", ".join(self.servo.error_names(bits))
            self.telemetry.status(SEV_ERROR, f"WB servo board error: {names}"[:100], key="servo-err")
        elif self.telemetry.active("servo-err"):
            self.telemetry.clear("servo-err")
            self.telemetry.status(SEV_NOTICE, "WB servo board error cleared")

    def link_fd(self) -> int | None:
        """File descriptor that becomes readable when the FC sends something (None if unknown)."""
        fd = getattr(getattr(self.link, "mav", None), "fd", None)
        return fd if isinstance(fd, int) and fd >= 0 else None

    def close(self) -> None:
        """Close the log, the parameter store (writes the last change), our devices and our link."""
        owned = self._owns_devices
        for what, fn in (("log", self.log.close if self.log else None), ("params", self.store.close),
                         ("servo", self.servo.close if owned and self.servo else None),
                         ("sensor", self.sensor.close if owned and self.sensor else None),
                         ("link", self.link.close if self._owns_link else None)):
            if fn is None:
                continue
            try:
                fn()
            except Exception:  # noqa: BLE001
                log.exception("closing %s failed", what)


def tendon_pulse(servo: Any, channel: int) -> float | None:
    """The pulse (us) the servo backend is sending on ``channel`` now (Maestro Get Position, the loop
    backend's last pulse), or None when the backend cannot tell."""
    for name in ("read_pulse", "pulse"):
        fn = getattr(servo, name, None)
        if callable(fn):
            v = fn(channel)
            return float(v) if v is not None and math.isfinite(v) and v > 0 else None
    return None


def is_fc_backend(spec: str) -> bool:
    """Whether a ``[servo] backend`` string drives the FC's own outputs (``fc:...``)."""
    return spec.strip().lower().startswith("fc:")


def _waiter(bridge: Bridge, wake: bool) -> Callable[[float], None]:
    """The loop timer's sleep: with ``wake``, run a cycle whenever the link becomes readable."""
    if not wake:
        return time.sleep

    def wait(delay: float) -> None:
        end = time.monotonic() + delay
        while (left := end - time.monotonic()) > 0:
            fd = bridge.link_fd()
            if fd is None:
                time.sleep(min(left, 0.005))  # link closed (reconnecting): check again soon
                continue
            try:
                ready, _, _ = select.select([fd], [], [], left)
            except (OSError, ValueError):  # closed under us: the next tick reconnects
                time.sleep(min(left, 0.005))
                continue
            if ready:
                bridge.tick()
    return wait


def run_bridge(config: Config, stop_event: threading.Event | None = None, duration: float | None = None,
               *, servo: Any = None, sensor: Any = None, link: Any = None, opened_servo: Any = None) -> RunResult:
    """Run the bridge at the loop rate until ``stop_event`` is set or ``duration`` s have passed.

    ``servo``/``sensor``/``link`` replace the configured ones (tests, SITL); ``opened_servo`` is the
    configured servo backend, already open (the bridge owns it)."""
    bridge = Bridge(config, servo=servo, sensor=sensor, link=link, opened_servo=opened_servo)
    timer = LoopTimer(config.loop.rate_hz, sleep=_waiter(bridge, config.loop.wake_on_message))
    w = next(iter(bridge.wings.values()))
    model = "paper" if config.model_file is None else str(config.model_file)
    calibrated = [n for n in bridge.wings if n in bridge.tuning.store.current]
    if calibrated:  # what flies is the calibration of the configured model, not the model alone
        model += f" with the {' and '.join(calibrated)} wing's calibration from {bridge.tuning.store.path}"
    log.info("bridge running at %g Hz: FC link %s, servo %s, sensor %s, model %s, mode %s%s", config.loop.rate_hz,
             config.link.connection, config.servo_backend, config.sensor_backend, model, w.ctl.mode,
             bridge._mode_note(w.ctl.mode))
    try:
        while not (stop_event is not None and stop_event.is_set()):
            if duration is not None and timer.elapsed() >= duration:
                break
            bridge.tick()
            timer.wait()
    finally:
        bridge.close()
    stats = timer.stats()
    if stats.overruns:
        log.warning("loop overran %d tick(s); worst lateness %.1f ms", stats.overruns, 1000 * stats.late_max_s)
    return RunResult(bridge.cycles, stats, bridge.failsafe_entries,
                     str(bridge.log.path) if bridge.log is not None else None)
