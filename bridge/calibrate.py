"""Field tuning in the running bridge: pre-flight self-calibration and online pre-tension adaptation.

``FieldTuning`` is owned by ``bridge.app.Bridge`` and hooked into its cycle:

- **Self-calibration** (``start_calibration``), from the ground station by the
  parameter ``WB_CAL_RUN`` (1 quick: offset, gain, hysteresis width; 2 the
  full model) or ``COMMAND_LONG`` ``MAV_CMD_USER_1`` (31010) to component 191
  (param1: 1 quick, 2 full, 3 restore the previous model, 0 abort; answered by
  COMMAND_ACK, ``MAV_RESULT_DENIED`` while armed), and from ``warpbridge
  calibrate``. Only while the FC reports disarmed. Both tendons fly
  ``model.recalibrate.excitation`` in feed-forward only for ``WB_CAL_SEC``
  seconds within the safe part of the warp range; the record is fitted on a
  worker thread (``model.recalibrate.refit`` / ``refit_full``), and each wing's
  new model is applied only if it passes the held-out rule; otherwise the old
  one stays and a STATUSTEXT says why. Arming, a sensor fault or warp outside
  the safe envelope aborts at once. Each wing keeps its previous model;
  ``WB_CAL_REST`` = 1 swaps current and previous (setting it again undoes it).
  Calibrations persist in ``<params file stem>-cal.json`` beside the parameter
  file (as a pre-tension transform of the base model, so ``WB_BW_*`` still apply).
  The fitting code (``model.recalibrate``: scipy, compiled kernels) loads only
  when a calibration starts. In ``warpbridge run``, whose model kernels run
  interpreted (``model._jit``), the excitation and the fit run in a worker
  process with compiled kernels, started for the calibration and ended with it:
  the flight process stays small and its loop never waits on the fit; the
  excitation begins once the worker has prepared it (a few seconds).
- **Online adaptation** (``WB_ADAPT``): a ``model.adapt.PretensionEstimator``
  per wing, fed with each cycle's command and measured warp, whose offset and
  gain the controller applies (``WingController.set_pretension``) and whose
  sensor drift estimate (``WB_AD_DRIFT``) is taken off the measurement. Switched
  off, the estimates return to neutral at the rate limits. The estimates are
  telemetry (``L_ad_off``, ``L_ad_gain``, ``L_ad_drft``, ``L_ad_st`` and ``R_...``)
  and parameters (``WB_ADL_OFF``, ``WB_ADL_GAIN``, ``WB_ADL_DRFT``, ``WB_ADR_...``),
  published every ``PUBLISH_S`` when they moved; setting one overrides the estimate.
  With interpreted kernels (``warpbridge run``) the estimator is fed at about
  ``ADAPT_HZ_INTERPRETED`` (the mean command and warp of the cycles in between):
  its forward model costs most of an interpreted cycle, and the estimate moves
  over tens of seconds.

Telemetry ``WB_cal`` holds ``CalState``; ``WB_cal_pct`` the progress in percent.
"""

from __future__ import annotations

import enum
import json
import logging
import math
import threading
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from warpbridge.bridge.atomic import write_text_atomic
from warpbridge.bridge.mavlink_env import mavlink
from warpbridge.bridge.params import ParamSpec
from warpbridge.model import _jit
from warpbridge.model.adapt import AdaptConfig, PretensionEstimator, fold_pretension
from warpbridge.model.boucwen import BoucWenParams
from warpbridge.model.transform import Transform

if TYPE_CHECKING:
    from warpbridge.model.recalibrate import RefitResult

log = logging.getLogger(__name__)

FORMAT = "warpbridge-calibration/1"
MAV_CMD_CALIBRATE = mavlink.MAV_CMD_USER_1  # 31010
CMD_ABORT, CMD_QUICK, CMD_FULL, CMD_RESTORE = 0, 1, 2, 3
SEV_ERROR, SEV_WARNING, SEV_NOTICE, SEV_INFO = (mavlink.MAV_SEVERITY_ERROR, mavlink.MAV_SEVERITY_WARNING,
                                                mavlink.MAV_SEVERITY_NOTICE, mavlink.MAV_SEVERITY_INFO)
TAG = {"left": "L", "right": "R"}
SAFE_LO, SAFE_HI = 0.15, 0.85  # excitation range as fractions of the wing's max warp (scaled by WB_CAL_AMP)
ENVELOPE_DEG = 2.0  # measured warp this far outside [0, max warp] aborts a calibration
PUBLISH_S = 10.0  # estimates -> parameters at most this often
PROGRESS_STEP = 25  # percent between progress STATUSTEXTs
ADAPT_HZ_INTERPRETED = 25.0  # estimator update rate when the kernels run interpreted
EDGE_MARGIN = 0.02  # the estimator's shadow models look this far beyond its command


