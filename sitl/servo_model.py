"""A hobby servo pulling a tendon: commanded pulse width (us) -> tendon travel (mm).

The servo sees its pulse quantised to the servo board's 0.25 us steps, ignores
corrections smaller than its deadband (the output only moves once the target
is more than half the deadband away, then heads for the edge of the deadband:
a play operator in pulse units), and gets there through its internal position
loop: a first-order approach with time constant ``tau_s`` whose speed is
capped at its rated speed (``s_per_60deg`` on a horn of ``horn_mm`` radius). Travel is linear in pulse
width: ``mm = (pulse - pulse_zero_us) * mm_per_us``, the same map as the
bridge's ``hw.calibration.ServoCalibration``, so the bridge's tendon command in
mm is what the simulated tendon does, less the servo's own imperfections.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class ServoSpec:
    """Geometry and imperfections of one tendon servo.

    ``deg_per_us`` is the horn rotation per microsecond of pulse (a 90 deg
    servo over 1000..2000 us has 0.09); ``mm_per_us`` follows from the horn."""

    horn_mm: float = 10.0
    deg_per_us: float = 0.09
    pulse_zero_us: float = 1100.0
    pulse_min_us: float = 900.0
    pulse_max_us: float = 2100.0
    s_per_60deg: float = 0.10
    deadband_us: float = 2.0
    quantum_us: float = 0.25
    tau_s: float = 0.02  # position-loop time constant of small moves

    def __post_init__(self) -> None:
        if not (self.horn_mm > 0 and self.deg_per_us > 0 and self.s_per_60deg > 0):
            raise ValueError("horn radius, deg per us and speed must be positive")
        if self.deadband_us < 0 or self.quantum_us < 0 or self.tau_s < 0:
            raise ValueError("deadband, quantum and time constant cannot be negative")
        if not self.pulse_min_us < self.pulse_max_us:
            raise ValueError("pulse_min_us must be below pulse_max_us")

    @property
    def mm_per_us(self) -> float:
        """Tendon travel per microsecond of pulse (arc length on the horn)."""
        return self.horn_mm * math.radians(self.deg_per_us)

    @property
    def max_speed_us_s(self) -> float:
        """Slew limit in pulse microseconds per second."""
        return 60.0 / self.s_per_60deg / self.deg_per_us

    @property
    def max_speed_mm_s(self) -> float:
        """Slew limit in tendon mm per second."""
        return self.max_speed_us_s * self.mm_per_us

    def mm_of(self, pulse_us: float) -> float:
        """Tendon travel for a (steady) servo position in pulse units."""
        return (pulse_us - self.pulse_zero_us) * self.mm_per_us

    def pulse_of(self, mm: float) -> float:
        """Pulse width that holds the tendon at ``mm``."""
        return self.pulse_zero_us + mm / self.mm_per_us


class ServoModel:
    """One servo's state: ``step(t, pulse_us)`` moves it to time t and returns tendon mm."""

    def __init__(self, spec: ServoSpec = ServoSpec(), t0: float = 0.0, pulse0_us: float | None = None) -> None:
        self.spec = spec
        self.t = float(t0)
        p0 = spec.pulse_zero_us if pulse0_us is None else float(pulse0_us)
        self.position_us = self._clamp(self._quantise(p0))

    def _quantise(self, pulse_us: float) -> float:
        q = self.spec.quantum_us
        return round(pulse_us / q) * q if q > 0 else pulse_us

    def _clamp(self, pulse_us: float) -> float:
        return min(max(pulse_us, self.spec.pulse_min_us), self.spec.pulse_max_us)

    @property
    def mm(self) -> float:
        """Current tendon travel (mm)."""
        return self.spec.mm_of(self.position_us)

    def step(self, t: float, pulse_us: float) -> float:
        """Advance to time ``t`` (s) with ``pulse_us`` commanded since the last step."""
        dt = max(float(t) - self.t, 0.0)
        self.t = float(t)
        if not math.isfinite(pulse_us):
            return self.mm  # a servo given no valid pulse holds
        target = self._clamp(self._quantise(float(pulse_us)))
        half = 0.5 * self.spec.deadband_us
        err = target - self.position_us
        if abs(err) > half:
            goal = target - math.copysign(half, err)
            d = goal - self.position_us
            tau = self.spec.tau_s
            if tau > 0:
                d *= -math.expm1(-dt / tau)
            max_move = self.spec.max_speed_us_s * dt
            self.position_us += max(-max_move, min(max_move, d))
        return self.mm
