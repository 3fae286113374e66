"""Mixer: the flight controller's aileron PWM -> one warp setpoint (deg) per wing.

Sign convention: a positive aileron (roll right) makes the LEFT wing gain lift.
Per wing, the source channel's PWM is normalised to ``a`` in [-1, 1] around
``pwm_trim`` (scaled separately below and above trim) and negated when the wing
is ``reverse``; ``a > 0`` then means "this wing must gain lift". With one shared
aileron output the right wing is the reversed one; with two outputs each is set
so that "above trim" means "gain lift".

A tendon only pulls, so each wing's warp is one-sided, within [0, max_warp_deg]::

    a >= 0:  w = bias + a (max_warp - bias)     (gains lift: towards max_warp)
    a <  0:  w = bias (1 + a)                   (relaxes: towards 0)

With ``bias_deg = 0`` a wing only pulls when it must gain lift; with a pre-warp
bias both wings sit at ``bias`` at neutral and can move both ways. Absurd or
missing PWM (0, 65535, outside [pwm_min - 200, pwm_max + 200]) gives ``None``
for that wing: the app then holds the wing at its neutral warp.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol

PWM_MARGIN_US = 200.0  # PWM further than this outside [pwm_min, pwm_max] is invalid


class MixSettings(Protocol):
    """What a wing's configuration holds for the mixer (``config.WingConfig`` is one)."""

    source_channel: int
    reverse: bool
    pwm_min: float
    pwm_trim: float
    pwm_max: float
    max_warp_deg: float
    bias_deg: float


@dataclass(frozen=True)
class WingMix:
    """The part of a wing's configuration the mixer uses."""

    source_channel: int
    reverse: bool
    pwm_min: float
    pwm_trim: float
    pwm_max: float
    max_warp_deg: float
    bias_deg: float

    @classmethod
    def from_config(cls, w: MixSettings) -> WingMix:
        return cls(w.source_channel, w.reverse, w.pwm_min, w.pwm_trim, w.pwm_max, w.max_warp_deg, w.bias_deg)

    def normalise(self, pwm: float | None) -> float | None:
        """PWM (us) -> aileron in [-1, 1], positive = this wing gains lift; None if invalid."""
        if pwm is None or not math.isfinite(pwm) or pwm <= 0 or pwm >= 65535:
            return None
        if pwm < self.pwm_min - PWM_MARGIN_US or pwm > self.pwm_max + PWM_MARGIN_US:
            return None
        if pwm >= self.pwm_trim:
            a = (pwm - self.pwm_trim) / (self.pwm_max - self.pwm_trim)
        else:
            a = (pwm - self.pwm_trim) / (self.pwm_trim - self.pwm_min)
        a = min(1.0, max(-1.0, a))
        return -a if self.reverse else a

    def warp(self, a: float) -> float:
        """Normalised aileron -> warp setpoint (deg), clamped to [0, max_warp_deg]."""
        bias = min(max(self.bias_deg, 0.0), self.max_warp_deg)
        w = bias + a * (self.max_warp_deg - bias) if a >= 0 else bias * (1.0 + a)
        return min(self.max_warp_deg, max(0.0, w))

    @property
    def deg_per_us(self) -> float:
        """Steepest warp change per microsecond of PWM (deg/us), above or below trim."""
        bias = min(max(self.bias_deg, 0.0), self.max_warp_deg)
        return max((self.max_warp_deg - bias) / (self.pwm_max - self.pwm_trim),
                   bias / (self.pwm_trim - self.pwm_min))

    def jitter_deadband(self, jitter_us: float) -> float:
        """Half-width (deg) of the setpoint play that absorbs +-``jitter_us`` of PWM jitter."""
        return max(0.0, float(jitter_us)) * self.deg_per_us

    @property
    def neutral_deg(self) -> float:
        """Warp held at neutral aileron and in failsafe."""
        return self.warp(0.0)


class Mixer:
    """Both wings' mixes; ``setpoints(pwm_by_channel)`` -> ``{"left": deg | None, "right": deg | None}``."""

    def __init__(self, wings) -> None:
        """``wings``: a ``Config`` or a mapping of wing name -> ``WingConfig`` | ``WingMix``."""
        wings = getattr(wings, "wings", wings)
        self.wings: dict[str, WingMix] = {
            name: w if isinstance(w, WingMix) else WingMix.from_config(w) for name, w in wings.items()
        }

    def retune(self, *, max_warp_deg: float | None = None, bias_deg: float | None = None) -> None:
        """Change the warp range of both wings live (WB_MAXWARP, WB_BIAS); bias is capped at max."""
        for name, w in self.wings.items():
            mx = w.max_warp_deg if max_warp_deg is None else float(max_warp_deg)
            b = w.bias_deg if bias_deg is None else float(bias_deg)
            self.wings[name] = WingMix(w.source_channel, w.reverse, w.pwm_min, w.pwm_trim, w.pwm_max,
                                       mx, min(b, mx))

    def aileron(self, pwm_by_channel: Mapping[int, float]) -> dict[str, float | None]:
        """Normalised aileron per wing (positive = gains lift), None where the PWM is invalid."""
        return {name: w.normalise(pwm_by_channel.get(w.source_channel)) for name, w in self.wings.items()}

    def setpoints(self, pwm_by_channel: Mapping[int, float]) -> dict[str, float | None]:
        """Warp setpoint (deg) per wing, None where the PWM is missing or invalid."""
        out: dict[str, float | None] = {}
        for name, a in self.aileron(pwm_by_channel).items():
            out[name] = None if a is None else self.wings[name].warp(a)
        return out

    def neutral(self) -> dict[str, float]:
        """Neutral (failsafe) warp per wing: the bias."""
        return {name: w.neutral_deg for name, w in self.wings.items()}