def model_top(params: BoucWenParams) -> float:
    """Largest tendon travel (mm) a model reaches at positive warp: u at the vertex of its centre line plus
    az times the largest z of a loading run. Beyond it the forward map (tendon -> warp) has no solution and
    searches at length (hundreds of ms interpreted). inf when the model rises without bound."""
    if params.a1 >= 0.0:
        return math.inf
    w_top = -params.a2 / (2.0 * params.a1)
    hi, lo = params.z_saturation(1.0)
    z = max(hi, lo) if params.az > 0 else min(hi, lo)
    if not math.isfinite(z) or w_top <= 0.0:
        return math.inf
    return params.a1 * w_top * w_top + params.a2 * w_top + params.a3 + params.az * z


def excitation_task(grid: np.ndarray, ranges: dict[str, tuple[float, float, float, int]]) -> dict[str, np.ndarray]:
    """Each wing's calibration setpoint over ``grid`` (s): ``ranges[wing] = (lo, hi, start, seed)``, deg."""
    from warpbridge.model.recalibrate import excitation

    return {name: excitation(grid, lo, hi, start_deg=start, seed=seed)
            for name, (lo, hi, start, seed) in ranges.items()}


def fit_task(base: BoucWenParams, t: np.ndarray, u: np.ndarray, w: np.ndarray, current: Transform,
             old: BoucWenParams, full: bool) -> RefitResult:
    """One wing's calibration fit (``model.recalibrate``): the quick refit, then the full model if asked."""
    from warpbridge.model.recalibrate import refit, refit_full

    quick = refit(base, t, u, w, current=current, old=old)
    return refit_full(base, t, u, w, lag_s=quick.lag_s, old=old, seed=1) if full else quick


class Worker:
    """Where a calibration computes: this process (compiled kernels) or, when the kernels of this process
    run interpreted, one worker process with compiled kernels for the calibration's length."""

    def __init__(self) -> None:
        self.in_process = _jit.mode() == "compiled"
        self._pool: ProcessPoolExecutor | None = None

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future:
        if self.in_process:
            fut: Future = Future()
            try:
                fut.set_result(fn(*args))
            except Exception as e:  # noqa: BLE001 - reported through the future
                fut.set_exception(e)
            return fut
        if self._pool is None:
            import multiprocessing

            self._pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"),
                                             initializer=_jit.compile_kernels)
        return self._pool.submit(fn, *args)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None


class CalState(enum.IntEnum):
    """Calibration state (telemetry ``WB_cal``)."""

    IDLE = 0
    EXCITING = 1
    FITTING = 2
    APPLIED = 3  # the last calibration changed at least one wing's model
    KEPT = 4  # the last calibration kept the old models (see its STATUSTEXT)
    ABORTED = 5


class Refused(ValueError):
    """A calibration or restore request that cannot be carried out now; the message says why."""


@dataclass
class WingCal:
    """One wing's calibrated model: a transform of the base model, or full parameters."""

    transform: Transform = field(default_factory=Transform)
    params: BoucWenParams | None = None  # a full re-identification (supersedes base + transform)
    report: dict = field(default_factory=dict)

    def model(self, base: BoucWenParams) -> BoucWenParams:
        return self.params if self.params is not None else self.transform.apply(base)

    def describe(self) -> str:
        """What the wing flies with this calibration, in a few words (STATUSTEXT-sized)."""
        if self.params is not None:
            return "full re-fit"
        t = self.transform
        if t == Transform():
            return "base model"
        return f"{t.offset:+.2f} mm, gain {t.gain:.3f}, width {t.az_scale:.2f}"

    def to_dict(self) -> dict:
        d: dict[str, Any] = {"transform": self.transform.to_dict(), "report": self.report}
        if self.params is not None:
            d["params"] = self.params.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> WingCal:
        params = BoucWenParams.from_dict(d["params"]) if d.get("params") else None
        return cls(Transform.from_dict(d.get("transform") or {"offset_mm": 0, "gain": 1}), params,
                   dict(d.get("report") or {}))


