"""The capstan form of friction: a stall at every reversal that grows with the tension, through the
plant, the feed-forward, the model file, the effects switch and the diagnosis (the per-sample plant:
tests/test_boucwen.py)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from warpbridge.bridge.commands.effects_spec import parse_effects
from warpbridge.bridge.errors import UserError
from warpbridge.model.boucwen import BoucWenParams, inverse
from warpbridge.model.compensation import Compensator
from warpbridge.model.diagnosis.problem import Problem
from warpbridge.model.effects import Effects, apply_input_effects
from warpbridge.model.excitation import filtered_random
from warpbridge.model.modelfile import ModelFile
from warpbridge.model.plant import Plant, PlantStepper

P = BoucWenParams.paper()
CAPSTAN = Effects(capstan_pull_ratio=0.06, capstan_release_ratio=0.03, capstan_zero_mm=-2.0)


def test_the_stall_after_a_reversal_grows_with_the_tension():
    # a ramp up to a peak and back; tendon slack below -2 mm. By hand: pulling, the sheath's end sits
    # 0.06 (x + 2) below the travel; after the reversal it stays put until x + 0.03 (x + 2) comes down to
    # it, then follows that edge
    for peak in (4.0, 10.0):
        x = np.concatenate([np.linspace(0.0, peak, 401), np.linspace(peak, 0.0, 401)[1:]])
        y = apply_input_effects(CAPSTAN, np.arange(x.size) * 0.01, x)
        up = x[:401]
        np.testing.assert_allclose(y[:401], up - 0.06 * (up + 2.0), atol=1e-12)
        top = peak - 0.06 * (peak + 2.0)
        down = x[401:]
        expected = np.minimum(top, down + 0.03 * (down + 2.0))
        np.testing.assert_allclose(y[401:], expected, atol=1e-12)
        # the travel it takes to break away after the reversal: (0.06 + 0.03) (peak + 2), more at more tension
        moved = np.flatnonzero(y[401:] < top - 1e-12)[0]
        assert peak - down[moved] == pytest.approx(0.09 * (peak + 2.0), abs=2 * peak / 400)


@pytest.mark.parametrize("effects", [CAPSTAN, CAPSTAN.merged(Effects(backlash_mm=0.2))])
def test_the_feed_forward_takes_up_the_stall_ahead_of_the_motion(effects):
    t = np.arange(0, 12, 0.01)
    w_sp = filtered_random(t, 1.0, 3.0, offset=7.0, seed=2)
    plant = Plant(P, effects)
    comp = Compensator(plant, w0=w_sp[0])
    wing = PlantStepper(plant, t[0], comp.step(w_sp[0]))
    err = [wing.step(t[k], comp.step(w_sp[k]))[0] - w_sp[k] for k in range(1, t.size)]
    naive = Compensator(Plant(P), w0=w_sp[0])
    wing2 = PlantStepper(plant, t[0], naive.step(w_sp[0]))
    err2 = [wing2.step(t[k], naive.step(w_sp[k]))[0] - w_sp[k] for k in range(1, t.size)]
    rms, rms2 = (float(np.sqrt(np.mean(np.square(e[200:])))) for e in (err, err2))
    assert rms < 0.02
    assert rms2 > 5 * max(rms, 0.01)


def test_effects_check_and_carry_the_capstan_parameters():
    with pytest.raises(ValueError, match="capstan"):
        Effects(capstan_pull_ratio=1.0)
    with pytest.raises(ValueError, match="capstan"):
        Effects(capstan_release_ratio=-0.1)
    with pytest.raises(ValueError, match="capstan"):
        Effects(capstan_pull_ratio=0.1, capstan_zero_mm=math.inf)
    # without a stall the slack travel means nothing, so it does not make friction active
    assert Effects(capstan_zero_mm=-3.0).active() == []
    assert CAPSTAN.active() == ["friction"]
    assert parse_effects("friction=1:0.06:0.03:-2") == CAPSTAN
    with pytest.raises(UserError, match="capstan"):
        parse_effects("friction=1:1.5")
    mf = ModelFile(P, CAPSTAN)
    back = ModelFile.from_dict(json.loads(json.dumps(mf.to_dict())))
    assert back.effects == CAPSTAN


def test_the_diagnosis_fits_the_capstan_form_when_the_stall_grows_with_the_tension():
    fs, noise = 200.0, 0.03
    t = np.arange(int(20 * fs)) / fs
    u, _ = inverse(P, filtered_random(t, 1.0, 4.5, 7.0, seed=5))
    _, w = Plant(P, CAPSTAN).simulate(t, u)
    w = w + noise * np.random.default_rng(6).standard_normal(t.size)
    fit = Problem(t, u, w, None, P, Effects()).fit(("friction",))
    e = fit.effects
    assert e.friction_scale == 1.0 and fit.params_of["friction"] == 3
    # the stalls at the log's middle travel, pulling and releasing, come out as they went in
    mid = float(np.median(u))
    for ratio in ("capstan_pull_ratio", "capstan_release_ratio"):
        want = getattr(CAPSTAN, ratio) * (mid - CAPSTAN.capstan_zero_mm)
        got = getattr(e, ratio) * (mid - e.capstan_zero_mm)
        assert got == pytest.approx(want, rel=0.15), ratio
    assert math.sqrt(fit.score_mse) < 1.3 * noise
