"""Calibrations: servo pulse (us) <-> tendon travel (mm), sensor counts <-> warp (deg).

Both come from the TOML config as plain dicts and go back with ``to_dict``:

``ServoCalibration``: ``{"pulse_min_us", "pulse_max_us", "pulse_zero_us", "mm_per_us"}``
and optionally ``"quantum_us"`` (0.25 = the Maestro's step, 0 = none). Instead of
``mm_per_us`` the dict may give the servo horn: ``"horn_radius_mm"`` and ``"deg_per_us"``
(servo shaft rotation per microsecond; negative for a servo pulling on shorter pulses).
``pulse_zero_us`` is the pulse at zero tendon travel (tendon just taut).

``SensorCalibration``: ``{"counts": [...], "deg": [...]}``, a table interpolated
piecewise linearly; both columns strictly monotone; clamped outside the table.
Validation errors are ``ValueError`` naming the offending key.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

PULSE_BOUNDS_US = (100.0, 3000.0)


def _number(d: dict[str, Any], key: str, where: str) -> float:
    if key not in d:
        raise ValueError(f"{where}: missing key {key!r}")
    value = d[key]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{where}: {key} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{where}: {key} must be finite, got {value!r}")
    return float(value)


def _no_extra(d: dict[str, Any], allowed: set[str], where: str) -> None:
    extra = sorted(set(d) - allowed)
    if extra:
        raise ValueError(f"{where}: unknown key(s) {', '.join(extra)} (allowed: {', '.join(sorted(allowed))})")


@dataclass(frozen=True)
class ServoCalibration:
    """Tendon travel u (mm, + = pull) <-> servo pulse (us): u = mm_per_us * (pulse - pulse_zero_us)."""

    pulse_min_us: float
    pulse_max_us: float
    pulse_zero_us: float
    mm_per_us: float
    quantum_us: float = 0.25

    def __post_init__(self) -> None:
        for key in ("pulse_min_us", "pulse_max_us", "pulse_zero_us", "mm_per_us", "quantum_us"):
            if not math.isfinite(getattr(self, key)):
                raise ValueError(f"servo calibration: {key} must be finite, got {getattr(self, key)}")
        lo, hi = PULSE_BOUNDS_US
        if not lo <= self.pulse_min_us < self.pulse_max_us <= hi:
            raise ValueError(
                f"servo calibration: need {lo:g} <= pulse_min_us < pulse_max_us <= {hi:g}, "
                f"got {self.pulse_min_us:g}, {self.pulse_max_us:g}"
            )
        if not self.pulse_min_us <= self.pulse_zero_us <= self.pulse_max_us:
            raise ValueError(
                f"servo calibration: pulse_zero_us {self.pulse_zero_us:g} outside "
                f"[{self.pulse_min_us:g}, {self.pulse_max_us:g}]"
            )
        if self.mm_per_us == 0:
            raise ValueError("servo calibration: mm_per_us must not be 0")
        if self.quantum_us < 0:
            raise ValueError(f"servo calibration: quantum_us must be >= 0, got {self.quantum_us}")
        if self.quantum_us > 0 and self._grid_hi() < self._grid_lo():
            raise ValueError("servo calibration: no quantised pulse lies within the pulse range")

    @classmethod
    def from_horn(
        cls,
        horn_radius_mm: float,
        deg_per_us: float,
        pulse_zero_us: float,
        pulse_min_us: float,
        pulse_max_us: float,
        quantum_us: float = 0.25,
    ) -> ServoCalibration:
        """From the horn radius (mm) and the servo's rotation per microsecond (deg/us)."""
        if not horn_radius_mm > 0:
            raise ValueError(f"servo calibration: horn_radius_mm must be > 0, got {horn_radius_mm}")
        mm_per_us = horn_radius_mm * math.radians(deg_per_us)
        return cls(pulse_min_us, pulse_max_us, pulse_zero_us, mm_per_us, quantum_us)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ServoCalibration:
        """From a config table (see module docstring)."""
        where = "servo calibration"
        base = {"pulse_min_us", "pulse_max_us", "pulse_zero_us", "quantum_us"}
        quantum = _number(d, "quantum_us", where) if "quantum_us" in d else 0.25
        common = [_number(d, k, where) for k in ("pulse_min_us", "pulse_max_us", "pulse_zero_us")]
        if "mm_per_us" in d:
            _no_extra(d, base | {"mm_per_us"}, where)
            return cls(*common, _number(d, "mm_per_us", where), quantum)
        if "horn_radius_mm" in d or "deg_per_us" in d:
            _no_extra(d, base | {"horn_radius_mm", "deg_per_us"}, where)
            horn = _number(d, "horn_radius_mm", where)
            return cls.from_horn(horn, _number(d, "deg_per_us", where), common[2], common[0], common[1], quantum)
        raise ValueError(f"{where}: give mm_per_us, or horn_radius_mm and deg_per_us")

    def to_dict(self) -> dict[str, float]:
        """The config table (``mm_per_us`` form)."""
        return {
            "pulse_min_us": self.pulse_min_us,
            "pulse_max_us": self.pulse_max_us,
            "pulse_zero_us": self.pulse_zero_us,
            "mm_per_us": self.mm_per_us,
            "quantum_us": self.quantum_us,
        }

    def _grid_lo(self) -> float:
        return math.ceil(self.pulse_min_us / self.quantum_us - 1e-9) * self.quantum_us

    def _grid_hi(self) -> float:
        return math.floor(self.pulse_max_us / self.quantum_us + 1e-9) * self.quantum_us

    def clamp_pulse(self, pulse_us: float) -> float:
        """``pulse_us`` within [pulse_min_us, pulse_max_us], on the quantum grid."""
        if not math.isfinite(pulse_us):
            raise ValueError(f"pulse must be finite, got {pulse_us}")
        if self.quantum_us == 0:
            return min(max(pulse_us, self.pulse_min_us), self.pulse_max_us)
        q = round(pulse_us / self.quantum_us) * self.quantum_us
        return min(max(q, self._grid_lo()), self._grid_hi())

    def pulse_for_mm(self, u_mm: float) -> float:
        """Pulse (us) for tendon travel ``u_mm``; clamped and quantised."""
        if not math.isfinite(u_mm):
            raise ValueError(f"tendon travel must be finite, got {u_mm}")
        return self.clamp_pulse(self.pulse_zero_us + u_mm / self.mm_per_us)

    def mm_for_pulse(self, pulse_us: float) -> float:
        """Tendon travel (mm) for ``pulse_us`` (not clamped: what that pulse would do)."""
        return self.mm_per_us * (pulse_us - self.pulse_zero_us)

    @property
    def mm_range(self) -> tuple[float, float]:
        """Tendon travel (mm) reachable within the pulse range, (low, high)."""
        a = self.mm_for_pulse(self.pulse_min_us)
        b = self.mm_for_pulse(self.pulse_max_us)
        return (min(a, b), max(a, b))


