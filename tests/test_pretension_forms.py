"""Pre-tension's two forms: the backbone moved alone, or the whole loop (the friction band with it)."""

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
from warpbridge.model.effects import Effects, core_params, form_fields, form_parameters
from warpbridge.model.excitation import filtered_random
from warpbridge.model.modelfile import ModelFile
from warpbridge.model.plant import Plant

P = BoucWenParams.paper()


def band_width_mm(eff: Effects, level: float = 7.0) -> float:
    """Tendon travel between the loading and the unloading branch of a large loop at warp ``level``."""
    n = 2001
    x = np.concatenate([np.linspace(-2.0, 12.0, n), np.linspace(12.0, -2.0, n)[1:], np.linspace(-2.0, 12.0, n)[1:]])
    w, _, _ = forward(core_params(P, eff), x, z0=0.0)
    up_x, up_w = x[2 * n - 2:], w[2 * n - 2:]
    down_x, down_w = x[n - 1:2 * n - 1][::-1], w[n - 1:2 * n - 1][::-1]
    return float(np.interp(level, up_w, up_x) - np.interp(level, down_w, down_x))  # pulling takes more


def test_the_whole_loop_form_scales_the_band_with_the_backbone():
    w0 = band_width_mm(Effects())
    assert w0 > 0.3
    gain = 1.5
    backbone = Effects(pretension_offset_mm=0.4, pretension_gain=gain)
    whole = Effects(pretension_offset_mm=0.4, pretension_gain=gain, pretension_loop=1.0)
    assert band_width_mm(backbone) == pytest.approx(w0, rel=0.02)  # the band stays
    assert band_width_mm(whole) == pytest.approx(w0 / gain, rel=0.02)  # the band follows the tension
    # the same rest point either way at the band's middle
    assert core_params(P, whole).a3 == pytest.approx(core_params(P, backbone).a3)


def test_the_form_flag_is_checked_carried_and_alone_changes_nothing():
    for bad in (0.5, -1.0, 2.0, math.nan):
        with pytest.raises(ValueError, match="pretension_loop|number"):
            Effects(pretension_offset_mm=0.2, pretension_loop=bad)
    assert Effects(pretension_loop=1.0).active() == []
    assert Effects(pretension_loop=1.0).to_dict() == {}
    eff = Effects(pretension_offset_mm=0.3, pretension_gain=1.2, pretension_loop=1.0)
    assert eff.active() == ["pretension"]
    assert form_fields("pretension", eff) == ("pretension_offset_mm", "pretension_gain", "pretension_loop")
    assert form_parameters("pretension", eff) == 2
    first = Effects(pretension_offset_mm=0.3, pretension_gain=1.2)
    assert form_fields("pretension", first) == ("pretension_offset_mm", "pretension_gain")
    assert "pretension_loop" not in first.to_dict()["pretension"]  # files of the first form are as before
    back = ModelFile.from_dict(json.loads(json.dumps(ModelFile(P, eff).to_dict())))
    assert back.effects == eff
    assert parse_effects("pretension=0.3:1.2:1") == eff
    with pytest.raises(UserError, match="pretension_loop"):
        parse_effects("pretension=0.3:1.2:0.5")


def test_the_feed_forward_inverts_the_whole_loop_form():
    eff = Effects(pretension_offset_mm=0.5, pretension_gain=1.3, pretension_loop=1.0)
    rms_error = partial(feedforward_rms, P, eff)
    exact = rms_error(eff)
    backbone_only = rms_error(Effects(pretension_offset_mm=0.5, pretension_gain=1.3))
    assert exact < 0.02
    assert backbone_only > 5 * max(exact, 0.01)


@pytest.mark.parametrize("loop,offset,gain", [(0.0, 0.2, 1.15), (1.0, 0.2, 1.15), (0.0, -0.3, 0.8), (1.0, -0.3, 0.8)])
def test_the_diagnosis_fits_both_forms_and_keeps_the_one_of_the_log(loop, offset, gain):
    fs, noise = 200.0, 0.03
    t = np.arange(int(20 * fs)) / fs
    u, _ = inverse(P, filtered_random(t, 1.0, 4.5, 7.0, seed=5))
    truth = Effects(pretension_offset_mm=offset, pretension_gain=gain, pretension_loop=loop)
    _, w = Plant(P, truth).simulate(t, u)
    w = w + noise * np.random.default_rng(6).standard_normal(t.size)
    fit = Problem(t, u, w, None, P, Effects()).fit(("pretension",))
    assert fit.effects.pretension_loop == loop
    assert fit.params_of["pretension"] == 2
    assert fit.effects.pretension_gain == pytest.approx(gain, rel=0.02)
    assert fit.effects.pretension_offset_mm == pytest.approx(offset, abs=0.03)
    assert fit.values()["pretension"].get("pretension_loop", 0.0) == loop
    assert math.sqrt(fit.score_mse) < 1.3 * noise


def test_a_nominal_of_the_whole_loop_form_still_tries_the_backbone_form():
    fs, noise = 200.0, 0.03
    t = np.arange(int(20 * fs)) / fs
    u, _ = inverse(P, filtered_random(t, 1.0, 4.5, 7.0, seed=5))
    nominal = Effects(pretension_offset_mm=0.1, pretension_gain=1.05, pretension_loop=1.0)
    truth = Effects(pretension_offset_mm=-0.3, pretension_gain=0.8)
    _, w = Plant(P, truth).simulate(t, u)
    w = w + noise * np.random.default_rng(6).standard_normal(t.size)
    fit = Problem(t, u, w, None, P, nominal).fit(("pretension",))
    assert fit.effects.pretension_loop == 0.0
    assert fit.effects.pretension_gain == pytest.approx(0.8, rel=0.02)
