"""The warp sensor's own dynamics as one or two first-order lags in cascade, through the plant, the effects
switch, the model file and the diagnosis (the per-sample plant: tests/test_boucwen.py)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from warpbridge.bridge.commands.effects_spec import parse_effects
from warpbridge.bridge.errors import UserError
from warpbridge.model.boucwen import BoucWenParams
from warpbridge.model.diagnosis.problem import Problem
from warpbridge.model.effects import Effects, sensor_filtered
from warpbridge.model.excitation import filtered_random
from warpbridge.model.modelfile import ModelFile
from warpbridge.model.plant import Plant

P = BoucWenParams.paper()
TWO_STAGES = Effects(sensor_tau_s=0.04, sensor_stage_ratio=0.5)


@pytest.mark.parametrize("ratio", [0.0, 0.5, 1.0])
def test_the_sensor_follows_a_step_as_its_lags_in_cascade(ratio):
    """Step response of lags tau1 and tau2 = ratio tau1 in cascade, written out from the differential equations:
    1 - (tau1 e^(-t/tau1) - tau2 e^(-t/tau2)) / (tau1 - tau2), and (1 + t/tau) e^(-t/tau) for equal lags."""
    tau1 = 0.04
    tau2 = ratio * tau1
    t = np.arange(0.0, 0.4, 1e-4)
    w = np.where(t > 0.0, 1.0, 0.0)
    got = sensor_filtered(Effects(sensor_tau_s=tau1, sensor_stage_ratio=ratio), t, w)
    if ratio == 0.0:
        want = 1.0 - np.exp(-t / tau1)
    elif ratio == 1.0:
        want = 1.0 - (1.0 + t / tau1) * np.exp(-t / tau1)
    else:
        want = 1.0 - (tau1 * np.exp(-t / tau1) - tau2 * np.exp(-t / tau2)) / (tau1 - tau2)
    # the input is held over each 0.1 ms sample: the second stage sees its input up to one sample early
    assert np.max(np.abs(got - want)) < 5e-3, np.max(np.abs(got - want))
    assert got[-1] == pytest.approx(1.0, abs=1e-3)


def test_effects_check_and_carry_the_sensor_stages():
    with pytest.raises(ValueError, match="stage ratio"):
        Effects(sensor_tau_s=0.02, sensor_stage_ratio=1.5)
    with pytest.raises(ValueError, match="stage ratio"):
        Effects(sensor_tau_s=0.02, sensor_stage_ratio=-0.1)
    # without a lag there is no second stage either
    assert Effects(sensor_stage_ratio=0.5) == Effects()
    assert TWO_STAGES.active() == ["sensor_lag"]
    assert parse_effects("sensor_lag=0.04:0.5") == TWO_STAGES
    assert parse_effects("sensor_lag=0.04") == Effects(sensor_tau_s=0.04)
    with pytest.raises(UserError, match="stage ratio"):
        parse_effects("sensor_lag=0.04:2")
    back = ModelFile.from_dict(json.loads(json.dumps(ModelFile(P, TWO_STAGES).to_dict())))
    assert back.effects == TWO_STAGES


def test_the_plant_lags_the_measurement_only():
    t = np.arange(0.0, 4.0, 1 / 500)
    u = filtered_random(t, 1.0, 3.0, offset=4.5, seed=2)
    w_true, w_meas = Plant(P, TWO_STAGES).simulate(t, u)
    w_bare, _ = Plant(P, Effects()).simulate(t, u)
    assert np.array_equal(w_true, w_bare)
    np.testing.assert_allclose(w_meas, sensor_filtered(TWO_STAGES, t, w_true), atol=1e-12)


@pytest.mark.parametrize("ratio", [0.0, 1.0])
def test_the_diagnosis_tells_one_lag_from_two(ratio):
    """A first-order sensor comes back with (almost) no second stage, two equal lags with two."""
    fs, dur = 200.0, 20.0
    t = np.arange(int(fs * dur)) / fs
    u = filtered_random(t, 1.0, 4.5, 7.0, seed=5)
    eff = Effects(sensor_tau_s=0.05, sensor_stage_ratio=ratio)
    _, w = Plant(P, eff).simulate(t, u)
    w = w + 0.03 * np.random.default_rng(6).standard_normal(t.size)
    fit = Problem(t, u, w, None, P, Effects()).fit(("sensor_lag",))
    assert fit.effects.sensor_tau_s == pytest.approx(0.05, rel=0.1)
    assert abs(fit.effects.sensor_stage_ratio - ratio) < 0.1, fit.effects.sensor_stage_ratio
    assert math.sqrt(fit.score_mse) < 1.2 * 0.03