class CalStore:
    """Current and previous calibration per wing, persisted atomically as JSON."""

    def __init__(self, path: Path | None) -> None:
        self.path = path
        self.current: dict[str, WingCal] = {}
        self.previous: dict[str, WingCal | None] = {}
        self.load_report: str | None = None
        if path is not None and path.exists():
            try:
                doc = json.loads(path.read_text(encoding="utf-8"))
                if doc.get("format") != FORMAT:
                    raise ValueError(f"format {doc.get('format')!r}")
                for wing, d in doc.get("wings", {}).items():
                    self.current[wing] = WingCal.from_dict(d["current"])
                    self.previous[wing] = WingCal.from_dict(d["previous"]) if d.get("previous") else None
            except (OSError, ValueError, KeyError, TypeError, AttributeError) as e:
                self.current, self.previous = {}, {}
                self.load_report = f"WB cal file unreadable ({e}); base model used"[:100]
                log.error("calibration file %s: %s; using the base model", path, e)

    def get(self, wing: str) -> WingCal:
        return self.current.get(wing) or WingCal()

    def push(self, wing: str, cal: WingCal) -> None:
        self.previous[wing] = self.get(wing)
        self.current[wing] = cal
        self.save()

    def swap(self, wing: str) -> bool:
        prev = self.previous.get(wing)
        if prev is None:
            return False
        self.previous[wing], self.current[wing] = self.get(wing), prev
        self.save()
        return True

    def save(self) -> None:
        if self.path is None:
            return
        doc = {"format": FORMAT, "wings": {
            w: {"current": c.to_dict(), "previous": (p.to_dict() if (p := self.previous.get(w)) else None)}
            for w, c in self.current.items()}}
        try:
            write_text_atomic(self.path, json.dumps(doc, indent=1))
        except OSError as e:
            log.error("cannot save calibration to %s: %s", self.path, e)


def cal_path(params_file: Path | None) -> Path | None:
    """Where calibrations persist: beside the parameter file."""
    return None if params_file is None else params_file.with_name(params_file.stem + "-cal.json")


@dataclass
class _Batch:
    """The cycles between two estimator updates: mean command, mean warp (None if one was missing), time."""

    n: int = 0
    u: float = 0.0
    w: float = 0.0
    missing: bool = False
    dt: float = 0.0

    def add(self, u: float, w: float | None, dt: float) -> None:
        self.n += 1
        self.u += u
        self.dt += dt
        if w is None:
            self.missing = True
        else:
            self.w += w

    def take(self) -> tuple[float, float | None, float]:
        out = (self.u / self.n, None if self.missing else self.w / self.n, self.dt)
        self.n, self.u, self.w, self.missing, self.dt = 0, 0.0, 0.0, False, 0.0
        return out


@dataclass
class _Run:
    """A calibration in progress."""

    full: bool
    source: str
    t0: float | None  # None while the worker prepares the excitation
    duration: float
    grid_t: np.ndarray
    setpoint: dict[str, np.ndarray] | None
    modes: dict[str, str]
    worker: Worker
    prepared: Future | None = None
    record: dict[str, list[tuple[float, float, float]]] = field(default_factory=dict)
    next_pct: int = PROGRESS_STEP
    thread: threading.Thread | None = None
    results: dict[str, RefitResult | str] = field(default_factory=dict)
    progress: str = ""


