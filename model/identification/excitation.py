"""Step 2 of identification, ``excite check``: how many reversals the training part holds, at which
levels of the warp range, over how wide a band (``excitation_check``); what a log does not excite is said,
and the parameters it leaves open are flagged by the uncertainty step (``uncertainty``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from warpbridge.model.signals import central_range, turning_indices, turning_points

MIN_TURNING_POINTS = 4  # reversals (5 % of the span or more) the training part needs to pin the loop down
NARROW_NOISES = 20.0  # a training warp band narrower than this many noise deviations is narrow


@dataclass
class Excitation:
    """What the training part excites: turning points of the input (5 % of its span or more), where in the
    warp range the warp turns back (maxima and minima per third of the training warp band), the band's width
    (deg and noise deviations), and one line per shortcoming (``notes``); ``poor`` when there is one."""

    turning_points: int
    maxima_per_third: tuple[int, int, int]
    minima_per_third: tuple[int, int, int]
    band_deg: float
    band_noises: float
    notes: list[str] = field(default_factory=list)

    @property
    def poor(self) -> bool:
        return bool(self.notes)

    def to_dict(self) -> dict:
        return {"turning_points": self.turning_points, "maxima_per_third": list(self.maxima_per_third),
                "minima_per_third": list(self.minima_per_third), "band_deg": self.band_deg,
                "band_noises": self.band_noises if math.isfinite(self.band_noises) else None,
                "poor": self.poor, "notes": list(self.notes)}


def excitation_check(u: np.ndarray, w: np.ndarray, noise: float) -> Excitation:
    """Step 2: how well the training part (``u``, ``w``) excites the model, and what it leaves open."""
    k = turning_points(u)
    lo, hi = central_range(w)
    band = hi - lo
    thr = max(0.05 * band, 10.0 * noise if math.isfinite(noise) else 0.0)
    turns = turning_indices(w, thr) if thr > 0 else np.zeros(0, dtype=np.int64)
    maxima, minima = [0, 0, 0], [0, 0, 0]
    for i in turns:
        prev = w[max(i - 1, 0)]
        third = int(min(2, max(0, (w[i] - lo) / band * 3))) if band > 0 else 1
        (maxima if w[i] >= prev else minima)[third] += 1
    band_noises = band / noise if noise > 0 and math.isfinite(noise) else math.inf
    notes = []
    if k < MIN_TURNING_POINTS:
        notes.append(f"too little excitation: the tendon input turns back only {k} times in the training part "
                     f"(at least {MIN_TURNING_POINTS} needed): the loop's shape is not pinned down")
    if band_noises < NARROW_NOISES:
        notes.append(f"a narrow band: the training warp spans {band:.3g} deg, {band_noises:.0f} noise deviations "
                     f"(under {NARROW_NOISES:.0f}): the backbone's curvature and the saturation are not pinned down")
    if k >= MIN_TURNING_POINTS:
        where = ("lower", "middle", "upper")
        no_max = [where[i] for i in range(3) if maxima[i] == 0]
        no_min = [where[i] for i in range(3) if minima[i] == 0]
        if sum(1 for x in maxima if x) + sum(1 for x in minima if x) <= 2:
            notes.append("reversals at one level only (the warp turns back at the same heights every time): the "
                         "return from a reversal inside the loop (minor loops) is not excited, so the return "
                         "ratios rest on the model's form")
        elif no_max == ["lower", "middle"] and no_min == ["middle", "upper"]:
            notes.append("the warp turns back only at the band's ends: minor loops are not excited")
    return Excitation(k, tuple(maxima), tuple(minima), float(band), float(band_noises), notes)
