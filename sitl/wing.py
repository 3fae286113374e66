"""The simulated wing: servo -> tendon-sheath plant -> warp -> flex sensor, in a flow.

One ``SimWing`` per side. Its servo (``sitl.servo_model``) turns the commanded
pulse into tendon travel; the plant (``model.plant.PlantStepper``: the paper's
Bouc-Wen model by default, or a MODEL.json's, inside any ``model.effects``
chain) turns that into warp, losing some to the aerodynamic load at the
current airspeed; the flow (steady, or ``sitl.gust.Gust``) adds buffeting; the
flex sensor (``sitl.flex_sensor``) reads the measured warp as ADC counts.
``advance(t)`` integrates up to time t in sub-steps of ``substep_s`` (1 ms by
default) with the last commanded pulse held, so the same wing code serves the
lock-step run (advanced by the loop) and the real-time run (advanced by a
clock thread while the servo board emulator sets pulses and reads counts).
"""

from __future__ import annotations

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

    plant: Plant = field(default_factory=default_plant)
    servo: ServoSpec = field(default_factory=ServoSpec)
    sensor: FlexSensorSpec = field(default_factory=FlexSensorSpec)
    substep_s: float = 0.001

    def with_effects(self, effects: Effects) -> WingSpec:
        """The same wing with ``effects`` switched on over the plant's own."""
        return WingSpec(Plant(self.plant.params, self.plant.effects.merged(effects)), self.servo, self.sensor,
                        self.substep_s)

    def rest_pulse(self, w_deg: float) -> float:
        """Pulse that holds the nominal (unloaded, z = 0) wing at ``w_deg``."""
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
        self.plant = PlantStepper(spec.plant, t0, self.servo.mm)
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
