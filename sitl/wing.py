"""The simulated wing: servo -> tendon-sheath plant -> warp -> flex sensor, in a flow.

One ``SimWing`` per side. Its servo (``sitl.servo_model``) turns the commanded
pulse into tendon travel; the plant turns that into warp, losing some to the
aerodynamic load at the current airspeed. The plant is a ``model.plant.Plant``
(the paper's Bouc-Wen model by default, or a MODEL.json's, inside any
``model.effects`` chain: the model's own class), or any ``WingPlant``: the
physics-based sheath (``SheathWing``: a tendon in a sheath with distributed
friction, ``sitl.sheath``; not the model's class, so a controller identified on
it does not know it exactly) or a straight line (``LinearPlant``, for loop
measurements); the flow (steady, or ``sitl.gust.Gust``) adds buffeting; the
flex sensor (``sitl.flex_sensor``) reads the measured warp as ADC counts.
``advance(t)`` integrates up to time t in sub-steps of ``substep_s`` (1 ms by
default) with the last commanded pulse held, so the same wing code serves the
lock-step run (advanced by the loop) and the real-time run (advanced by a
clock thread while the servo board emulator sets pulses and reads counts).
"""

from __future__ import annotations

import functools
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from warpbridge.model.boucwen import BoucWenParams
from warpbridge.model.effects import Effects
from warpbridge.model.plant import Plant, PlantStepper
from warpbridge.sitl.flex_sensor import FlexSensor, FlexSensorSpec
from warpbridge.sitl.servo_model import ServoModel, ServoSpec

# The SITL's default wing is the paper's, with a small aerodynamic load: about 4 % of the
# warp and 0.1 deg lost at 12 m/s (q = 0.088 kPa); nothing on the bench (V = 0).
SITL_AERO_LOAD = Effects(aero_gain_per_kpa=0.5, aero_deg_per_kpa=1.0)


def default_plant() -> Plant:
    """The paper's Bouc-Wen wing plus the SITL's small aerodynamic load."""
    return Plant(BoucWenParams.paper(), SITL_AERO_LOAD)


class PlantState(Protocol):
    """A running plant: ``step(t, u_mm, airspeed) -> (w_true, w_meas)`` in deg."""

    def step(self, t: float, u: float, airspeed: float | None = None) -> tuple[float, float]: ...


class WingPlant(Protocol):
    """A simulated wing's mechanics other than ``model.plant.Plant``."""

    def start(self, t0: float, u0: float) -> PlantState:
        """The plant at rest at time t0 with the tendon at u0 (mm)."""

    def rest_tendon(self, w_deg: float) -> float:
        """Tendon travel (mm) that brings the plant, pulled from slack, to ``w_deg``."""

    def with_effects(self, effects: Effects) -> WingPlant: ...


@dataclass(frozen=True)
class LinearPlant:
    """w = w_ref + slope (u - u_ref): no hysteresis, no dynamics (deg, mm). A plant of a given
    small-signal slope, for measuring the loop's frequency response (``benchmarks/bench_margins.py``)."""

    slope_deg_per_mm: float
    u_ref_mm: float = 0.0
    w_ref_deg: float = 0.0

    def start(self, t0: float, u0: float) -> PlantState:
        return _LinearState(self)

    def rest_tendon(self, w_deg: float) -> float:
        return self.u_ref_mm + (w_deg - self.w_ref_deg) / self.slope_deg_per_mm

    def with_effects(self, effects: Effects) -> WingPlant:
        if effects != Effects():
            raise ValueError("effects apply to the Bouc-Wen wing only")
        return self


class _LinearState:
    def __init__(self, plant: LinearPlant) -> None:
        self.p = plant

    def step(self, t: float, u: float, airspeed: float | None = None) -> tuple[float, float]:
        w = self.p.w_ref_deg + self.p.slope_deg_per_mm * (u - self.p.u_ref_mm)
        return w, w


@dataclass(frozen=True)
class SheathWing:
    """The physics-based tendon-sheath wing (``sitl.sheath``) behind the SITL's servo and sensor.

    ``u_rest_mm``: the servo's tendon travel at which the rigged tendon rests at its pre-tension (an
    installation offset). The aerodynamic load is a force pushing the trailing edge back,
    ``q (aero_n_per_kpa + aero_n_per_kpa_deg * w)`` N at dynamic pressure q (kPa) and the last warp w:
    about what the Bouc-Wen wing's ``SITL_AERO_LOAD`` loses (0.1 deg and 4 % at 12 m/s), here felt
    through the sheath's friction. ``model.effects`` do not apply (they are the Bouc-Wen wing's)."""

    params: object  # sitl.sheath.SheathParams
    u_rest_mm: float = 0.0
    aero_n_per_kpa: float = 0.66
    aero_n_per_kpa_deg: float = 0.27

    def start(self, t0: float, u0: float) -> PlantState:
        return _SheathState(self, u0)

    @property
    def slack_mm(self) -> float:
        """A tendon travel at which the tendon is surely slack (well below any working travel)."""
        p = self.params
        return self.u_rest_mm - 5.0 * (p.pretension_n / p.k_tendon + p.pretension_n / p.k_wing + p.slack_mm + 1.0)

    def rest_tendon(self, w_deg: float) -> float:
        """Tendon travel reaching ``w_deg`` when pulled from a slack tendon (no load)."""
        return _sheath_rest_tendon(self, float(w_deg))

    def with_effects(self, effects: Effects) -> WingPlant:
        if effects != Effects():
            raise ValueError("effects apply to the Bouc-Wen wing only (change the sheath's parameters instead)")
        return self


