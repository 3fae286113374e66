"""What a verdict leaves: the scored block that holds most of the held-out residual above the floor.

The held-out test names an effect only from what the training blocks show. An effect that acts in one
stretch of a log alone (a slew limit reached in one fast excursion, a load at the top airspeed only) is
fitted where it does nothing and stays in the residual of the block it acts in. ``left_over`` says so when
what the verdict leaves is material (at least the decision's material gain x the floor, per sample, on
the scored blocks) and one scored block holds most of it, and names what that block has that no training
block has: faster motion, tendon travel outside theirs, a higher airspeed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from warpbridge.model.diagnosis.blocks import Split, input_speed
from warpbridge.model.diagnosis.records import Record


def _peak(x: np.ndarray) -> float:
    return float(np.percentile(x, 99)) if x.size else 0.0


@dataclass(frozen=True, kw_only=True)
class LeftOver(Record):
    """Where the residual a verdict leaves on the scored blocks lies: the held-out RMS against the floor, the
    scored block holding the largest share of the excess (its time span, share, peak input speed, input range
    and peak airspeed against the training blocks'), whether it holds most of it, and what in it the training
    blocks never reach."""

    OPTIONAL = ("block_peak_airspeed_m_s", "train_peak_airspeed_m_s")
    heldout_rms_deg: float
    floor_deg: float
    block_s: list[float]
    share_of_excess: float
    mostly: bool
    block_peak_speed_mm_s: float
    train_peak_speed_mm_s: float
    block_travel_mm: list[float]
    train_travel_mm: list[float] | None
    block_peak_airspeed_m_s: float | None = None
    train_peak_airspeed_m_s: float | None = None
    beyond_training: list[str]


def left_over(t: np.ndarray, u: np.ndarray, r_after: np.ndarray, split: Split, floor2: float, min_gain: float,
              airspeed: np.ndarray | None = None) -> LeftOver | None:
    """Where the residual ``r_after`` (deg) the verdict leaves on the scored blocks lies above ``floor2``
    (deg^2); None when what it leaves is under ``min_gain`` x the floor per scored sample. The peak input
    speed is the 99th percentile, as ``make_split`` measures it; the training blocks' is the fastest of them,
    their range their joint one, their airspeed their peak; ``mostly``: that block holds more than half of
    the excess."""
    score = split.score
    if not score.any() or not floor2 > 0:
        return None
    r2 = r_after ** 2
    excess = float(np.mean(r2[score])) - floor2
    if excess < min_gain * floor2:
        return None
    scored = [(i0, i1) for i0, i1, kind in split.blocks if kind == "score"]
    per_block = [max(float(np.sum(r2[i0:i1])) - (i1 - i0) * floor2, 0.0) for i0, i1 in scored]  # noise cancels
    total = sum(per_block)
    if not total > 0:
        return None
    b = int(np.argmax(per_block))
    i0, i1 = scored[b]
    fs = (t.size - 1) / max(float(t[-1] - t[0]), 1e-12)
    speed = input_speed(t, u, fs)
    train = split.train
    in_block = np.zeros(t.size, bool)
    in_block[i0:i1] = True
    train_peak = max((_peak(speed[j0:j1]) for j0, j1, kind in split.blocks if kind == "train"), default=0.0)
    block_speed = _peak(speed[in_block])
    block_travel = [float(np.min(u[in_block])), float(np.max(u[in_block]))]
    train_travel = [float(np.min(u[train])), float(np.max(u[train]))] if train.any() else None
    beyond = []
    if block_speed > train_peak:
        beyond.append("faster motion")
    if train_travel is not None and (block_travel[0] < train_travel[0] or block_travel[1] > train_travel[1]):
        beyond.append("tendon travel")
    block_air = train_air = None
    if airspeed is not None and train.any():
        a = np.asarray(airspeed, dtype=np.float64)
        block_air, train_air = float(np.nanmax(a[in_block])), float(np.nanmax(a[train]))
        if block_air > train_air:
            beyond.append("airspeed")
    return LeftOver(heldout_rms_deg=math.sqrt(float(np.mean(r2[score]))), floor_deg=math.sqrt(floor2),
                    block_s=[float(t[i0]), float(t[i1 - 1])], share_of_excess=per_block[b] / total,
                    mostly=per_block[b] > 0.5 * total, block_peak_speed_mm_s=block_speed,
                    train_peak_speed_mm_s=train_peak, block_travel_mm=block_travel, train_travel_mm=train_travel,
                    block_peak_airspeed_m_s=block_air, train_peak_airspeed_m_s=train_air, beyond_training=beyond)


def left_over_note(lo: LeftOver | None, named: bool) -> str | None:
    """The report's note on ``left_over``'s finding, when one block holds most of what is left."""
    if lo is None or not lo.mostly:
        return None
    what = "the verdict leaves" if named else "the nominal model leaves"
    a, b = lo.block_s
    text = (f"{what} {lo.heldout_rms_deg:.3f} deg held out against a floor of {lo.floor_deg:.3f}, "
            f"{lo.share_of_excess:.0%} of the excess in one scored block (t = {a:.1f}-{b:.1f} s)")
    why = []
    if "faster motion" in lo.beyond_training:
        why.append(f"the command moves faster there ({lo.block_peak_speed_mm_s:.3g} mm/s) than in any block "
                   f"the fit trained on ({lo.train_peak_speed_mm_s:.3g} mm/s at most)")
    if "tendon travel" in lo.beyond_training:
        why.append("the tendon travels outside the training blocks' range there "
                   f"({lo.block_travel_mm[0]:.3g}-{lo.block_travel_mm[1]:.3g} mm against "
                   f"{lo.train_travel_mm[0]:.3g}-{lo.train_travel_mm[1]:.3g})")
    if "airspeed" in lo.beyond_training:
        why.append(f"it flies faster there ({lo.block_peak_airspeed_m_s:.3g} m/s against "
                   f"{lo.train_peak_airspeed_m_s:.3g})")
    if why:
        text += (": " + "; ".join(why) + ". An effect that acts only there (a slew limit reached only there, a "
                 "load at the top airspeed) cannot be fitted from the other blocks and is not named; a log with "
                 "such stretches spread over its length would tell")
    else:
        text += ": an effect that acts in that stretch alone cannot be fitted from the other blocks and is not named"
    return text
