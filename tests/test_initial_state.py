"""Initial hysteretic state from the first samples of a log that does not start at rest."""

from __future__ import annotations

import numpy as np
import pytest

from warpbridge.model.boucwen import BoucWenParams, forward, inverse
from warpbridge.model.initial_state import algebraic_z0, estimate_z0


def test_the_algebraic_state_is_the_hand_computed_one():
    # a1 = 0, az = 2: z = (u - 0.5 w - 1) / 2; u = 4, w = 2 -> z = 1.0, inside the band of this model
    p = BoucWenParams(a1=0.0, a2=0.5, a3=1.0, az=2.0, A=3.0, n=2.0, b=(0.5, 0.5, 0.0, 0.0, 0.5, 0.0))
    assert algebraic_z0(p, np.full(5, 4.0), np.full(5, 2.0)) == pytest.approx(1.0)


def test_the_algebraic_state_is_clamped_to_what_z_can_reach():
    p = BoucWenParams.paper().canonical()
    hi, lo = p.z_saturation(1.0)
    z = algebraic_z0(p, np.full(5, 100.0), np.full(5, 2.0))  # u far above any loop
    assert z == pytest.approx(max(hi, lo))


def _numpy_algebraic_z0(p, u, w):
    """algebraic_z0 written with numpy calls: the quiet start (input within 2 % of its span of the first
    sample, at most 25 samples), the median finite algebraic z, clamped to the band at the median warp."""
    span = float(np.nanmax(u) - np.nanmin(u)) if u.size else 0.0
    if span <= 0:
        k = min(u.size, 25)
    else:
        moved = np.abs(u[:25] - u[0]) > 0.02 * span
        k = max(1, int(np.argmax(moved)) if moved.any() else min(u.size, 25))
    z = (u[:k] - p.a1 * w[:k] * w[:k] - p.a2 * w[:k] - p.a3) / p.az
    z = z[np.isfinite(z)]
    if z.size == 0:
        return 0.0
    hi, lo = p.z_saturation(1.0 if (float(np.nanmedian(w[:k])) if np.isfinite(w[:k]).any() else 0.0) >= 0 else -1.0)
    return float(np.clip(np.median(z), min(lo, hi), max(lo, hi)))


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_the_algebraic_state_is_bit_for_bit_the_numpy_one_on_ragged_openings():
    rng = np.random.default_rng(3)
    base = BoucWenParams.paper()
    for trial in range(400):
        n = int(rng.choice([1, 2, 3, 24, 25, 26, 400]))
        u = np.cumsum(rng.normal(0.0, rng.choice([0.001, 0.05, 1.0]), n)) + rng.normal(0.0, 5.0)
        if rng.random() < 0.3:
            u[: int(rng.integers(0, n + 1))] = u[0]  # a held start of any length
        w = rng.normal(0.0, 10.0, n)
        for arr, what, chance in ((w, np.nan, 0.2), (u, np.nan, 0.1), (w, np.inf, 0.05)):
            if rng.random() < chance:
                arr[rng.integers(0, n)] = what
        p = BoucWenParams(a1=rng.normal(0.0, 0.01), a2=rng.normal(1.0, 0.3), a3=rng.normal(0.0, 1.0),
                          az=float(rng.choice([1.0, 0.5, 2.3])), A=base.A, n=base.n, b=base.b)
        got, want = algebraic_z0(p, u, w), _numpy_algebraic_z0(p, u, w)
        assert got == want or (np.isnan(got) and np.isnan(want)), (trial, got, want)


def test_the_algebraic_state_of_a_warp_shorter_than_the_opening_is_an_error():
    with pytest.raises(ValueError, match="warp samples"):
        algebraic_z0(BoucWenParams.paper(), np.zeros(10), np.zeros(3))


@pytest.fixture(scope="module")
def loaded_log():
    """A plant run cut after its start: the log begins with the tendon loaded (true z known)."""
    p = BoucWenParams.paper().canonical()
    t = np.arange(0, 24, 0.002)
    w_ref = 6 + 4 * np.sin(2 * np.pi * 0.3 * t) + 1.5 * np.sin(2 * np.pi * 1.1 * t + 1)
    u, _ = inverse(p, w_ref)
    w, z, _ = forward(p, u)
    return p, u, w, z


@pytest.mark.parametrize("cut", [1000, 2345, 5000])
def test_the_estimate_recovers_the_state_the_plant_had(loaded_log, cut):
    p, u, w, z = loaded_log
    rng = np.random.default_rng(cut)
    wc = w[cut:] + rng.normal(0, 0.05, w.size - cut)
    z0 = estimate_z0(p, u[cut:], wc)
    assert abs(z0 - z[cut]) < 0.02 * (np.ptp(z))


def test_a_loaded_start_predicts_as_well_as_the_rest_of_the_log(loaded_log):
    """Whole-log RMS of the right model within 1.1x of its RMS after the first 5 s (the target)."""
    p, u, w, z = loaded_log
    cut = 5000  # the tendon at the top of a loading run
    rng = np.random.default_rng(0)
    uc, wc = u[cut:], w[cut:] + rng.normal(0, 0.05, w.size - cut)
    after = slice(2500, None)  # 5 s at 500 Hz

    def rms(pred, sl=slice(None)):
        return float(np.sqrt(np.mean((pred[sl] - wc[sl]) ** 2)))

    at_rest = forward(p, uc, z0=0.0)[0]
    estimated = forward(p, uc, z0=estimate_z0(p, uc, wc))[0]
    assert rms(at_rest) > 1.5 * rms(at_rest, after)  # the start at rest is visibly wrong
    assert rms(estimated) < 1.1 * rms(estimated, after)


