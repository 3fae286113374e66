"""A friction change that scales the hysteresis band about a level inside it (``friction_pivot``): which level
stays put, its checks, the model file, the effects switch, the feed-forward and the diagnosis's fit."""

from __future__ import annotations

import json
import math
from functools import partial

import numpy as np
import pytest
from helpers import feedforward_rms

from warpbridge.bridge.commands.effects_spec import parse_effects
from warpbridge.bridge.errors import UserError
from warpbridge.model.boucwen import BoucWenParams, forward, inverse
from warpbridge.model.diagnosis.problem import Problem
from warpbridge.model.effect_registry import EFFECT_FIELDS
from warpbridge.model.effects import BAND_FIELDS, CAPSTAN_FIELDS, Effects, core_params, form_fields
from warpbridge.model.excitation import filtered_random
from warpbridge.model.modelfile import ModelFile
from warpbridge.model.plant import Plant

P = BoucWenParams.paper()


def branches(eff: Effects) -> tuple[np.ndarray, np.ndarray]:
    """Warp on the saturated parts of the loading and unloading branches of a large loop (positive warp)."""
    n = 1301
    x = np.concatenate([np.linspace(0.5, 7.0, n), np.linspace(7.0, 0.5, n)[1:], np.linspace(0.5, 7.0, n)[1:]])
    w, _, _ = forward(core_params(P, eff), x, z0=0.0)
    up = w[2 * n - 2:][900:]  # the second loading run, its last 2 mm of travel
    down = w[n - 1:2 * n - 1][::-1][:400]  # the unloading run, its last 2 mm, in increasing travel
    return up, down


@pytest.mark.parametrize("scale", [0.7, 1.5])
def test_the_pivot_names_the_level_of_the_band_that_stays_put(scale):
    up0, down0 = branches(Effects())
    up, down = branches(Effects(friction_scale=scale, friction_pivot=1.0))
    np.testing.assert_allclose(up, up0, atol=1e-6)  # +1: the loading edge stays
    assert np.max(np.abs(down - down0)) > 0.2
    up, down = branches(Effects(friction_scale=scale, friction_pivot=-1.0))
    np.testing.assert_allclose(down, down0, atol=1e-6)  # -1: the unloading edge stays
    assert np.max(np.abs(up - up0)) > 0.2
    # 0 (the default): the loop widens or narrows about its middle, so one branch moves up and the other down
    up, down = branches(Effects(friction_scale=scale))
    assert np.median(up - up0) * np.median(down - down0) < 0


def test_the_pivot_is_checked_and_means_nothing_without_a_friction_change():
    for bad in (-1.01, 1.5, math.nan):
        with pytest.raises(ValueError, match="pivot|number"):
            Effects(friction_scale=1.2, friction_pivot=bad)
    assert Effects(friction_pivot=0.6) == Effects()
    assert Effects(friction_pivot=0.6).active() == []
    eff = Effects(friction_scale=1.2, friction_pivot=-0.4)
    assert eff.active() == ["friction"]
    assert form_fields("friction", eff) == ("friction_scale", "friction_pivot")
    # friction's two forms share out its parameters: each belongs to exactly one
    assert sorted(BAND_FIELDS + CAPSTAN_FIELDS) == sorted(EFFECT_FIELDS["friction"][0])
    assert form_fields("friction", Effects(capstan_pull_ratio=0.05)) == CAPSTAN_FIELDS


def test_the_model_file_and_the_effects_switch_carry_the_pivot():
    eff = Effects(friction_scale=1.25, friction_pivot=0.5)
    back = ModelFile.from_dict(json.loads(json.dumps(ModelFile(P, eff).to_dict())))
    assert back.effects == eff
    assert parse_effects("friction=1.25,friction_pivot=0.5") == eff
    with pytest.raises(UserError, match="pivot"):
        parse_effects("friction=1.25,friction_pivot=2")
    # a file of this version without the pivot reads as the band scaled about its middle
    doc = ModelFile(P, Effects(friction_scale=1.25)).to_dict()
    doc["effects"]["friction"].pop("friction_pivot", None)
    assert ModelFile.from_dict(doc).effects.friction_pivot == 0.0


def test_the_feed_forward_inverts_a_pivoted_friction_change():
    eff = Effects(friction_scale=1.4, friction_pivot=0.8)
    rms_error = partial(feedforward_rms, P, eff)
    exact, unpivoted = rms_error(eff), rms_error(Effects(friction_scale=1.4))
    assert exact < 0.02
    assert unpivoted > 5 * max(exact, 0.01)


@pytest.mark.parametrize("scale,pivot", [(1.3, 0.6), (0.75, -0.5)])
def test_the_diagnosis_recovers_the_scale_and_the_level_it_keeps(scale, pivot):
    fs, noise = 200.0, 0.03
    t = np.arange(int(20 * fs)) / fs
    u, _ = inverse(P, filtered_random(t, 1.0, 4.5, 7.0, seed=5))
    truth = Effects(friction_scale=scale, friction_pivot=pivot)
    _, w = Plant(P, truth).simulate(t, u)
    w = w + noise * np.random.default_rng(6).standard_normal(t.size)
    fit = Problem(t, u, w, None, P, Effects()).fit(("friction",))
    assert fit.params_of["friction"] == 2
    assert fit.effects.friction_scale == pytest.approx(scale, abs=0.03)
    assert fit.effects.friction_pivot == pytest.approx(pivot, abs=0.1)
    assert math.sqrt(fit.score_mse) < 1.3 * noise