def _interp(x: float, xs: list[float], ys: list[float]) -> float:
    """Piecewise-linear ys(x) over increasing xs, held at the ends (``numpy.interp`` without numpy)."""
    x = float(x)
    if math.isnan(x):
        return math.nan
    if x <= xs[0]:
        return ys[0]
    if x >= xs[-1]:
        return ys[-1]
    i = bisect.bisect_right(xs, x)
    x0, x1, y0, y1 = xs[i - 1], xs[i], ys[i - 1], ys[i]
    return y0 + (y1 - y0) * (x - x0) / (x1 - x0)


class SensorCalibration:
    """Sensor counts <-> warp (deg) by a strictly monotone table, clamped at its ends."""

    def __init__(self, counts: Sequence[float], deg: Sequence[float]) -> None:
        where = "sensor calibration"
        try:
            c = [float(x) for x in counts]
            d = [float(x) for x in deg]
        except TypeError:
            raise ValueError(f"{where}: counts and deg must be flat lists") from None
        if len(c) != len(d):
            raise ValueError(f"{where}: counts has {len(c)} entries but deg has {len(d)}")
        if len(c) < 2:
            raise ValueError(f"{where}: need at least 2 points, got {len(c)}")
        for name, col in (("counts", c), ("deg", d)):
            if not all(math.isfinite(x) for x in col):
                raise ValueError(f"{where}: {name} must be finite numbers")
            steps = [b - a for a, b in zip(col, col[1:], strict=False)]
            if not (all(s > 0 for s in steps) or all(s < 0 for s in steps)):
                sign = math.copysign(1.0, steps[0])
                i = next((k for k, s in enumerate(steps) if s * sign <= 0), 0) if steps[0] != 0 else 0
                raise ValueError(
                    f"{where}: {name} must be strictly increasing or strictly decreasing "
                    f"(breaks at entries {i} and {i + 1}: {col[i]:g}, {col[i + 1]:g})"
                )
        self.counts = tuple(c)
        self.deg = tuple(d)
        by_c = sorted(zip(c, d, strict=True))
        self._c_by_c, self._d_by_c = [p[0] for p in by_c], [p[1] for p in by_c]
        by_d = sorted(zip(d, c, strict=True))
        self._d_by_d, self._c_by_d = [p[0] for p in by_d], [p[1] for p in by_d]

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SensorCalibration:
        """From ``{"counts": [...], "deg": [...]}``."""
        where = "sensor calibration"
        _no_extra(d, {"counts", "deg"}, where)
        for key in ("counts", "deg"):
            if key not in d:
                raise ValueError(f"{where}: missing key {key!r}")
            if isinstance(d[key], str | bytes) or not isinstance(d[key], Sequence):
                raise ValueError(f"{where}: {key} must be a list of numbers")
            if any(isinstance(v, bool) or not isinstance(v, int | float) for v in d[key]):
                raise ValueError(f"{where}: {key} must be a list of numbers")
        return cls(d["counts"], d["deg"])

    def to_dict(self) -> dict[str, list[float]]:
        """The config table."""
        return {"counts": list(self.counts), "deg": list(self.deg)}

    def deg_for_counts(self, counts: float) -> float:
        """Warp (deg) for a reading; clamped to the table's range."""
        return _interp(counts, self._c_by_c, self._d_by_c)

    def counts_for_deg(self, deg: float) -> float:
        """Reading expected at warp ``deg``; clamped to the table's range."""
        return _interp(deg, self._d_by_d, self._c_by_d)

    @property
    def deg_range(self) -> tuple[float, float]:
        """Warp (deg) covered by the table, (low, high)."""
        return (min(self.deg), max(self.deg))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, SensorCalibration) and (self.counts, self.deg) == (other.counts, other.deg)

    def __repr__(self) -> str:
        return f"SensorCalibration(counts={list(self.counts)}, deg={list(self.deg)})"