class _SheathState:
    """A running sheath wing, started slack and pulled to the first tendon travel (the loading branch)."""

    def __init__(self, wing: SheathWing, u0: float) -> None:
        from warpbridge.sitl.sheath import SheathPlant

        self.wing = wing
        self.plant = SheathPlant(wing.params, wing.u_rest_mm)
        self.plant.step(min(wing.slack_mm, u0 - 1.0))
        self.w = self.plant.step(u0)

    def step(self, t: float, u: float, airspeed: float | None = None) -> tuple[float, float]:
        load = 0.0
        if airspeed:
            q = 0.5 * 1.225 * airspeed * airspeed / 1000.0  # kPa
            load = q * (self.wing.aero_n_per_kpa + self.wing.aero_n_per_kpa_deg * max(self.w, 0.0))
        self.w = self.plant.step(u, load)
        return self.w, self.w


@functools.lru_cache(maxsize=256)
def _sheath_rest_tendon(wing: SheathWing, w_deg: float) -> float:
    from warpbridge.sitl.sheath import SheathPlant

    plant = SheathPlant(wing.params, wing.u_rest_mm)
    u = np.arange(wing.slack_mm, wing.u_rest_mm + 200.0, 0.002)
    for k in range(0, u.size, 5000):
        w = plant.simulate(u[k:k + 5000])
        hit = np.nonzero(w >= w_deg)[0]
        if hit.size:
            j = int(hit[0])
            if j == 0:
                return float(u[k])
            wa, wb = w[j - 1], w[j]
            return float(u[k + j - 1] + (w_deg - wa) * (u[k + j] - u[k + j - 1]) / (wb - wa))
    raise ValueError(f"the sheath wing never reaches {w_deg:g} deg")


def start_plant(plant: Plant | WingPlant, t0: float, u0: float) -> PlantState:
    """The running state of ``plant`` at rest with the tendon at u0."""
    if isinstance(plant, Plant):
        return _BoucWenState(plant, t0, u0)
    return plant.start(t0, u0)


class _BoucWenState(PlantStepper):
    """``PlantStepper`` that skips the aerodynamic load where there is no air (it is exactly zero)."""

    def step(self, t: float, u: float, airspeed: float | None = None) -> tuple[float, float]:
        return super().step(t, u, airspeed if airspeed else None)


class Flow(Protocol):
    """Air at the wing: airspeed (m/s) and buffeting warp (deg) at times t (arrays)."""

    def airspeed(self, t): ...

    def buffet_deg(self, t, airspeed=None): ...


class SteadyFlow:
    """Smooth flow following a mean-airspeed profile (a float or a function of time)."""

    def __init__(self, airspeed_ms: float | Callable[[np.ndarray], np.ndarray] = 0.0) -> None:
        self._v = airspeed_ms

    def airspeed(self, t):
        if callable(self._v):
            return np.asarray(self._v(np.asarray(t, dtype=np.float64)), dtype=np.float64)
        return np.full(np.shape(t), float(self._v))

    def buffet_deg(self, t, airspeed=None):
        return np.zeros(np.shape(t))


@dataclass(frozen=True)
class WingSpec:
    """Everything that makes one simulated wing."""

    plant: Plant | WingPlant = field(default_factory=default_plant)
    servo: ServoSpec = field(default_factory=ServoSpec)
    sensor: FlexSensorSpec = field(default_factory=FlexSensorSpec)
    substep_s: float = 0.001

    def with_effects(self, effects: Effects) -> WingSpec:
        """The same wing with ``effects`` switched on over the plant's own."""
        if isinstance(self.plant, Plant):
            plant: Plant | WingPlant = Plant(self.plant.params, self.plant.effects.merged(effects))
        else:
            plant = self.plant.with_effects(effects)
        return WingSpec(plant, self.servo, self.sensor, self.substep_s)

    def rest_pulse(self, w_deg: float) -> float:
        """Pulse that holds the nominal (unloaded, z = 0) wing at ``w_deg``."""
        if not isinstance(self.plant, Plant):
            return self.servo.pulse_of(self.plant.rest_tendon(w_deg))
        p = self.plant.params
        return self.servo.pulse_of(p.a1 * w_deg * w_deg + p.a2 * w_deg + p.a3)


