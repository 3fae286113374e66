"""A rigged wing relative to its base model: pre-tension offset and gain, hysteresis width.

What a pre-flight calibration (``model.recalibrate``) finds and the bridge
persists and flies; kept apart from the fitting code so that the running bridge
reads a stored calibration without loading the optimiser.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from warpbridge.model.adapt import fold_pretension
from warpbridge.model.boucwen import BoucWenParams


@dataclass(frozen=True)
class Transform:
    """The rigged wing relative to the base model: u = offset + f(w) / gain, the hysteresis band scaled
    by ``az_scale`` (the friction effect, ``model.effects.friction_core``)."""

    offset: float = 0.0  # mm
    gain: float = 1.0
    az_scale: float = 1.0

    def apply(self, base: BoucWenParams) -> BoucWenParams:
        return fold_pretension(base, self.offset, self.gain, self.az_scale)

    def then(self, offset: float, gain: float) -> Transform:
        """This transform followed by a further pre-tension change u = offset + u_this / gain."""
        return Transform(offset + self.offset / gain, self.gain * gain, self.az_scale)

    def to_dict(self) -> dict[str, float]:
        return {"offset_mm": self.offset, "gain": self.gain, "az_scale": self.az_scale}

    @classmethod
    def from_dict(cls, d: dict) -> Transform:
        try:
            t = cls(float(d["offset_mm"]), float(d["gain"]), float(d.get("az_scale", 1.0)))
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(f"bad calibration transform: {e}") from None
        if not (math.isfinite(t.offset) and t.gain > 0 and t.az_scale > 0):
            raise ValueError("calibration transform: offset must be finite, gain and az_scale positive")
        return t