class FieldTuning:
    """Self-calibration and online adaptation for the bridge's wings; see the module docstring.

    ``wings``: {name: object with ``.ctl`` (WingController) and ``.cfg`` (WingConfig)};
    ``base_model()`` the bridge's current base model; ``announce(name)`` sends a parameter's
    PARAM_VALUE after the bridge changed it itself."""

    def __init__(self, wings: dict[str, Any], link: Any, telemetry: Any, *, base_model: Callable[[], BoucWenParams],
                 params_file: Path | None, clock: Callable[[], float], loop_hz: float = 100.0,
                 has_sensor: Callable[[str], bool] = lambda _w: True, allowed_gcs=(),
                 max_warp: Callable[[str], float] | None = None, adapt_config: AdaptConfig | None = None) -> None:
        self.wings, self.link, self.telemetry, self.clock = wings, link, telemetry, clock
        self.base_model = base_model
        self.loop_hz = loop_hz
        self.has_sensor = has_sensor
        self.max_warp = max_warp or (lambda n: float(wings[n].cfg.max_warp_deg))
        self.allowed_gcs = set(allowed_gcs or ())
        self.store = CalStore(cal_path(params_file))
        self.params_store: Any = None  # the bridge's ParamStore, set by attach()
        self.announce: Callable[[str], None] = lambda _name: None
        self.allow_no_fc = False  # bench use (warpbridge calibrate --no-fc): no FC to ask about arming
        self.state = CalState.IDLE
        self.last_reason = ""
        self.cal_seconds = 20.0
        self.cal_amp = 1.0
        self._run: _Run | None = None
        self.last_results: dict[str, RefitResult | str] = {}
        self.last_restore = ""  # what each wing flies after the last restore, e.g. "left base model"
        self._ready = False
        self._internal = False  # True while the bridge itself sets one of our parameters
        self.adapt_on = True
        self.adapt_cfg = adapt_config or AdaptConfig()
        self.est: dict[str, PretensionEstimator] = {}
        for name in wings:
            self.est[name] = PretensionEstimator(self.wing_model(name), self.adapt_cfg)
        self.adapt_every = 1 if _jit.mode() == "compiled" else max(1, round(loop_hz / ADAPT_HZ_INTERPRETED))
        self._acc: dict[str, _Batch] = {name: _Batch() for name in wings}
        self._tops: dict[str, tuple[BoucWenParams, float]] = {}
        self._published: dict[str, float] = {}
        self._next_publish = 0.0

    # ------------------------------------------------------------------ models

    def wing_model(self, wing: str) -> BoucWenParams:
        """The model the wing flies: its calibration applied to the base model."""
        return self.store.get(wing).model(self.base_model())

    def base_changed(self) -> None:
        """The base model changed (WB_BW_*): every wing's model follows; estimates kept."""
        for name, w in self.wings.items():
            w.ctl.set_model(self.wing_model(name))
            est = self.est[name]
            keep = est.estimate
            est.set_model(self.wing_model(name))
            est.set_estimate(keep.offset, keep.gain, keep.drift)

    def _u_top(self, wing: str, params: BoucWenParams) -> float:
        """The largest tendon travel (mm) the estimator's model reaches (its loading branch at its vertex);
        inf when the model rises without bound."""
        cached = self._tops.get(wing)
        if cached is not None and cached[0] is params:
            return cached[1]
        top = model_top(params)
        self._tops[wing] = (params, top)
        return top

    def _apply_wing_model(self, wing: str) -> None:
        model = self.wing_model(wing)
        self.wings[wing].ctl.set_model(model)
        self.est[wing].set_model(model)
        self.wings[wing].ctl.set_pretension(0.0, 1.0)
        self._publish(force=True)

    # ------------------------------------------------------------------ parameters

    def param_specs(self, apply: Callable[[str, float], None]) -> list[ParamSpec]:
        """The WB_CAL_* / WB_AD* parameters (range beside each definition)."""
        c = self.adapt_cfg

        def spec(name, default, lo, hi, doc, integer=False):
            return ParamSpec(name, default, lo, hi, doc, integer, apply)

        specs = [
            spec("WB_CAL_RUN", 0, 0, 2, "set 1: calibrate offset, gain, width; 2: full model (disarmed only); "
                 "reads 0 when done; set 0 to abort", True),
            spec("WB_CAL_REST", 0, 0, 1, "set 1: swap each wing's model with the one before the last calibration "
                 "(disarmed only); reads 0 after", True),
            spec("WB_CAL_SEC", 20.0, 8.0, 29.0, "calibration excitation length, s"),
            spec("WB_CAL_AMP", 1.0, 0.3, 1.0, "calibration excitation amplitude, fraction of 15..85 % of max warp"),
            spec("WB_ADAPT", 1, 0, 1, "online pre-tension adaptation: 0 off (estimates return to neutral), 1 on",
                 True),
            spec("WB_AD_RATE", c.rate_mm_s, 0.0, 0.2, "adaptation: fastest offset change, mm/s (gain: /5 mm)"),
            spec("WB_AD_MAX", c.max_offset_mm, 0.0, 5.0, "adaptation: largest |offset|, mm"),
            spec("WB_AD_GMAX", c.max_gain_dev, 0.0, 0.5, "adaptation: gain within [1/(1+x), 1+x]"),
            spec("WB_AD_DRIFT", 0, 0, 1, "adaptation: also estimate the sensor zero drift (needs wide moves)", True),
            spec("WB_AD_DMAX", c.max_drift_deg, 0.0, 3.0, "adaptation: largest |sensor drift|, deg"),
            spec("WB_AD_TAU", c.tau_s, 5.0, 120.0, "adaptation: estimator memory (forgetting time), s"),
        ]
        for name in self.wings:
            t = TAG[name]
            specs += [
                spec(f"WB_AD{t}_OFF", 0.0, -5.0, 5.0, f"{name} pre-tension offset estimate, mm (set: override)"),
                spec(f"WB_AD{t}_GAIN", 1.0, 0.5, 2.0, f"{name} pre-tension gain estimate (set: override)"),
                spec(f"WB_AD{t}_DRFT", 0.0, -3.0, 3.0, f"{name} sensor zero drift estimate, deg (set: override)"),
            ]
        return specs

    @staticmethod
    def owns(name: str) -> bool:
        return name.startswith(("WB_CAL_", "WB_AD"))

    @staticmethod
    def is_estimate(name: str) -> bool:
        """True for a parameter the adaptation writes itself (a wing's offset, gain or drift estimate), not one a
        user sets."""
        return any(name == f"WB_AD{t}_{k}" for t in TAG.values() for k in ("OFF", "GAIN", "DRFT"))

    def attach(self, store: Any, announce: Callable[[str], None]) -> None:
        """Hand over the parameter store (after the bridge applied the persisted values)."""
        self.params_store, self.announce = store, announce

    def apply_param(self, name: str, v: float) -> None:
        """Apply a WB_CAL_* / WB_AD* value; raises ValueError (-> the set is refused) with the reason."""
        if self._internal and name in ("WB_CAL_RUN", "WB_CAL_REST"):
            return  # our own reset or echo: nothing to start
        if name == "WB_CAL_RUN":
            if not self._ready:
                return  # a value persisted by an interrupted run: never start at boot
            if int(v) == 0:
                if self._run is not None:
                    self.abort("stopped by WB_CAL_RUN = 0")
                return
            self.start_calibration(full=int(v) == 2, source="param")
        elif name == "WB_CAL_REST":
            if self._ready and int(v) == 1:
                self.restore()
        elif name == "WB_CAL_SEC":
            self.cal_seconds = float(v)
        elif name == "WB_CAL_AMP":
            self.cal_amp = float(v)
        elif name == "WB_ADAPT":
            self.adapt_on = bool(int(v))
            for est in self.est.values():
                est.enabled = self.adapt_on
        elif name in ("WB_AD_RATE", "WB_AD_MAX", "WB_AD_GMAX", "WB_AD_DRIFT", "WB_AD_DMAX", "WB_AD_TAU"):
            key = {"WB_AD_RATE": "rate_mm_s", "WB_AD_MAX": "max_offset_mm", "WB_AD_GMAX": "max_gain_dev",
                   "WB_AD_DRIFT": "estimate_drift", "WB_AD_DMAX": "max_drift_deg", "WB_AD_TAU": "tau_s"}[name]
            kw: dict[str, Any] = {key: bool(int(v)) if key == "estimate_drift" else float(v)}
            if key == "rate_mm_s":
                kw["rate_gain_s"] = float(v) / 5.0
            self.adapt_cfg = replace(self.adapt_cfg, **kw)
            for est in self.est.values():
                est.set_config(self.adapt_cfg)
        elif name.startswith("WB_AD") and name[5:6] in ("L", "R"):
            wing = "left" if name[5] == "L" else "right"
            if wing not in self.est:
                return
            what = name[7:]
            est = self.est[wing]
            cur = est.estimate
            now = {"OFF": cur.offset, "GAIN": cur.gain, "DRFT": cur.drift}[what]
            if abs(now - v) <= 1e-4:
                return  # our own publication coming back (rounded to 4 decimals)
            est.set_estimate(**{{"OFF": "offset", "GAIN": "gain", "DRFT": "drift"}[what]: float(v)})

    def _set_param(self, name: str, value: float) -> None:
        """Change one of our parameters from inside the bridge, and tell the ground station."""
        if self.params_store is None or name not in self.params_store:
            return
        self._internal = True
        try:
            before = self.params_store.get(name)
            if self.params_store.set(name, value) != before:  # held at float32's precision: may not change
                self.announce(name)
        except Exception:  # noqa: BLE001
            log.exception("could not update %s", name)
        finally:
            self._internal = False

    # ------------------------------------------------------------------ requests

    def _check_disarmed(self) -> None:
        link = self.link
        if getattr(link, "armed", False):
            raise Refused("refused while armed")
        if not self.allow_no_fc and not getattr(link, "fc_alive", False):
            raise Refused("no FC heartbeat: cannot confirm disarmed")

    def start_calibration(self, *, full: bool = False, source: str = "param") -> None:
        """Start a calibration now; raises ``Refused`` (a ValueError) with the reason."""
        if self._run is not None:
            raise Refused("a calibration is already running")
        self._check_disarmed()
        for name in self.wings:
            if not self.has_sensor(name):
                raise Refused(f"{name} wing has no warp sensor")
        dur = float(self.cal_seconds)
        n = int(math.ceil(dur * self.loop_hz)) + 1
        grid = np.arange(n) / self.loop_hz
        ranges, modes = {}, {}
        for i, (name, w) in enumerate(self.wings.items()):
            wmax = self.max_warp(name)
            mid = 0.5 * (SAFE_LO + SAFE_HI) * wmax
            half = 0.5 * (SAFE_HI - SAFE_LO) * wmax * self.cal_amp
            ranges[name] = (mid - half, mid + half, float(getattr(w, "setpoint", mid)), 7 + i)
            modes[name] = w.ctl.mode
            w.ctl.set_mode("ff")  # open loop: a clean record of the model's input and the wing's answer
        worker = Worker()
        run = _Run(full, source, None, dur, grid, None, modes, worker, record={name: [] for name in self.wings})
        self._run = run
        self.state = CalState.EXCITING
        self.last_reason = ""
        what = "full model" if full else "offset, gain, width"
        log.info("calibration started by %s (%s)%s", source, what,
                 "" if worker.in_process else "; preparing it in a worker process")
        run.prepared = worker.submit(excitation_task, grid, ranges)
        self._begin_excitation(run)

    def _begin_excitation(self, run: _Run) -> None:
        """Fly the excitation once the worker has prepared it (at once when it runs in this process)."""
        fut = run.prepared
        if run.t0 is not None or fut is None or not fut.done():
            return
        try:
            run.setpoint = fut.result()
        except Exception as e:  # noqa: BLE001 - e.g. the worker process could not start
            log.exception("calibration excitation could not be prepared")
            self.abort(f"could not prepare the excitation: {e}"[:80])
            return
        run.t0 = self.clock()
        what = "full model" if run.full else "offset, gain, width"
        self.telemetry.status(SEV_NOTICE, f"WB cal start ({what}), {run.duration:.0f} s: keep clear of the wings")

    def restore(self) -> None:
        """Swap every wing's model with its previous one; raises ``Refused``."""
        if self._run is not None:
            raise Refused("a calibration is running")
        self._check_disarmed()
        swapped = [name for name in self.wings if self.store.swap(name)]
        if not swapped:
            raise Refused("no previous model to restore")
        for name in swapped:
            self._apply_wing_model(name)
        # a restore swaps the two: say what flies now (a second restore brings the other back)
        now = "; ".join(f"{name} {self.store.get(name).describe()}" for name in swapped)
        self.last_restore = now
        log.info("previous model restored: %s flies now (restore again to swap back)", now)
        self.telemetry.status(SEV_NOTICE, f"WB cal restored: {now}", log_it=False)

    def abort(self, reason: str) -> None:
        run = self._run
        if run is None:
            return
        self._end_excitation(run)
        run.worker.close()
        self._run = None
        self.state = CalState.ABORTED
        self.last_reason = reason
        self.telemetry.status(SEV_WARNING, f"WB cal aborted: {reason}"[:100])
        log.warning("calibration aborted: %s", reason)
        self._set_param("WB_CAL_RUN", 0)

    def _end_excitation(self, run: _Run) -> None:
        for name, w in self.wings.items():
            w.ctl.set_mode(run.modes[name])

    @property
    def running(self) -> bool:
        return self._run is not None

    def wait_fit(self, timeout: float | None = None) -> None:
        """Block until a running fit's worker thread is done (the next ``poll`` reports it)."""
        run = self._run
        if run is not None and run.thread is not None:
            run.thread.join(timeout)

    # ------------------------------------------------------------------ MAVLink command

    def handle_messages(self, messages: list[Any]) -> list[Any]:
        """Take the MAV_CMD_USER_1 COMMAND_LONGs addressed to us; return the rest."""
        out = []
        for msg in messages:
            try:
                if msg.get_type() == "COMMAND_LONG" and msg.command == MAV_CMD_CALIBRATE \
                        and msg.target_component == self.link.component_id \
                        and msg.target_system in (0, self.link.system_id):
                    self._command(msg)
                    continue
            except Exception:  # noqa: BLE001
                log.exception("calibration command not handled")
                continue
            out.append(msg)
        return out

    def _command(self, msg: Any) -> None:
        action = int(round(msg.param1)) if math.isfinite(msg.param1) else -1
        result, reason = mavlink.MAV_RESULT_ACCEPTED, ""
        sender = msg.get_srcSystem()
        try:
            if self.allowed_gcs and sender not in self.allowed_gcs:
                raise Refused(f"sysid {sender} may not calibrate")
            if action in (CMD_QUICK, CMD_FULL):
                self.start_calibration(full=action == CMD_FULL, source=f"command from {sender}")
                self._set_param("WB_CAL_RUN", action)
            elif action == CMD_RESTORE:
                self.restore()
            elif action == CMD_ABORT:
                self.abort("stopped by command")
            else:
                result, reason = mavlink.MAV_RESULT_UNSUPPORTED, f"unknown action {msg.param1:g}"
        except Refused as e:
            reason = str(e)
            busy = "running" in reason
            result = mavlink.MAV_RESULT_TEMPORARILY_REJECTED if busy else mavlink.MAV_RESULT_DENIED
        if reason:
            self.telemetry.status(SEV_WARNING, f"WB cal: {reason}"[:100])
        self.link.send(mavlink.MAVLink_command_ack_message(MAV_CMD_CALIBRATE, result, 0, 0, sender,
                                                           msg.get_srcComponent()))

    # ------------------------------------------------------------------ the cycle

    def setpoint(self, wing: str, now: float, setpoint: float) -> float:
        """The wing's setpoint this cycle: the excitation while calibrating, else as given."""
        run = self._run
        if run is None or self.state != CalState.EXCITING or run.t0 is None or run.setpoint is None:
            return setpoint
        return float(np.interp(now - run.t0, run.grid_t, run.setpoint[wing]))

    def measurement(self, wing: str, measured: float | None) -> float | None:
        """The measurement the controller should use (sensor drift estimate taken off)."""
        if measured is None or self._run is not None:
            return measured
        return measured - self.est[wing].estimate.drift

    def before_step(self, wing: str) -> None:
        """Put the current pre-tension estimate into the wing's controller."""
        if self._run is not None and self.state == CalState.EXCITING:
            return
        e = self.est[wing].estimate
        self.wings[wing].ctl.set_pretension(e.offset, e.gain)

    def after_step(self, wing: str, now: float, u_cmd: float, measured: float | None, dt: float) -> None:
        """Feed the cycle's command and raw measurement to the calibration or the estimator."""
        run = self._run
        if run is not None and self.state == CalState.EXCITING:
            if run.t0 is None:
                return  # the excitation is being prepared
            wmax = self.max_warp(wing)
            if measured is None:
                self.abort(f"{wing} sensor unhealthy")
            elif not -ENVELOPE_DEG <= measured <= wmax + ENVELOPE_DEG:
                self.abort(f"{wing} warp {measured:.1f} deg outside the safe range")
            else:
                run.record[wing].append((now - run.t0, u_cmd, measured))
            return
        batch = self._acc[wing]
        batch.add(u_cmd, measured, dt)
        if batch.n < self.adapt_every:
            return
        u_cmd, measured, dt = batch.take()
        est = self.est[wing]
        e = est.estimate
        if e.gain * (u_cmd - e.offset) * (1.0 + EDGE_MARGIN) >= self._u_top(wing, est.params):
            return  # beyond the top of the model's loop: the forward map has no answer there, nothing to learn
        if self.adapt_on:
            est.update(u_cmd, measured, dt, healthy=measured is not None and run is None)
        else:
            est.update(u_cmd, None, dt)
            est.relax(dt)

    def poll(self, now: float) -> None:
        """Once per cycle after the wings: interlock, progress, fit results, telemetry."""
        if not self._ready:
            self._ready = True
            self._set_param("WB_CAL_RUN", 0)
            self._set_param("WB_CAL_REST", 0)
            if self.store.load_report:
                self.telemetry.status(SEV_WARNING, self.store.load_report)
        if self.params_store is not None and "WB_CAL_REST" in self.params_store \
                and self.params_store.get("WB_CAL_REST") != 0:
            self._set_param("WB_CAL_REST", 0)  # a one-shot: reads 0 again once done
        run = self._run
        if run is not None:
            if getattr(self.link, "armed", False):
                if self.state == CalState.EXCITING:
                    self.abort("armed")
                run = self._run
        if run is not None and self.state == CalState.EXCITING and run.t0 is None:
            self._begin_excitation(run)
        elif run is not None and self.state == CalState.EXCITING:
            pct = int(100 * (now - run.t0) / run.duration)
            if pct >= run.next_pct and pct < 100:
                self.telemetry.status(SEV_INFO, f"WB cal {run.next_pct} %")
                run.next_pct += PROGRESS_STEP
            if now - run.t0 >= run.duration:
                self._end_excitation(run)
                self.state = CalState.FITTING
                self.telemetry.status(SEV_INFO, "WB cal: excitation done, fitting")
                run.thread = threading.Thread(target=self._fit, args=(run,), name="wb-calibrate", daemon=True)
                run.thread.start()
        elif run is not None and self.state == CalState.FITTING and run.thread is not None \
                and not run.thread.is_alive():
            self._finish(run)
        self._telemetry(now)

    def _fit(self, run: _Run) -> None:
        """Worker thread: fit every wing's record."""
        base = self.base_model()
        for name in self.wings:
            try:
                rec = np.array(run.record[name], dtype=np.float64)
                if rec.shape[0] < 200:
                    raise ValueError(f"only {rec.shape[0]} samples recorded")
                t, u, w = rec[:, 0], rec[:, 1], rec[:, 2]
                est = self.est[name].estimate
                cal = self.store.get(name)
                flown = cal.model(base)  # what the wing flies now: its model and the adaptation on top
                old = fold_pretension(flown, est.offset, est.gain)
                current = cal.transform.then(est.offset, est.gain) if cal.params is None else Transform()
                run.results[name] = run.worker.submit(fit_task, base, t, u, w, current, old, run.full).result()
            except Exception as e:  # noqa: BLE001 - a failed fit keeps the old model
                log.exception("calibration fit of the %s wing failed", name)
                run.results[name] = f"fit failed: {e}"

    def _finish(self, run: _Run) -> None:
        run.worker.close()
        self._run = None
        applied = []
        armed = getattr(self.link, "armed", False)
        for name in self.wings:
            res = run.results.get(name, "no result")
            t = TAG[name]
            if isinstance(res, str):
                self.telemetry.status(SEV_WARNING, f"WB cal {t}: kept old model: {res}"[:100])
                continue
            tf = res.transform
            fit = (f"off {tf.offset:+.2f} gain {tf.gain:.3f} width {tf.az_scale:.2f}" if not res.full
                   else "full model")
            self.telemetry.status(SEV_INFO, f"WB cal {t}: {fit}, held {res.heldout_rms:.2f} "
                                            f"(old {res.old_heldout_rms:.2f}) deg"[:100])
            if armed:
                res.accepted, res.reason = False, "armed before the fit finished"
            if not res.accepted:
                self.telemetry.status(SEV_WARNING, f"WB cal {t}: kept old model: {res.reason}"[:100])
                continue
            cal = WingCal(tf, res.params if res.full else None, {k: v for k, v in res.summary().items()})
            self.store.push(name, cal)
            self._apply_wing_model(name)
            applied.append(name)
            self.telemetry.status(SEV_NOTICE, f"WB cal {t}: new model applied ({res.reason})"[:100])
        self.state = CalState.APPLIED if applied else CalState.KEPT
        self.last_results = run.results
        self._set_param("WB_CAL_RUN", 0)

    # ------------------------------------------------------------------ telemetry

    def _telemetry(self, now: float) -> None:
        tl = self.telemetry
        try:
            tl.named_float("WB_cal", float(self.state))
            run = self._run
            if run is not None and self.state == CalState.EXCITING and run.t0 is not None:
                tl.named_float("WB_cal_pct", min(100.0, 100.0 * (now - run.t0) / run.duration))
            for name, est in self.est.items():
                e = est.estimate
                t = TAG[name]
                tl.named_float(f"{t}_ad_off", e.offset)
                tl.named_float(f"{t}_ad_gain", e.gain)
                tl.named_float(f"{t}_ad_st", float(e.state))
                if self.adapt_cfg.estimate_drift:
                    tl.named_float(f"{t}_ad_drft", e.drift)
        except Exception:  # noqa: BLE001
            log.exception("field-tuning telemetry failed")
        if now >= self._next_publish:
            self._next_publish = now + PUBLISH_S
            self._publish()

    def _publish(self, force: bool = False) -> None:
        """Estimates -> parameters, when they moved by more than a small quantum."""
        for name, est in self.est.items():
            e = est.estimate
            t = TAG[name]
            for suffix, v, q in (("OFF", e.offset, 0.005), ("GAIN", e.gain, 0.0005), ("DRFT", e.drift, 0.005)):
                pname = f"WB_AD{t}_{suffix}"
                v = round(v, 4)
                if force or abs(self._published.get(pname, math.inf) - v) >= q:
                    self._published[pname] = v
                    self._set_param(pname, v)