class SimWing:
    """One wing's state. ``set_pulse`` commands, ``advance(t)`` integrates, ``read_counts`` senses.

    Thread-safe: the real-time run calls these from the emulator's and the clock's threads.
    ``grid_origin``: None, sub-steps of ``substep_s`` from each ``advance``'s start; a time, sub-steps
    end on that time plus whole sub-steps (and at each ``advance``'s end), so that advancing to
    such a grid point in between changes nothing: a run advanced more often (the real-time rig,
    kept current between the bridge's calls) integrates exactly as its replay."""

    def __init__(self, spec: WingSpec = WingSpec(), flow: Flow | None = None, *, t0: float = 0.0,
                 w0_deg: float = 0.0, seed: int = 0, record: bool = False, grid_origin: float | None = None,
                 ) -> None:
        self.spec = spec
        self.grid_origin = grid_origin
        self.flow: Flow = flow if flow is not None else SteadyFlow(0.0)
        self.pulse_us = spec.rest_pulse(w0_deg)
        self.servo = ServoModel(spec.servo, t0, self.pulse_us)
        self.plant: PlantState = start_plant(spec.plant, t0, self.servo.mm)
        self.sensor = FlexSensor(spec.sensor, seed)
        self.t = float(t0)
        v0 = float(self.flow.airspeed(np.array([t0]))[0])
        self.airspeed = v0
        self.w_true, self.w_meas = self.plant.step(t0, self.servo.mm, v0)
        self.record = record
        self._trace: dict[str, list[float]] = {k: [] for k in ("t", "pulse", "u", "airspeed", "w_true", "w_meas")}
        self._lock = threading.Lock()

    def set_pulse(self, pulse_us: float) -> None:
        """Command a new pulse width (us); held until the next command."""
        with self._lock:
            self.pulse_us = float(pulse_us)

    def advance(self, t: float) -> None:
        """Integrate from the current time to ``t`` in sub-steps (no-op if t is not later)."""
        with self._lock:
            h = self.spec.substep_s
            if self.grid_origin is None:
                n = math.ceil((t - self.t) / h - 1e-9)
                if n <= 0:
                    return
                ts = self.t + h * np.arange(1, n + 1)
                ts[-1] = t
            else:
                if not t > self.t + 1e-9:
                    return
                o = self.grid_origin
                k = np.arange(math.floor((self.t - o) / h) + 1, math.ceil((t - o) / h))
                inner = o + h * k
                ts = np.append(inner[(inner > self.t + 1e-9) & (inner < t - 1e-9)], t)
                n = ts.size
            v = self.flow.airspeed(ts)
            buffet = self.flow.buffet_deg(ts, v)
            for k in range(n):
                tk = float(ts[k])
                u = self.servo.step(tk, self.pulse_us)
                w_true, w_meas = self.plant.step(tk, u, float(v[k]))
                self.w_true = w_true + float(buffet[k])
                self.w_meas = w_meas + float(buffet[k])
                if self.record:
                    tr = self._trace
                    tr["t"].append(tk)
                    tr["pulse"].append(self.pulse_us)
                    tr["u"].append(u)
                    tr["airspeed"].append(float(v[k]))
                    tr["w_true"].append(self.w_true)
                    tr["w_meas"].append(self.w_meas)
            self.t = float(t)
            self.airspeed = float(v[-1])

    @property
    def u_mm(self) -> float:
        """Tendon travel at the servo (mm)."""
        return self.servo.mm

    def read_counts(self) -> int:
        """The flex sensor's ADC reading now (noisy, quantised)."""
        with self._lock:
            return self.sensor.read(self.w_meas)

    def trace(self) -> dict[str, np.ndarray]:
        """Recorded sub-steps (if ``record``): t, pulse, u, airspeed, w_true, w_meas."""
        with self._lock:
            return {k: np.asarray(v, dtype=np.float64) for k, v in self._trace.items()}


def bench_log(spec: WingSpec, u_lo: float, u_hi: float, *, seconds: float = 90.0, rate_hz: float = 200.0,
              cutoff_hz: float = 1.0, seed: int = 0) -> dict[str, np.ndarray]:
    """A bench identification log of the simulated wing, as a user records one (README, "Real hardware",
    step 4): the tendon driven by a low-passed random command over [u_lo, u_hi] mm, the flex sensor read
    through its noise and 10-bit ADC and converted to degrees by its calibration table, both logged at
    ``rate_hz``. Returns the columns ``t`` (s), ``u`` (commanded tendon, mm) and ``warp`` (deg)."""
    from warpbridge.model.excitation import filtered_random

    if not u_lo < u_hi:
        raise ValueError("u_lo must be below u_hi")
    t = np.arange(int(round(seconds * rate_hz))) / rate_hz
    u = filtered_random(t, cutoff_hz, 0.5 * (u_hi - u_lo), offset=0.5 * (u_lo + u_hi), seed=seed)
    wing = SimWing(spec, t0=0.0, w0_deg=0.0, seed=seed + 1)
    wing.set_pulse(spec.servo.pulse_of(float(u[0])))
    wing.advance(1.0)  # settle at the first command before logging starts
    counts = np.empty(t.size)
    for k in range(t.size):
        wing.set_pulse(spec.servo.pulse_of(float(u[k])))
        wing.advance(1.0 + t[k])
        counts[k] = wing.read_counts()
    return {"t": t, "u": u, "warp": np.asarray(spec.sensor.deg_of_counts(counts), dtype=np.float64)}
