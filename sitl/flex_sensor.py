"""A simulated flex sensor on the servo board's 10-bit ADC: warp (deg) -> counts.

The resistive flex sensor sits in a conditioning bridge that spans the warp
range over most of the ADC (about 28 counts per degree, slightly curved, as a
real divider is). A reading adds Gaussian noise in degrees, then quantises to
whole counts in 0..1023. ``calibration_table`` samples the same curve into the
``counts=[...]``/``deg=[...]`` pairs the bridge's sensor calibration takes
(``[wing.*.sensor]`` in the config, ``hw.calibration.SensorCalibration``), so a
bridge given that table reads back the warp to within its interpolation error
(below 0.01 deg).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ADC_MAX = 1023


@dataclass(frozen=True)
class FlexSensorSpec:
    """counts(w) = mid + slope (w - w_mid) + curve (w - w_mid)^2, plus noise_deg RMS of noise."""

    mid_counts: float = 512.0
    w_mid_deg: float = 10.0
    slope_counts_per_deg: float = 28.0
    curve_counts_per_deg2: float = -0.15
    noise_deg: float = 0.03
    table_lo_deg: float = -5.0
    table_hi_deg: float = 25.0
    table_step_deg: float = 2.5

    def __post_init__(self) -> None:
        if self.slope_counts_per_deg <= 0 or self.noise_deg < 0:
            raise ValueError("sensor slope must be positive and noise non-negative")
        for w in (self.table_lo_deg, self.table_hi_deg):
            if 2 * self.curve_counts_per_deg2 * (w - self.w_mid_deg) + self.slope_counts_per_deg <= 0:
                raise ValueError("sensor curve must stay monotone over its table")

    def counts_exact(self, w_deg):
        """Noise-free, unquantised ADC reading for warp ``w_deg`` (array or float)."""
        d = np.asarray(w_deg, dtype=np.float64) - self.w_mid_deg
        return self.mid_counts + self.slope_counts_per_deg * d + self.curve_counts_per_deg2 * d * d

    def calibration_table(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """(counts, deg): the calibration a careful bench calibration of this sensor yields."""
        deg = np.arange(self.table_lo_deg, self.table_hi_deg + 1e-9, self.table_step_deg)
        counts = self.counts_exact(deg)
        return tuple(round(float(c), 2) for c in counts), tuple(float(d) for d in deg)

    def deg_of_counts(self, counts):
        """Warp (deg) from counts through the calibration table (what the bridge computes)."""
        c, d = self.calibration_table()
        return np.interp(counts, c, d)


class FlexSensor:
    """One sensor with its own noise generator: ``read(w_deg) -> counts``."""

    def __init__(self, spec: FlexSensorSpec = FlexSensorSpec(), seed: int = 0) -> None:
        self.spec = spec
        self._rng = np.random.default_rng(seed)

    def skip(self, n: int = 1) -> None:
        """Draw (and drop) the noise of ``n`` readings: a replay keeps the noise sequence of a run
        whose reads it does not all make."""
        if n > 0 and self.spec.noise_deg > 0:
            self._rng.normal(0.0, self.spec.noise_deg, n)

    def read(self, w_deg: float) -> int:
        """A 10-bit ADC reading of the sensor bent to ``w_deg`` (with noise)."""
        if not np.isfinite(w_deg):
            return 0
        noise = self._rng.normal(0.0, self.spec.noise_deg) if self.spec.noise_deg > 0 else 0.0
        c = float(self.spec.counts_exact(w_deg + noise))
        return int(min(max(round(c), 0), ADC_MAX))
