"""The verdict's effects sized on the whole analysed log once the scored blocks have chosen them."""

from __future__ import annotations

import math

import numpy as np
import pytest

from warpbridge.model.boucwen import BoucWenParams, inverse
from warpbridge.model.diagnosis import diagnose
from warpbridge.model.diagnosis.problem import Problem
from warpbridge.model.effects import Effects, dynamic_pressure_kpa
from warpbridge.model.excitation import filtered_random
from warpbridge.model.modelfile import FitQuality, ModelFile
from warpbridge.model.plant import Plant

FS, NOISE = 200.0, 0.03
P = BoucWenParams.paper()


def make_log(effects: Effects, seed: int, duration: float = 20.0):
    t = np.arange(int(duration * FS)) / FS
    u, _ = inverse(P, filtered_random(t, 1.0, 4.5, 7.0, seed=seed))
    v = filtered_random(t, 0.1, 6.0, 14.0, seed=seed + 100)
    _, w = Plant(P, effects).simulate(t, u, v)
    return t, u, w + NOISE * np.random.default_rng(seed + 1).standard_normal(t.size), v


def test_linear_sizes_are_the_least_squares_solution_on_every_analysed_sample():
    t, u, w, v = make_log(Effects(aero_gain_per_kpa=0.5, aero_deg_per_kpa=2.0), seed=4)
    prob = Problem(t, u, w, v, P, Effects())
    fit = prob.fit(("aero_load",))
    whole = prob.refit_whole(fit, max_evals=60)
    # written out again: w = w_core (1 - g q) - c q, solved on the training and scored blocks together
    m = prob.split.train | prob.split.score
    w_core, q = prob.predict(Effects()), dynamic_pressure_kpa(v)
    g, c = np.linalg.lstsq(np.column_stack([-q * w_core, -q])[m], (w - w_core)[m], rcond=None)[0]
    assert whole.effects.aero_gain_per_kpa == pytest.approx(g, rel=1e-6)
    assert whole.effects.aero_deg_per_kpa == pytest.approx(c, rel=1e-6)
    # the training fit solved it on fewer samples, so the two differ, and each is best on its own samples
    assert whole.effects.aero_gain_per_kpa != fit.effects.aero_gain_per_kpa
    assert prob.mse(whole.w_pred, m) <= prob.mse(fit.w_pred, m)
    assert fit.train_mse <= whole.train_mse
    np.testing.assert_allclose(prob.predict(whole.effects), whole.w_pred, atol=1e-9)


def test_a_nonlinear_size_moves_from_the_training_fits_end_to_the_whole_logs_best():
    t, u, w, v = make_log(Effects(delay_s=0.04), seed=6)
    prob = Problem(t, u, w, v, P, Effects())
    fit = prob.fit(("delay",))
    whole = prob.refit_whole(fit, max_evals=60)
    m = prob.split.train | prob.split.score

    def whole_mse(d: float) -> float:
        return prob.mse(prob.predict(Effects(delay_s=d)), m)

    assert whole.effects.delay_s == pytest.approx(0.04, abs=0.004)
    assert abs(whole.effects.delay_s - fit.effects.delay_s) < 0.004  # a polish near the training fit's end
    assert whole_mse(whole.effects.delay_s) <= whole_mse(fit.effects.delay_s)
    # no better delay on the whole log nearby: the refit is that log's minimum along its parameter
    for d in whole.effects.delay_s + np.array([-2e-3, -5e-4, 5e-4, 2e-3]):
        assert whole_mse(whole.effects.delay_s) <= whole_mse(float(d)) + 1e-12


@pytest.mark.slow
def test_the_report_and_the_model_carry_the_whole_log_sizes_and_the_held_out_figures_stay_the_trainings():
    t, u, w, v = make_log(Effects(backlash_mm=0.15), seed=11)
    model = ModelFile(params=P, fit=FitQuality(train_rms_deg=NOISE, heldout_rms_deg=NOISE, noise_deg=NOISE))
    d = diagnose(t, u, w, v, model)
    rep = d.report
    assert d.verdict == ["backlash"]
    sized = rep["effects"]["backlash"]["backlash_mm"]
    trained = rep["effects_on_training_blocks"]["backlash"]["backlash_mm"]
    assert sized == pytest.approx(0.15, rel=0.1) and trained == pytest.approx(0.15, rel=0.1)
    assert sized != trained
    assert d.model.effects.backlash_mm == sized
    # the held-out RMS is of the training sizes' prediction on the scored blocks, never of the refit
    sc = d.split.score
    after = rep["shrinkage"]["heldout_rms_after_deg"]
    assert after == pytest.approx(math.sqrt(np.mean((d.w - d.w_augmented)[sc] ** 2)))
    prob = Problem(d.t, d.u, d.w, v, P, Effects(), z0=rep["initial_state"]["z0"], split=d.split)
    held = prob.mse(prob.predict(Effects(backlash_mm=trained)), sc)
    assert after == pytest.approx(math.sqrt(held), rel=0.02)
    assert "every analysed sample" in rep["effects_sized_on"]
