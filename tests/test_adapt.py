"""Online pre-tension estimator: the exact fold of the pre-tension into the model, convergence, and its
bounds (how far, how fast) and freezes (sensor, excitation, residual)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from warpbridge.model.adapt import AdaptConfig, AdaptState, PretensionEstimator, fold_pretension
from warpbridge.model.boucwen import BoucWenParams, forward, inverse
from warpbridge.model.effects import Effects, core_params, friction_core
from warpbridge.model.excitation import filtered_random
from warpbridge.model.plant import Plant

P = BoucWenParams.paper()
DT = 0.01


def rigged(effects: Effects) -> Plant:
    """The wing re-rigged on the command side, as the estimator models it: pre-tension and friction of
    ``effects`` folded with ``fold_pretension`` (u = offset + f(w) / gain), its other effects kept."""
    folded = fold_pretension(P, effects.pretension_offset_mm, effects.pretension_gain, effects.friction_scale)
    return Plant(folded, replace(effects, pretension_offset_mm=0.0, pretension_gain=1.0, friction_scale=1.0))


def record(effects: Effects, seconds: float = 120.0, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Tendon command (a random warp reference through the model) and the rigged wing's warp."""
    t = np.arange(int(seconds / DT)) * DT
    w_ref = 6.0 + filtered_random(t, cutoff_hz=0.5, amplitude=4.0, seed=seed)
    u, _ = inverse(P, w_ref)
    _, w = rigged(effects).simulate(t, u)
    return u, w


def feed(est: PretensionEstimator, u, w, **kw) -> np.ndarray:
    out = []
    for uk, wk in zip(u, w, strict=True):
        e = est.update(float(uk), float(wk), DT, **kw)
        out.append((e.offset, e.gain, e.drift))
    return np.array(out)


def test_pretension_folds_exactly_into_the_model():
    t = np.arange(3000) * DT
    u = 4.0 + 2.5 * np.sin(2 * np.pi * 0.3 * t) * np.sin(2 * np.pi * 0.07 * t)
    # the command-side rigging: the sheath sees gain (u - offset)
    w_cmd, _, _ = forward(friction_core(P, 1.2), 1.12 * (u - 0.7))
    w_fold, _, _ = forward(fold_pretension(P, 0.7, 1.12, 1.2), u)
    np.testing.assert_allclose(w_fold, w_cmd, atol=1e-6)
    # the diagnosis's pretension effect moves only the backbone: u = offset + (a1 w^2 + a2 w + a3) / gain + az z
    eff = Effects(pretension_offset_mm=0.7, pretension_gain=1.12, friction_scale=1.2)
    _, w_plant = Plant(P, eff).simulate(t, u)
    core = core_params(P, eff)
    assert (core.a1, core.a2, core.az) == pytest.approx((P.a1 / 1.12, P.a2 / 1.12, P.az))
    np.testing.assert_allclose(forward(core, u)[0], w_plant, atol=1e-9)
    # and the feed-forward direction: the folded inverse is offset + u_model / gain
    w_ref = 6 + 3 * np.sin(np.linspace(0, 12, 500))
    u_model, _ = inverse(P, w_ref)
    u_fold, _ = inverse(fold_pretension(P, 0.7, 1.12), w_ref)
    np.testing.assert_allclose(u_fold, 0.7 + u_model / 1.12, atol=1e-9)


def test_estimator_finds_offset_and_gain_of_a_rigged_wing():
    u, w = record(Effects(pretension_offset_mm=0.5, pretension_gain=1.08))
    est = PretensionEstimator(P, AdaptConfig(input_tau_s=0.0, rate_mm_s=0.05, rate_gain_s=0.01))
    hist = feed(est, u, w)
    o, g, _ = hist[-1]
    assert o == pytest.approx(0.5, abs=0.1) and g == pytest.approx(1.08, abs=0.03)
    assert est.estimate.state == AdaptState.ADAPTING
    assert est.apply(3.0) == pytest.approx(o + 3.0 / g)