def test_a_model_with_effects_is_started_from_the_whole_chain():
    """With pre-tension and a lagging sensor, the state is estimated through the whole effects chain:
    the loaded start predicts as well as the rest of the log."""
    from warpbridge.model.effects import Effects
    from warpbridge.model.initial_state import estimate_plant_z0
    from warpbridge.model.plant import Plant

    p = BoucWenParams.paper().canonical()
    plant = Plant(p, Effects(pretension_offset_mm=0.3, pretension_gain=0.9, sensor_tau_s=0.03))
    t = np.arange(0, 30, 0.002)
    u = 5 + 2 * np.sin(2 * np.pi * 0.3 * t) + 0.8 * np.sin(2 * np.pi * 1.1 * t + 1)
    _, w = plant.simulate(t, u)
    cut = int(np.argmax(u[:2500]))
    tc, uc = t[cut:], u[cut:]
    wc = w[cut:] + np.random.default_rng(1).normal(0, 0.05, uc.size)
    after = tc >= tc[0] + 5.0

    def rms(pred, sel=slice(None)):
        return float(np.sqrt(np.mean((pred[sel] - wc[sel]) ** 2)))

    at_rest = plant.simulate(tc, uc, z0=0.0)[1]
    estimated = plant.simulate(tc, uc, z0=estimate_plant_z0(plant, tc, uc, wc))[1]
    assert rms(at_rest) > 1.5 * rms(at_rest, after)
    assert rms(estimated) < 1.1 * rms(estimated, after)


@pytest.fixture(scope="module")
def slack_log():
    """A plant with a wide play (backlash 1.2 mm) run from rest, then cut where the input was lowest (its
    slack last taken up by a release) and where it was highest (by a pull)."""
    from warpbridge.model.effects import Effects
    from warpbridge.model.plant import Plant

    p = BoucWenParams.paper().canonical()
    plant = Plant(p, Effects(backlash_mm=1.2))
    t = np.arange(0, 30, 0.002)
    u = 5 + 2 * np.sin(2 * np.pi * 0.3 * t) + 0.8 * np.sin(2 * np.pi * 1.1 * t + 1)
    _, w = plant.simulate(t, u)
    w = w + np.random.default_rng(2).normal(0, 0.05, w.size)
    return plant, t, u, w


@pytest.mark.parametrize("at", ["lowest", "highest"])
def test_the_play_starts_on_the_edge_the_log_opens_with(slack_log, at):
    """The initial state of a model with a play is z0 and the edge its slack was taken up on: a log cut where
    the input turned up starts released, one cut where it turned down starts pulled; either way its whole-log
    RMS is within 1.1x of its RMS after the first 5 s, and a start assumed on the other edge is visibly wrong."""
    from dataclasses import replace

    from warpbridge.model.effects import PULLED, RELEASED
    from warpbridge.model.initial_state import estimate_plant_start, estimate_plant_z0

    plant, t, u, w = slack_log
    first = u[2500:5000]
    cut = 2500 + int(np.argmin(first) if at == "lowest" else np.argmax(first))
    tc, uc, wc = t[cut:], u[cut:], w[cut:]
    after = tc >= tc[0] + 5.0

    def rms(pl, z0, sel=slice(None)):
        return float(np.sqrt(np.mean((pl.simulate(tc, uc, z0=z0)[1][sel] - wc[sel]) ** 2)))

    z0, side = estimate_plant_start(plant, tc, uc, wc)
    assert side == (RELEASED if at == "lowest" else PULLED)
    right = replace(plant, slack_side=side)
    assert rms(right, z0) < 1.1 * rms(right, z0, after)
    wrong = replace(plant, slack_side=-side)
    z_wrong = estimate_plant_z0(wrong, tc, uc, wc)
    assert rms(wrong, z_wrong) > 1.5 * rms(wrong, z_wrong, after)


def test_a_model_without_a_play_has_one_unknown():
    from warpbridge.model.effects import PULLED, Effects
    from warpbridge.model.initial_state import estimate_plant_start, estimate_plant_z0, reachable_band
    from warpbridge.model.plant import Plant

    plant = Plant(BoucWenParams.paper().canonical(), Effects(sensor_tau_s=0.02))
    t = np.arange(0, 6, 0.002)
    u = 5 + 2 * np.sin(2 * np.pi * 0.4 * t)
    _, w = plant.simulate(t, u, z0=0.2)
    w = w + np.random.default_rng(3).normal(0, 0.03, w.size)
    z0, side = estimate_plant_start(plant, t, u, w)
    assert side == PULLED and z0 == estimate_plant_z0(plant, t, u, w)
    lo, hi = reachable_band(plant.params, float(w[0]))
    assert abs(z0 - 0.2) < 0.05 * (hi - lo)  # the state the log started in
