"""The model-error model: reversal bookkeeping by hand, recovery of a planted correction, no structure learned
from noise, a model file that carries it (and one that does not), and a bench lag learned as structure."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import spread_friction, two_stage_lag

from warpbridge.model.boucwen import BoucWenParams, inverse
from warpbridge.model.effects import Effects, apply_input_effects, lagged, play
from warpbridge.model.excitation import filtered_random
from warpbridge.model.model_error import (
    FEATURE_SETS,
    LAG_TIMES_S,
    SET_COLUMNS,
    ErrorModel,
    _smooth_rate,
    bench_error_model,
    design,
    fit_error_model,
    lag_states,
    play_states,
    time_terms,
    travel_since_reversal,
)
from warpbridge.model.modelfile import ModelFile
from warpbridge.model.plant import Plant

P = BoucWenParams.paper()


def test_travel_since_reversal_on_a_triangle_by_hand():
    # 0 -> 4 -> 1 -> 3 in steps of 1 mm (deadband 0.5 mm)
    x = np.array([0.0, 1, 2, 3, 4, 3, 2, 1, 2, 3])
    s, d, a = travel_since_reversal(x, 0.5)
    assert list(s) == [1, 1, 1, 1, 1, -1, -1, -1, 1, 1]
    # before the first reversal the travel counts from the start
    assert list(d) == [0, 1, 2, 3, 4, 1, 2, 3, 1, 2]
    # the leg before the current one: none, then 0 -> 4, then 4 -> 1
    assert list(a) == [0, 0, 0, 0, 0, 4, 4, 4, 3, 3]


def test_a_wiggle_inside_the_deadband_is_not_a_reversal():
    x = np.array([0.0, 1.0, 2.0, 1.9, 2.5, 3.0])
    s, d, _ = travel_since_reversal(x, 0.5)
    assert np.all(s == 1) and d[-1] == 3.0


def test_play_states_by_hand():
    # a play of half-width 1 mm starts relaxed, is dragged along, then lets go inside its band
    x = np.array([0.0, 0.5, 2.0, 3.0, 2.5, 1.0, 0.5, 1.5])
    q = play_states(x, np.array([1.0]))[:, 0]
    # play position: 0, 0, 1, 2, 2, 2, 1.5, 1.5 -> q = x - p
    np.testing.assert_allclose(q, [0.0, 0.5, 1.0, 1.0, 0.5, -1.0, -1.0, 0.0])


def _jittered_times(n=4000, fs=500.0, seed=3):
    """Sample times of a logged file: 500 Hz with a little jitter (the non-uniform branch of np.gradient)."""
    rng = np.random.default_rng(seed)
    return np.round(np.arange(n) / fs + rng.uniform(-2e-4, 2e-4, n), 4)


@pytest.mark.parametrize("times", ["jittered", "uniform", "three", "two", "one"])
def test_the_rate_and_lag_terms_are_bit_for_bit_the_plain_operators(times):
    # the correction takes its rate's smoothing width and its lags' step factors from terms kept per log;
    # the result must be exactly what the plain operators give, so a diagnosis does not depend on the caching
    # (steps of 1/512 s are exact in binary: np.gradient's uniform branch; 1/500 s steps are not)
    t = {"jittered": _jittered_times(), "uniform": np.arange(4000) / 512.0, "three": np.array([0.0, 0.002, 0.0041]),
         "two": np.array([0.0, 0.002]), "one": np.array([0.0])}[times]
    w = np.sin(7.0 * t) + 0.3 * np.cos(31.0 * t) + 2.0
    rate_scale = 0.7
    plain_rate = np.gradient(w, t) if t.size > 2 else np.zeros_like(w)
    k = max(1, int(round(0.01 / float(np.median(np.diff(t)))))) if t.size > 1 else 1
    if k > 1:
        plain_rate = np.convolve(plain_rate, np.ones(k) / k, mode="same")
    plain_lags = np.column_stack([(lagged(t, w, tau, float(w[0])) - w) / (rate_scale * tau) for tau in LAG_TIMES_S])
    terms = time_terms(t)
    for got in (_smooth_rate(t, w), _smooth_rate(t, w, terms)):
        assert np.array_equal(got, plain_rate)
    for got in (lag_states(t, w, rate_scale), lag_states(t, w, rate_scale, terms)):
        assert np.array_equal(got, plain_lags)


def test_play_states_are_bit_for_bit_one_play_after_another():
    x = np.cumsum(np.random.default_rng(4).normal(0.0, 0.05, 3000)) + 5.0
    thresholds = np.array([0.01, 0.1, 0.4, 2.0])
    plain = np.column_stack([(x - play(x, 2.0 * r, float(x[0]))) / r for r in thresholds])
    assert np.array_equal(play_states(x, thresholds), plain)


def test_the_correction_reuses_its_time_terms_only_for_the_same_times():
    t, u, w = _log()
    em = fit_error_model(t, u, w, w + 0.05 * np.gradient(w, t) + 0.02 * np.sin(3 * t), noise=0.001)
    assert "rate" in em.sets
    first = em.correction(t, u, w)
    stretched = t * 1.5  # another log's times: the rate terms change with them
    again = ErrorModel.from_dict(em.to_dict())
    assert np.array_equal(em.correction(stretched, u, w), again.correction(stretched, u, w))
    assert not np.array_equal(em.correction(stretched, u, w), first)
    assert np.array_equal(em.correction(t.copy(), u, w), first)
    fresh, t2 = ErrorModel.from_dict(em.to_dict()), t.copy()
    fresh.correction(t2, u, w)
    t2 *= 1.5  # the caller's times changed in place: not taken for the ones the terms were computed on
    assert np.array_equal(fresh.correction(t2, u, w), again.correction(stretched, u, w))


def _log(seconds=30.0, fs=200.0, seed=0):
    t = np.arange(int(seconds * fs)) / fs
    w_ref = filtered_random(t, 1.0, 4.5, 7.0, seed=seed)
    u, _ = inverse(P, w_ref)
    return t, u, w_ref


def test_a_planted_correction_is_recovered_and_its_known_error_is_small():
    t, u, w = _log()
    span = float(np.ptp(np.percentile(u, [0.5, 99.5])))
    X = design(t, u, w, 7.0, 4.5, span, 30.0, FEATURE_SETS[:3])
    rng = np.random.default_rng(1)
    theta = np.zeros(X.shape[1])
    theta[[1, 4, 7]] = [0.08, 0.05, -0.06]  # a level slope, a branch offset, a short transition
    noise = 0.02
    w_meas = w + X @ theta + noise * rng.standard_normal(t.size)
    em = fit_error_model(t, u, w, w_meas, noise=noise)
    assert "transition" in em.sets
    planted = X @ theta
    got = em.correction(t, u, w)
    assert np.sqrt(np.mean((got - planted) ** 2)) < 0.2 * np.sqrt(np.mean(planted ** 2))
    assert em.rms_before_deg > 2 * noise
    assert em.rms_after_deg == pytest.approx(noise, rel=0.1)
    assert em.known_error_deg < 0.5 * noise


def test_noise_alone_teaches_it_nothing():
    t, u, w = _log(seed=2)
    noise = 0.03
    w_meas = w + noise * np.random.default_rng(3).standard_normal(t.size)
    em = fit_error_model(t, u, w, w_meas, noise=noise)
    c = em.correction(t, u, w)
    # whatever it kept is far below the noise, and its cross-validated error is the noise
    assert np.sqrt(np.mean(c ** 2)) < 0.15 * noise
    assert em.rms_after_deg == pytest.approx(noise, rel=0.05)


@pytest.mark.slow
def test_a_bench_lag_the_model_lacks_is_learned_as_structure():
    t, u, _ = _log(seconds=40.0, fs=500.0, seed=4)
    _, w = Plant(P, Effects(sensor_tau_s=0.02)).simulate(t, u)
    noise = 0.03
    w = w + noise * np.random.default_rng(5).standard_normal(t.size)
    em = bench_error_model(P, Effects(), t, u, w)
    assert "rate" in em.sets
    # the lag costs several times the noise; the correction takes most of it away
    assert em.rms_before_deg > 3 * noise
    assert em.known_error_deg < 0.35 * math.sqrt(em.rms_before_deg ** 2 - noise ** 2)


def test_model_file_round_trip_and_files_without_the_field():
    t, u, w = _log(seed=6)
    em = fit_error_model(t, u, w, w + 0.05 * np.sin(t), noise=0.01)
    mf = ModelFile(params=P, model_error=em)
    d = mf.to_dict()
    assert d["format"] == "warpbridge-model/1"
    back = ModelFile.from_dict(d)
    assert back.model_error is not None
    np.testing.assert_array_equal(back.model_error.theta, em.theta)
    np.testing.assert_allclose(back.model_error.correction(t, u, w), em.correction(t, u, w), rtol=0, atol=1e-12)
    old = {k: v for k, v in d.items() if k != "model_error"}
    assert ModelFile.from_dict(old).model_error is None
    assert "model_error" not in ModelFile(params=P).to_dict()


@pytest.fixture(scope="module")
def fitted_field() -> dict:
    """A model-error field as a model file holds it, fitted once for the damages below."""
    t, u, w = _log(seed=7)
    return fit_error_model(t, u, w, w + 0.05 * np.sin(t), noise=0.01).to_dict()


@pytest.mark.parametrize("change, needle", [
    ({"format": "other/1"}, "unsupported model_error format"),
    ({"sets": ["rate"]}, "prefix"),
    ({"theta": [1.0]}, "does not match"),
    ({"w_scale": -1.0}, "positive"),
])
def test_a_damaged_model_error_field_is_refused_with_a_reason(fitted_field, change, needle):
    d = dict(fitted_field)
    ErrorModel.from_dict(d)  # whole, it is read
    d.update(change)
    with pytest.raises(ValueError, match=needle):
        ErrorModel.from_dict(d)
    with pytest.raises(ValueError, match=needle):
        ModelFile.from_dict({"format": "warpbridge-model/1", "params": P.to_dict(), "model_error": d})


def test_the_compiled_correction_is_the_feature_matrix_times_theta():
    t, u, w = _log(seed=8)
    rng = np.random.default_rng(9)
    span = float(np.ptp(u))
    for k in range(1, len(FEATURE_SETS) + 1):
        sets = FEATURE_SETS[:k]
        X = design(t, u, w, 6.0, 4.0, span, 25.0, sets)
        em = ErrorModel(6.0, 4.0, span, 25.0, sets, rng.standard_normal(X.shape[1]))
        np.testing.assert_allclose(em.correction(t, u, w), X @ em.theta, rtol=0, atol=1e-10)


def test_the_input_terms_reused_across_paths_give_each_path_its_own_correction():
    """A model that has seen other travel paths corrects each path as the feature matrix says (the terms
    kept from one path are never used for another, even one that differs in a single sample)."""
    t, u, w = _log(seed=10)
    span = float(np.ptp(u))
    X = design(t, u, w, 6.0, 4.0, span, 25.0, FEATURE_SETS)
    em = ErrorModel(6.0, 4.0, span, 25.0, FEATURE_SETS, np.random.default_rng(11).standard_normal(X.shape[1]))
    u2 = u.copy()
    u2[len(u) // 2] += 0.3 * span  # one sample moved: a reversal there and back
    paths = [u, np.roll(u, 40), u2, u, u2, 0.5 * u]
    for x in paths:
        for wk in (w, w + 0.2):
            expect = design(t, x, wk, 6.0, 4.0, span, 25.0, FEATURE_SETS) @ em.theta
            np.testing.assert_allclose(em.correction(t, x, wk), expect, rtol=0, atol=1e-10)


def test_the_terms_kept_at_a_held_band_are_those_of_that_band_and_path():
    """The input terms kept for bands other than 1 are used only for the same band and the same path; a path
    changed in place after it was kept is computed afresh."""
    t, u, w = _log(seed=12)
    span = float(np.ptp(u))
    X = design(t, u, w, 6.0, 4.0, span, 25.0, FEATURE_SETS)
    em = ErrorModel(6.0, 4.0, span, 25.0, FEATURE_SETS, np.random.default_rng(13).standard_normal(X.shape[1]))
    fresh = ErrorModel.from_dict(em.to_dict())
    x = u.copy()
    for band in (1.3, 1.3, 0.8, 1.3, 1.0, 0.8):
        plain = ErrorModel.from_dict(em.to_dict())  # nothing kept
        assert np.array_equal(em.correction(t, x, w, band), plain.correction(t, x, w, band))
    kept = em.correction(t, x, w, 1.3)
    x[len(x) // 3:] *= 0.7  # the caller's path changed in place
    assert np.array_equal(em.correction(t, x, w, 1.3), fresh.correction(t, x, w, 1.3))
    assert not np.array_equal(em.correction(t, x, w, 1.3), kept)


LOOP_SHAPE_SETS = ("branch", "transition", "memory", "play")  # a misfit of the band; level, rate, lag are not


@pytest.mark.parametrize("band", [0.4, 1.0, 1.7])
def test_the_loop_shape_terms_scale_with_the_band_in_height_and_travel_and_the_rest_stays(band):
    # the band scaled by s scales the loop self-similarly, z(u) -> s z(u / s): the loop-shape columns are
    # the bench's features on a travel scale s times as long, s times as large; level, rate and lag stay
    t, u, w = _log(seed=14)
    span = float(np.ptp(u))
    X = design(t, u, w, 6.0, 4.0, span, 25.0, FEATURE_SETS)
    Xs = design(t, u, w, 6.0, 4.0, span * band, 25.0, FEATURE_SETS)
    em = ErrorModel(6.0, 4.0, span, 25.0, FEATURE_SETS, np.random.default_rng(15).standard_normal(X.shape[1]))
    loop = np.concatenate([np.full(SET_COLUMNS[s], s in LOOP_SHAPE_SETS) for s in FEATURE_SETS])
    expect = X[:, ~loop] @ em.theta[~loop] + band * (Xs[:, loop] @ em.theta[loop])
    np.testing.assert_allclose(em.correction(t, u, w, band), expect, rtol=0, atol=1e-10)
    if band != 1.0:  # the travel scale does move the loop-shape part: not the amplitude alone
        assert np.max(np.abs(Xs[:, loop] - X[:, loop])) > 0.1


@pytest.mark.parametrize("band", [0.5, 2.0])
def test_the_loop_shape_correction_of_a_scaled_band_is_the_bench_one_on_the_travel_shrunk_by_it(band):
    # the self-similarity itself: along travel x with the band scaled by s, the loop-shape correction is s
    # times the bench's (band 1) along x / s
    t, u, w = _log(seed=18)
    span = float(np.ptp(u))
    X = design(t, u, w, 6.0, 4.0, span, 25.0, FEATURE_SETS)
    loop = np.concatenate([np.full(SET_COLUMNS[s], s in LOOP_SHAPE_SETS) for s in FEATURE_SETS])
    theta = np.where(loop, np.random.default_rng(19).standard_normal(X.shape[1]), 0.0)
    em = ErrorModel(6.0, 4.0, span, 25.0, FEATURE_SETS, theta)
    np.testing.assert_allclose(em.correction(t, u, w, band), band * em.correction(t, u / band, w, 1.0),
                               rtol=0, atol=1e-9)


@pytest.mark.parametrize("band", [0.0, -1.0, float("nan"), float("inf")])
def test_a_band_scale_that_is_not_positive_and_finite_is_refused(band):
    t, u, w = _log(seed=20)
    span = float(np.ptp(u))
    em = ErrorModel(6.0, 4.0, span, 25.0, FEATURE_SETS, np.ones(design(t, u, w, 6.0, 4.0, span, 25.0,
                                                                       FEATURE_SETS).shape[1]))
    with pytest.raises(ValueError, match="band scale"):
        em.correction(t, u, w, band)


def test_the_plant_runs_the_correction_with_its_friction_band():
    # a friction change that scales the band scales the loop-shape terms with it; in its capstan form (a stall
    # at each reversal, the band kept) and with no friction change the correction is the bench's
    t, u, _ = _log(seconds=10.0, seed=16)
    span = float(np.ptp(u))
    X = design(t, u, u, 6.0, 4.0, span, 25.0, FEATURE_SETS)
    em = ErrorModel(6.0, 4.0, span, 25.0, FEATURE_SETS, 0.05 * np.random.default_rng(17).standard_normal(X.shape[1]))
    for eff, band in ((Effects(friction_scale=0.6), 0.6), (Effects(friction_scale=1.4, friction_pivot=0.3), 1.4),
                      (Effects(capstan_pull_ratio=0.05, capstan_release_ratio=0.02), 1.0), (Effects(), 1.0)):
        w_core, _ = Plant(P, eff).simulate(t, u)  # no output-side effect: the core's warp
        _, w_plant = Plant(P, eff, em).simulate(t, u)
        x = apply_input_effects(eff, t, u)
        np.testing.assert_allclose(w_plant, w_core + em.correction(t, x, w_core, band), rtol=0, atol=1e-12)
        assert eff.band_scale == band


@pytest.mark.slow
def test_friction_spread_along_a_sheath_is_learned_by_the_play_set():
    # the wing's hysteresis carries, on top of the model's, a Prandtl-Ishlinskii part (plays of widths that
    # are not on the module's grid): memory one Bouc-Wen state cannot hold
    t, u, _ = _log(seconds=40.0, fs=200.0, seed=10)
    _, w = Plant(P).simulate(t, u)
    span = float(np.ptp(u))
    extra = spread_friction(u, span)
    noise = 0.02
    w_meas = w + extra + noise * np.random.default_rng(11).standard_normal(t.size)
    em = bench_error_model(P, Effects(), t, u, w_meas)
    assert "play" in em.sets
    before = math.sqrt(em.rms_before_deg ** 2 - noise ** 2)
    without = fit_error_model(t, u, w, w_meas, noise=noise, sets=FEATURE_SETS[:FEATURE_SETS.index("play")])
    assert before > 5 * noise
    # with the plays it is left with a small part of what the other sets leave
    assert em.known_error_deg < 0.5 * without.known_error_deg < 0.5 * before


def test_a_short_bench_log_still_gets_the_sets_its_samples_support():
    # 450 samples: enough for the first sets (20 samples per column), not for the plays' 14 columns more
    t, u, w = _log(seconds=2.25, fs=200.0, seed=12)
    span = float(np.ptp(u))
    X = design(t, u, w, 7.0, 4.5, span, 30.0, FEATURE_SETS[:2])
    w_meas = w + X @ np.array([0.0, 0.1, 0.0, 0.0, 0.08, 0.0, 0.0])
    em = fit_error_model(t, u, w, w_meas, noise=0.005)
    assert em.sets and "play" not in em.sets
    assert em.rms_after_deg < 0.5 * em.rms_before_deg


@pytest.mark.slow
def test_bench_dynamics_of_tens_of_ms_are_learned_by_the_lag_set():
    # the bench's servo and sensor: two stages of 25 and 12 ms on a fast input; the rate set is only the
    # first-order term of that, the lag set holds more of it
    t, u, _ = _log(seconds=40.0, fs=500.0, seed=12)
    _, w = Plant(P).simulate(t, u)
    noise = 0.02
    w_meas = two_stage_lag(t, w, 0.025, 0.012) + noise * np.random.default_rng(13).standard_normal(t.size)
    em = bench_error_model(P, Effects(), t, u, w_meas)
    assert em.sets[-1] == "lag"
    without = fit_error_model(t, u, w, w_meas, noise=noise, sets=FEATURE_SETS[:FEATURE_SETS.index("lag")])
    assert em.rms_before_deg > 5 * noise and without.known_error_deg > 0.5 * noise
    assert em.known_error_deg < 0.5 * without.known_error_deg


def test_the_plant_adds_the_correction_to_the_core_before_the_sensor_and_the_drift():
    # a correction that is a constant offset (level set, P0 only): the core's warp moves by it, and the
    # sensor lag and the drift act on the corrected warp, not beside it
    t, u, _ = _log(seconds=10.0)
    em = ErrorModel(w_center=7.0, w_scale=4.5, x_span=5.0, rate_scale=10.0, sets=("level",),
                    theta=np.array([0.3, 0.0, 0.0, 0.0]))
    eff = Effects(sensor_tau_s=0.05, drift_deg_s=0.01)
    _, bare = Plant(P).simulate(t, u)
    _, with_fx = Plant(P, eff).simulate(t, u)
    _, corrected = Plant(P, eff, em).simulate(t, u)
    lag = np.empty_like(bare)
    y = bare[0] + 0.3
    for k in range(t.size):  # the lag of the corrected core written out, then the ramp
        a = math.exp(-(t[k] - t[k - 1]) / 0.05) if k else 0.0
        y = a * y + (1 - a) * (bare[k] + 0.3)
        lag[k] = y
    assert np.allclose(corrected, lag + 0.01 * (t - t[0]), atol=1e-9)
    assert np.allclose(corrected - with_fx, 0.3, atol=1e-9)


def test_the_per_sample_plant_refuses_a_correction_it_cannot_run():
    from warpbridge.model.plant import PlantStepper

    em = ErrorModel(w_center=7.0, w_scale=4.5, x_span=5.0, rate_scale=10.0, sets=("level",),
                    theta=np.array([0.3, 0.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match="model-error correction"):
        PlantStepper(Plant(P, Effects(), em), 0.0, 3.0)