def test_estimates_never_leave_their_bounds_nor_move_faster_than_the_rate_limits():
    u, w = record(Effects(pretension_offset_mm=3.0, pretension_gain=1.5), seconds=80.0)
    cfg = AdaptConfig(input_tau_s=0.0, max_offset_mm=1.0, max_gain_dev=0.1, rate_mm_s=0.05, rate_gain_s=0.01,
                      gate_deg=50.0)
    hist = feed(PretensionEstimator(P, cfg), u, w)
    assert np.all(np.abs(hist[:, 0]) <= 1.0 + 1e-12)
    lo, hi = cfg.gain_bounds
    assert np.all((hist[:, 1] >= lo - 1e-12) & (hist[:, 1] <= hi + 1e-12))
    assert hist[-1, 0] == pytest.approx(1.0) and hist[-1, 1] == pytest.approx(hi)  # pushed to the bounds
    span = 80.0
    assert np.max(np.abs(np.diff(hist[:, 0]))) <= cfg.rate_mm_s * cfg.update_s + 1e-9
    assert np.max(np.abs(np.diff(hist[:, 1]))) <= cfg.rate_gain_s * cfg.update_s + 1e-9
    assert abs(hist[-1, 0] - hist[0, 0]) <= cfg.rate_mm_s * span
    assert np.all(hist[:, 2] == 0.0)  # drift not estimated unless asked


@pytest.mark.parametrize("case", ["sensor missing", "sensor unhealthy", "garbage reading"])
def test_estimator_freezes_when_the_sensor_cannot_be_trusted(case):
    u, w = record(Effects(pretension_offset_mm=0.5, pretension_gain=1.08), seconds=60.0)
    est = PretensionEstimator(P, AdaptConfig(input_tau_s=0.0, rate_mm_s=0.05))
    feed(est, u[:3000], w[:3000])  # 30 s of good data: it has started to move
    before = est.estimate
    assert before.offset > 0.05
    n = 2000
    if case == "sensor missing":
        hist = np.array([(e.offset, e.gain) for e in (est.update(x, None, DT) for x in u[3000:3000 + n])])
        state = AdaptState.SENSOR
    elif case == "sensor unhealthy":
        hist = feed(est, u[3000:3000 + n], w[3000:3000 + n], healthy=False)[:, :2]
        state = AdaptState.SENSOR
    else:  # a reading far from anything the bounded model can explain
        hist = feed(est, u[3000:3000 + n], w[3000:3000 + n] + 8.0)[:, :2]
        state = AdaptState.RESIDUAL
    assert est.estimate.state == state
    np.testing.assert_array_equal(hist, np.tile([before.offset, before.gain], (n, 1)))


def test_a_wing_held_still_teaches_one_combination_and_freezes_the_other():
    """At one operating point only ``offset + u / gain`` is observable: the estimator moves along that
    direction (the warp there is explained) and leaves the unexcited one alone."""
    n = 6000
    u0 = 4.0
    uu = np.full(n, u0)
    _, ww = rigged(Effects(pretension_offset_mm=0.5, pretension_gain=1.1)).simulate(np.arange(n) * DT, uu)
    est = PretensionEstimator(P, AdaptConfig(input_tau_s=0.0, rate_mm_s=0.05, rate_gain_s=0.01))
    hist = feed(est, uu, ww)
    e = est.estimate
    assert e.excited == 1
    assert abs(est.predict() - ww[-1]) < 0.05  # the held warp is explained ...
    assert abs(e.gain - 1.1) > 0.05  # ... without guessing the gain, which only a moving wing reveals
    # every step was along one fixed direction in (offset, gain)
    d = np.diff(hist[:, :2], axis=0)
    d = d[np.linalg.norm(d, axis=1) > 0]
    cos = np.abs(d @ d[0]) / (np.linalg.norm(d, axis=1) * np.linalg.norm(d[0]))
    assert np.all(cos > 0.999)


def test_switched_off_the_estimates_return_to_neutral_at_the_rate_limit():
    est = PretensionEstimator(P, AdaptConfig(rate_mm_s=0.02, rate_gain_s=0.004), offset=0.5, gain=1.05)
    est.enabled = False
    for _ in range(1000):  # 10 s
        est.update(3.0, 7.0, DT)
        est.relax(DT)
    e = est.estimate
    assert e.state == AdaptState.OFF
    assert e.offset == pytest.approx(0.5 - 0.2, abs=1e-9) and e.gain == pytest.approx(1.01, abs=1e-9)
    for _ in range(3000):
        est.relax(DT)
    assert est.estimate.offset == 0.0 and est.estimate.gain == 1.0


def test_config_rejects_nonsense():
    with pytest.raises(ValueError):
        AdaptConfig(tau_s=0.0)
    with pytest.raises(ValueError):
        AdaptConfig(max_offset_mm=-1.0)
    with pytest.raises(ValueError):
        PretensionEstimator(P).set_estimate(offset=math.nan)
