"""MODEL.json's effect forms: files are marked with the forms they were written in, and a file of the
earlier friction / pre-tension forms reads as what it meant when it was written."""

from __future__ import annotations

import json

import numpy as np
import pytest

from warpbridge.model.boucwen import BoucWenParams, forward
from warpbridge.model.effects import Effects
from warpbridge.model.modelfile import ModelFile

P = BoucWenParams(a1=-0.03, a2=0.8, a3=0.5, az=0.7, A=3.0, n=2.5, b=(0.5, 0.3, -0.1, 0.2, -0.05, 0.1))


def earlier_forms_warp(p: BoucWenParams, u: np.ndarray, offset: float, gain: float, scale: float) -> np.ndarray:
    """The plant as the earlier forms ran it, by hand: friction scaled az about the middle of the band
    (saturation levels (A / psi)^(1/n) of loading and unloading at positive warp), pre-tension mapped
    the tendon travel, u_eff = gain (u - offset)."""
    b1, b2, b3, b4, b5, b6 = p.b
    hi = (p.A / (b1 + b2 + b3 + b4 + b5 + b6)) ** (1 / p.n)
    lo = -(p.A / (b1 - b2 - b3 - b4 - b5 + b6)) ** (1 / p.n)
    mid = 0.5 * (hi + lo)
    q = BoucWenParams(a1=p.a1, a2=p.a2, a3=p.a3 + p.az * (1 - scale) * mid, az=p.az * scale, A=p.A, n=p.n, b=p.b)
    return forward(q, gain * (u - offset))[0]


def test_a_file_is_marked_with_its_effect_forms_and_reads_back_unchanged():
    mf = ModelFile(P, Effects(pretension_offset_mm=0.4, pretension_gain=1.1, friction_scale=1.2))
    d = json.loads(json.dumps(mf.to_dict()))
    assert d["effect_forms"] == 2
    back = ModelFile.from_dict(d)
    assert back.params == P and back.effects == mf.effects and "folded_on_reading" not in back.meta


def test_a_file_of_the_earlier_forms_means_what_it_meant():
    d = ModelFile(P, Effects(pretension_offset_mm=0.4, pretension_gain=1.1, friction_scale=1.2,
                             sensor_tau_s=0.02)).to_dict()
    del d["effect_forms"]  # as the earlier versions wrote it
    old = ModelFile.from_dict(d)
    assert old.effects == Effects(sensor_tau_s=0.02)  # friction and pre-tension now live in the parameters
    assert "folded_on_reading" in old.meta
    t = np.arange(3000) * 0.01
    u = 4.0 + 2.5 * np.sin(2 * np.pi * 0.3 * t) * np.sin(2 * np.pi * 0.07 * t)
    w_now = old.plant.simulate(t, u)[0]
    np.testing.assert_allclose(w_now, earlier_forms_warp(P, u, 0.4, 1.1, 1.2), atol=1e-6)
    # and it is not what the same numbers mean in today's forms
    today = ModelFile.from_dict(ModelFile(P, Effects(pretension_offset_mm=0.4, pretension_gain=1.1,
                                                     friction_scale=1.2)).to_dict())
    assert np.max(np.abs(today.plant.simulate(t, u)[0] - w_now)) > 0.05


def test_a_file_without_friction_or_pretension_needs_no_folding_and_unknown_forms_are_refused():
    d = ModelFile(P, Effects(backlash_mm=0.2)).to_dict()
    del d["effect_forms"]
    mf = ModelFile.from_dict(d)
    assert mf.params == P and mf.effects == Effects(backlash_mm=0.2) and "folded_on_reading" not in mf.meta
    with pytest.raises(ValueError, match="effect_forms"):
        ModelFile.from_dict(d | {"effect_forms": 3})
