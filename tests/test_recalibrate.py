"""Re-identification of pre-tension and hysteresis width from a calibration record, and the held-out
acceptance rule that decides whether a new model is applied."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from warpbridge.model.boucwen import BoucWenParams, inverse
from warpbridge.model.effects import Effects, fold_rigging
from warpbridge.model.plant import Plant
from warpbridge.model.recalibrate import AcceptRule, RefitResult, Transform, accept, excitation, refit

P = BoucWenParams.paper()
DT = 0.01


def calibration_record(effects: Effects, seconds: float = 20.0, noise: float = 0.03, seed: int = 0):
    """The excitation flown in feed-forward with the base model on a wing re-rigged by ``effects`` (pre-tension
    and friction on the command side, as the recalibration models them; the others as they are)."""
    t = np.arange(int(seconds / DT)) * DT
    w_ref = excitation(t, 1.8, 10.2, start_deg=6.0, seed=seed)
    u, _ = inverse(P, w_ref)
    folded = fold_rigging(P, effects.pretension_offset_mm, effects.pretension_gain, effects.friction_scale)
    rest = replace(effects, pretension_offset_mm=0.0, pretension_gain=1.0, friction_scale=1.0)
    _, w = Plant(folded, rest).simulate(t, u)
    return t, u, w + np.random.default_rng(seed).normal(0, noise, w.size)


def test_excitation_stays_in_its_range_sweeps_it_and_reverses_often():
    t = np.arange(2000) * DT
    w = excitation(t, 2.0, 10.0, start_deg=6.0, seed=3)
    assert w[0] == pytest.approx(6.0) and abs(w[-1] - 6.0) < 0.05
    assert w.min() >= 2.0 and w.max() <= 10.0
    assert w.max() > 9.9 and w.min() < 2.1  # the opening sweep covers the range
    reversals = np.sum(np.diff(np.sign(np.diff(w[t > 4.0]))) != 0)
    assert reversals >= 8
    with pytest.raises(ValueError):
        excitation(t, 5.0, 5.0)


def test_refit_recovers_offset_gain_and_width_and_is_accepted():
    eff = Effects(pretension_offset_mm=0.6, pretension_gain=1.08, friction_scale=1.25, delay_s=0.0)
    t, u, w = calibration_record(eff)
    res = refit(P, t, u, w)
    tf = res.transform
    assert tf.offset == pytest.approx(0.6, abs=0.05)
    assert tf.gain == pytest.approx(1.08, abs=0.01)
    assert tf.az_scale == pytest.approx(1.25, abs=0.08)
    assert res.accepted, res.reason
    assert res.heldout_rms < 2 * res.noise and res.old_heldout_rms > 5 * res.heldout_rms
    # the folded model is the transform applied to the base
    assert res.params == Transform(tf.offset, tf.gain, tf.az_scale).apply(P)


def test_a_model_that_still_fits_is_kept():
    t, u, w = calibration_record(Effects())
    res = refit(P, t, u, w)
    assert not res.accepted
    assert "old model still fits" in res.reason


def test_a_tendon_that_slips_during_calibration_is_refused_on_the_held_out_part():
    t, u, w = calibration_record(Effects(pretension_offset_mm=0.5))
    _, _, w_slipped = calibration_record(Effects(pretension_offset_mm=1.3))
    late = t >= 0.75 * t[-1]  # the held-out part: the tendon slipped 0.8 mm after the training part
    w[late] = w_slipped[late]
    res = refit(P, t, u, w)
    assert res.transform.offset == pytest.approx(0.5, abs=0.1)  # the training part was fitted ...
    assert not res.accepted  # ... but the fit does not hold on the held-out part
    assert "above noise bound" in res.reason


def _result(new: float, old: float, noise: float = 0.03, n_held: int = 600) -> RefitResult:
    return RefitResult(Transform(), P, 0.0, new, new, old, noise, 1000, n_held)


@pytest.mark.parametrize("new, old, noise, n_held, ok, why", [
    (0.05, 0.60, 0.03, 600, True, "held-out"),
    (0.05, 0.054, 0.03, 600, False, "old model still fits"),  # better, but by less than 10 %
    (0.05, 0.065, 0.03, 600, False, "old model still fits"),  # 23 % better but only 0.015 deg
    (0.40, 2.00, 0.03, 600, False, "above noise bound"),  # much better, still far from the noise floor
    (0.30, 2.00, 0.06, 600, True, "held-out"),  # a noisier sensor widens the bound
    (math.nan, 1.0, 0.03, 600, False, "no usable held-out"),
    (0.05, 0.60, 0.03, 10, False, "no usable held-out"),
])
def test_acceptance_rule(new, old, noise, n_held, ok, why):
    accepted, reason = accept(_result(new, old, noise, n_held), AcceptRule())
    assert accepted is ok
    assert why in reason


def test_a_fit_at_its_bounds_is_refused():
    accepted, reason = accept(_result(0.05, 0.6), at_bound=["gain"])
    assert not accepted and "bound (gain)" in reason


def test_transform_composition_matches_applying_both():
    base = Transform(0.4, 1.05, 1.1)
    both = base.then(0.2, 0.97)
    w = 6 + 3 * np.sin(np.linspace(0, 20, 800))
    u_base, _ = inverse(base.apply(P), w)
    u_both, _ = inverse(both.apply(P), w)
    np.testing.assert_allclose(u_both, 0.2 + u_base / 0.97, atol=1e-9)
    assert Transform.from_dict(both.to_dict()) == both
    with pytest.raises(ValueError):
        Transform.from_dict({"offset_mm": 0.0, "gain": -1.0})


def test_refit_refuses_a_record_it_cannot_use():
    with pytest.raises(ValueError, match="too short"):
        refit(P, np.arange(50) * DT, np.zeros(50), np.zeros(50))
    t, u, w = calibration_record(Effects(), seconds=10.0)
    w[100] = np.nan
    with pytest.raises(ValueError, match="missing"):
        refit(P, t, u, w)
