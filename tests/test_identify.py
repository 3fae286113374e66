"""Identification from logs simulated with the paper's parameters and 0.05 deg sensor noise."""

import math

import numpy as np
import pytest

from warpbridge.model.boucwen import BoucWenParams, forward, inverse
from warpbridge.model.effects import play, servo_follow
from warpbridge.model.excitation import filtered_random, multisine_reversals
from warpbridge.model.identification import identify, support_check
from warpbridge.model.identification.path import fit_stretches
from warpbridge.model.signals import compress_path, noise_floor, reversal_indices, turning_points

P = BoucWenParams.paper()
FS = 200.0
T = np.arange(0, 40 * FS) / FS


def noisy_log(u, seed, noise=0.05, params=P):
    w, _, flagged = forward(params, u)
    assert flagged == 0
    return w, w + noise * np.random.default_rng(seed).standard_normal(w.size)


@pytest.fixture(scope="module")
def fitted():
    u = filtered_random(T, 1.0, 2.5, offset=4.5, seed=1)
    w_true, w = noisy_log(u, 2)
    # start the search from a deliberately wrong prior so the test exercises the search, not the seed
    wrong = BoucWenParams(a1=-0.005, a2=0.5, a3=1.5, az=0.3, A=8.0, n=2.0, b=(5, -2, 1, -1, 3, -5))
    return u, w, identify(T, u, w, prior=wrong, maxiter=120)


def test_heldout_rms_within_1_2x_of_the_noise(fitted):
    _, _, res = fitted
    assert res.noise == pytest.approx(0.05, rel=0.1)
    assert res.heldout_rms < 1.2 * 0.05
    assert res.train_rms < 1.2 * 0.05
    assert res.linear_heldout_rms > 5 * res.heldout_rms  # hysteresis matters
    assert res.delay_s == 0.0  # the log has no transport delay, and the scan adds none


def test_reproduces_the_papers_loops(fitted):
    _, _, res = fitted
    leg = np.linspace(3.0, 11.0, 300)
    w = np.concatenate([leg, leg[::-1], leg, leg[::-1]])
    u_true, _ = inverse(P, w)
    u_fit, _ = inverse(res.params, w)
    # same loop in tendon travel (mm) after the first cycle, within 0.05 mm (~0.07 deg)
    assert np.max(np.abs(u_fit[300:] - u_true[300:])) < 0.05


def test_predicts_a_second_log_with_a_different_excitation_equally_well(fitted):
    _, _, res = fitted
    u2 = multisine_reversals(T, (1.8, 0.7, 0.3), (0.4, 1.1, 2.7), offset=4.5)
    w2_true, w2 = noisy_log(u2, 5)
    w_pred, _, _ = forward(res.params, u2)
    rms = float(np.sqrt(np.mean((w_pred - w2) ** 2)))
    assert rms < 1.2 * 0.05
    assert float(np.sqrt(np.mean((w_pred - w2_true) ** 2))) < 0.03


def test_same_seed_gives_the_same_model():
    u = filtered_random(T[:3000], 1.0, 2.5, offset=4.5, seed=4)
    _, w = noisy_log(u, 3)
    a = identify(T[:3000], u, w, maxiter=10, polish_evals=50, seed=7)
    b = identify(T[:3000], u, w, maxiter=10, polish_evals=50, seed=7)
    assert a.params == b.params


def test_a_result_at_the_exponents_upper_limit_is_refined_again_from_the_next_starts(monkeypatch):
    from warpbridge.model.identification import checks, pipeline

    u = filtered_random(T[:3000], 1.0, 2.5, offset=4.5, seed=4)
    _, w = noisy_log(u, 3)
    kw = dict(maxiter=8, polish_evals=200)
    # the exponent's restart alone: no backbone counts as folding
    monkeypatch.setattr(checks, "fold_depth", lambda thetas, c, lo, hi: np.zeros(np.atleast_2d(thetas).shape[0]))
    monkeypatch.setattr(pipeline, "EDGE_FRAC", -1.0)  # no result counts as at the limit
    once = identify(T[:3000], u, w, **kw)
    assert once.trace.restarts == 0 and "searched_again" not in once.fit_dict()
    monkeypatch.setattr(pipeline, "EDGE_FRAC", 1.0)  # every result counts as at the limit ...
    monkeypatch.setattr(pipeline, "EDGE_AGREE", -1.0)  # ... and its refined starts as disagreeing
    seen = []
    both = identify(T[:3000], u, w, progress=lambda stage, i, n: seen.append((stage, i)), **kw)
    assert both.trace.restarts == 1
    assert any(stage == "refine again" for stage, _ in seen)
    assert both.train_rms <= once.train_rms  # the better of the two is kept
    assert both.fit_dict()["searched_again"] and both.fit_dict()["second_search_kept"] == both.trace.restart_kept
    # refined starts that agree put n at the limit themselves: no second refinement
    monkeypatch.setattr(pipeline, "EDGE_AGREE", 1e9)
    agree = identify(T[:3000], u, w, **kw)
    assert agree.trace.restarts == 0


def test_the_answer_does_not_depend_on_the_seed():
    """The seed only scrambles the start design: every seed's model predicts the held-out part alike."""
    u = filtered_random(T[:4000], 1.0, 2.5, offset=4.5, seed=4)
    _, w = noisy_log(u, 3)
    held = [identify(T[:4000], u, w, seed=s).heldout_rms for s in (0, 1, 2)]
    assert max(held) <= 1.01 * min(held)
    assert max(held) < 1.2 * 0.05


def test_only_the_exponents_upper_limit_counts_as_its_edge():
    from warpbridge.model.identification.pipeline import EDGE_FRAC
    from warpbridge.model.identification.refine import at_exponent_edge
    from warpbridge.model.identification.space import BOUNDS_ONE_SIDED

    lo = np.array([b[0] for b in BOUNDS_ONE_SIDED])
    hi = np.array([b[1] for b in BOUNDS_ONE_SIDED])
    theta = 0.5 * (lo + hi)
    assert not at_exponent_edge(theta, lo, hi, EDGE_FRAC)
    theta[0] = hi[0]
    assert at_exponent_edge(theta, lo, hi, EDGE_FRAC)
    theta[0] = lo[0]  # n = 1, the classical Bouc-Wen form: a value of the model, not a limit of the search
    assert not at_exponent_edge(theta, lo, hi, EDGE_FRAC)


def test_noise_floor_estimate():
    rng = np.random.default_rng(0)
    t = np.arange(0, 20, 1 / 500)
    w = 5 + 3 * np.sin(2 * np.pi * t) + 0.03 * rng.standard_normal(t.size)
    assert noise_floor(w) == pytest.approx(0.03, rel=0.1)


@pytest.mark.parametrize("sigma", [0.025, 0.03, 0.035, 0.04])
def test_noise_floor_holds_on_a_quantised_sensor(sigma):
    # an ADC step near the noise: the second differences are multiples of the step and their median jumps by it
    rng = np.random.default_rng(1)
    t = np.arange(0, 60, 1 / 500)
    clean = 5 + 3 * np.sin(2 * np.pi * 0.7 * t) + np.sin(2 * np.pi * 2.3 * t)
    step = 0.03
    w = np.round((clean + sigma * rng.standard_normal(t.size)) / step) * step
    assert noise_floor(w) == pytest.approx(float(np.std(w - clean)), rel=0.03)


def test_path_compression_keeps_every_reversal_and_changes_no_output():
    u = filtered_random(T, 1.0, 2.5, offset=4.5, seed=9)
    idx = compress_path(u, 17)
    assert set(reversal_indices(u)).issubset(set(idx))
    w_full, _, _ = forward(P, u)
    w_comp, _, _ = forward(P, u[idx], w0=w_full[0])
    assert np.max(np.abs(w_comp - w_full[idx])) < 2e-3  # integration error only: far below sensor noise
    assert idx.size < u.size / 5


@pytest.mark.parametrize("case, message", [
    ("short", "too short"),
    ("monotone", "never reverses"),
    ("flat", "never changes"),
    ("negative", "decreases"),
])
def test_refuses_logs_that_cannot_identify_the_model(case, message):
    t = np.arange(0, 10, 0.01)
    u = 4 + np.sin(t)
    w = 5 + np.sin(t)
    if case == "short":
        t, u, w = t[:20], u[:20], w[:20]
    elif case == "monotone":
        u = np.linspace(1, 5, t.size)
    elif case == "flat":
        w = np.full(t.size, 3.0)
    elif case == "negative":
        w = 5 - np.sin(t)
    with pytest.raises(ValueError, match=message):
        identify(t, u, w)


# ---- the initial state, the line, the cost bound ----------------------------------------------

def test_a_log_that_starts_loaded_is_fitted_from_its_first_sample():
    """The search starts every candidate from the state the first samples imply: a log cut where the
    tendon is pulled far up identifies as well as one from rest, and its start is predicted."""
    u = filtered_random(T, 1.0, 2.5, offset=4.5, seed=11)
    w_true, w = noisy_log(u, 12)
    cut = 400 + int(np.argmax(u[400:3000]))
    assert w_true[cut] > np.median(w_true) + 1.0  # loaded
    wrong = BoucWenParams(a1=-0.005, a2=0.5, a3=1.5, az=0.3, A=8.0, n=2.0, b=(5, -2, 1, -1, 3, -5))
    res = identify(T[cut:], u[cut:], w[cut:], prior=wrong, maxiter=100)
    assert res.heldout_rms < 1.2 * 0.05 and res.train_rms < 1.2 * 0.05
    first_2s = slice(0, int(2 * FS))
    assert np.sqrt(np.mean((res.w_pred[first_2s] - w_true[cut:][first_2s]) ** 2)) < 0.05
    assert res.support.supported


def test_turning_points_ignore_jitter():
    t = np.linspace(0, 10, 5001)
    jitter = 0.01 * np.random.default_rng(0).standard_normal(t.size)
    assert turning_points(np.sin(2 * np.pi * t)) == 20  # 10 peaks, 10 troughs
    assert turning_points(np.sin(2 * np.pi * t) + jitter) == 20
    assert turning_points(t + jitter) == 0  # a ramp with noise never turns back by 5 % of its span
    assert turning_points(np.array([0.0, 1.0, 0.0, 1.0])) == 2


def _support_case(kind):
    """Hand-made logs for the support check: a 1 Hz sine, the last quarter held out."""
    t = np.arange(0, 40, 0.01)
    u = 5 + 2 * np.sin(2 * np.pi * 0.5 * t)
    w = 2 * u + 0.02 * np.random.default_rng(1).standard_normal(t.size)
    held = t >= 30
    train = ~held
    w_pred = w.copy()
    if kind == "few turns":
        u = np.where(train, 5 + 2 * np.sin(2 * np.pi * 0.04 * t), u)  # one slow swing in 30 s
        w = 2 * u + 0.02 * np.random.default_rng(1).standard_normal(t.size)
        w_pred = w + np.where(held, 1.0, 0.0)
    elif kind == "beyond range":
        u = np.where(held, 5 + 4 * np.sin(2 * np.pi * 0.5 * t), u)
        w = 2 * u
        w_pred = np.where(held, w + 0.5 * (u - 5) ** 2, w)
    elif kind == "drift":
        w = w + np.where(held, 0.1 * (t - 30), 0.0)
        w_pred = 2 * u - 0.3 * np.where(held, 1.0, 0.0)
    elif kind == "changed":
        loop = 0.3 * np.cos(2 * np.pi * 0.5 * t)  # a loop a line cannot follow
        w = 2 * u + loop
        w_pred = np.where(train, w, 2 * u - loop)  # fitted well, then the loop turns the other way
    elif kind == "no hysteresis":
        w_pred = w + 0.05 * np.sin(2 * np.pi * 3 * t)
    return t, u, w, w_pred, train, held


@pytest.mark.parametrize("kind, supported, needle", [
    ("perfect", True, "beats a straight line"),
    ("few turns", False, "too little excitation"),
    ("beyond range", False, "beyond the training range"),
    ("drift", False, "drifts"),
    ("changed", False, "behaves differently"),
    ("no hysteresis", False, "no hysteresis"),
])
def test_the_support_check_names_why_a_line_does_as_well(kind, supported, needle):
    t, u, w, w_pred, train, held = _support_case(kind)
    s = support_check(t, u, w, w_pred, train, held, noise=0.02)
    assert s.supported is supported
    assert needle in s.reason
    assert "\n" not in s.reason and "straight line" in s.reason


def test_a_held_out_part_that_loops_the_other_way_is_reported_as_unsupported():
    """The held-out quarter runs the plant backwards in time (its loop turns the other way, as if the
    rig changed): a hysteresis model fitted on the rest predicts it worse than a line, and says so."""
    t = np.arange(0, 20 * 100) / 100.0
    u = filtered_random(t, 1.0, 2.5, offset=4.5, seed=21)
    w_true, _, _ = forward(P, u)
    k = int(0.75 * t.size)
    u2 = np.concatenate([u[:k], u[k:][::-1]])
    w2 = np.concatenate([w_true[:k], w_true[k:][::-1]]) + 0.05 * np.random.default_rng(3).standard_normal(t.size)
    res = identify(t, u2, w2, maxiter=40, polish_evals=300)
    assert res.heldout_rms > res.linear_heldout_rms
    assert not res.support.supported
    assert res.support.reason.startswith("the data do not support the model")
    assert res.fit_dict()["supported"] is False


def test_a_diverging_candidate_is_rejected_within_its_budget():
    """A candidate the search once drew on a measured log (normalised units): the forward solve spends
    ten thousand sub-steps on the log (hundreds of thousands before a trial warp's reach was bounded), most
    of them on samples it cannot follow (past the turning point of its backbone). The fitting kernel gives
    up after its budget, at the price of a few ordinary evaluations."""
    from warpbridge.model import kernels as K
    from warpbridge.model.boucwen import rest_warp

    p = np.array([-0.07299, -0.08218, -0.1590, 1.0, 6.408, 4.406, 4.990e11, -2.495e11, 1.938e11, -2.495e11,
                  1.938e11, -3.876e11])
    u = np.sin(np.linspace(0, 6 * np.pi, 400))
    w0 = rest_warp(BoucWenParams.from_array(p), float(u[0]))
    budget = 500
    unbounded, wp, zp, zn = 0, w0, 0.0, -1.0
    for x in u:
        wp, zp, zn, _, taken = K._forward_solve(p, wp, zp, zn, x, -1, 1e-6)
        unbounded += taken
    assert unbounded > 10 * budget
    sse = K.forward_sse_budget(p, u, u, np.ones(u.size), w0, 0.0, budget, 1e-6)
    assert not np.isfinite(sse)
    used = 0
    wp, zp, zn = w0, 0.0, -1.0
    for x in u:
        wp, zp, zn, st, taken = K._forward_solve(p, wp, zp, zn, x, budget - used, 1e-6)
        used += taken
        if st != 0:
            break
    assert st != 0 and used <= budget


def test_a_stiff_loop_is_crossed_in_a_few_sub_steps():
    """A candidate the diagnosis drew on a stiff identified Dahl model (n = 5, b ~ 1e18): one sample runs from
    the unloading saturation through the loop to the loading one. The sub-step bound at an Euler step's
    landing point once took a long step's bound (deep in the saturation) at once and crawled through the
    loop's middle in steps of 1e-8 deg: 20,000 sub-steps and a failed solve. The solve takes a few dozen
    and lands where a stiff solver (scipy's Radau on dz/dw, written here from the model's equation) does."""
    from scipy.integrate import solve_ivp

    from warpbridge.model import kernels as K

    p = np.array([-0.01841547570872456, 0.9777738453033814, -0.6393145811716142, 1.0, 250.3694486717001,
                  4.999995199103737, 1.1775250569895537e18, 5.887625244798351e17, -5.879729715658113e17,
                  5.887625244798351e17, -5.879729715658113e17, -1.1759459511503194e18])
    w0, z0, u = 5.552245952957112, -0.016006925314893422, 4.236891460819856
    w, z, _, status, used = K._forward_solve(p, w0, z0, -1.0, u, -1, K.TOL_Z)
    assert status == 0 and used < 200
    assert abs(K.output_u(p, w, z) - u) < 1e-9
    A, n, b = p[4], p[5], p[6:]

    def dz_dw(_, y):  # loading (dw > 0) at w > 0: psi = b1 sz + b2 + b3 sz + b4 + b5 sz + b6
        sz = np.sign(y[0])
        return [A - abs(y[0]) ** n * (b[0] * sz + b[1] + b[2] * sz + b[3] + b[4] * sz + b[5])]

    ref = solve_ivp(dz_dw, (w0, w), [z0], method="Radau", rtol=1e-11, atol=1e-14)
    assert ref.success
    assert abs(z - ref.y[0, -1]) < 1e-8 * abs(ref.y[0, -1])


def test_the_search_scores_a_bounded_part_of_a_reversal_dense_log():
    u = filtered_random(np.arange(0, 60 * 500) / 500.0, 5.0, 2.5, offset=4.5, seed=2)
    n_end = int(0.75 * u.size)
    assert reversal_indices(u[:n_end]).size > 300
    ranges = fit_stretches(u, n_end, 60)
    assert ranges[0][0] == 0 and all(b <= n_end for _, b in ranges)
    assert sum(reversal_indices(u[a:b]).size for a, b in ranges) <= 60 + 2 * len(ranges)
    assert all(b0 <= a1 for (_, b0), (a1, _) in zip(ranges[:-1], ranges[1:], strict=True))  # no overlap
    assert fit_stretches(u[:2000], 2000, 10_000) == [(0, 2000)]


def test_a_transport_delay_in_front_of_the_hysteresis_is_found_not_widened_into_the_loop():
    # the rig's servo and link: the warp follows the tendon command 30 ms late
    from warpbridge.model.effects import delayed

    u = filtered_random(T, 1.0, 2.5, offset=4.5, seed=1)
    _, w = noisy_log(delayed(T, u, 0.03), 2)
    res = identify(T, u, w, maxiter=60, max_delay_s=0.16)
    assert res.delay_s == pytest.approx(0.03, abs=0.006)
    assert res.heldout_rms < 1.2 * 0.05
    without = identify(T, u, w, maxiter=60, max_lag_s=0.0)  # no delay, no servo lag
    assert without.delay_s == 0.0 and without.servo_tau_s == 0.0
    assert without.heldout_rms > 1.5 * res.heldout_rms  # the loop widened to take up the lag fits worse


def stepped_command(t: np.ndarray, seed: int) -> np.ndarray:
    """A closed loop's tendon command on setpoint steps: a new level every second, each reached through a
    feed-forward overshoot that decays in 30 ms (the jump the servo rounds off)."""
    rng = np.random.default_rng(seed)
    levels = rng.uniform(3.0, 6.0, int(t[-1]) + 1)
    k = np.floor(t).astype(int)
    jump = np.diff(levels, prepend=levels[0])[k]
    return levels[k] + 0.5 * jump * np.exp(-(t - k) / 0.03)


def test_the_servos_lag_is_found_in_front_of_the_hysteresis_on_a_stepped_closed_loop_log():
    t = T[: T.size // 2]  # 20 s: 20 steps
    u = stepped_command(t, 5)
    # the tendon follows the command through the servo's position loop, each row's command held until the next
    _, w = noisy_log(servo_follow(t, u, 0.02, math.inf, float(u[0])), 6)
    res = identify(t, u, w, maxiter=60)
    assert res.servo_tau_s == pytest.approx(0.02, abs=0.006) and math.isinf(res.servo_rate_mm_s)
    assert res.servo_deadband_mm == 0.0  # none where the servo has none
    assert res.trace.lag_train_rms[1] < 0.98 * res.trace.lag_train_rms[0]
    assert res.heldout_rms < 1.5 * res.noise
    bare = identify(t, u, w, maxiter=60, max_lag_s=0.0)  # fed the raw command, the model reverses at the spikes
    assert bare.servo_tau_s == 0.0 and bare.trace.lag_train_rms is None
    assert bare.heldout_rms > 3.0 * res.heldout_rms


def test_with_a_servo_the_scan_is_sure_of_the_escalation_waits_until_the_servo_is_refused(monkeypatch):
    """The model without the scan's sure servo is only a start and a yardstick: its global search runs only once
    the servo is refused, after the search through it. What the fold check did is reported of the model kept."""
    from warpbridge.model.identification import pipeline

    real_fold_check = pipeline.fold_check

    def fold_check(data, best, *rest):
        """As the real one, and the model without a servo always folded."""
        kept = real_fold_check(data, best, *rest)
        if not data.servo.active:
            trace = rest[1]
            trace.fold_deg, trace.working_range_deg, trace.fold_outcome = 1.0, (0.0, 2.0), "kept"
            trace.fold_train_rms = (1.0, 1.0)
        return kept

    monkeypatch.setattr(pipeline, "fold_check", fold_check)

    t = T[: T.size // 2]
    u = stepped_command(t, 5)
    _, w = noisy_log(servo_follow(t, u, 0.03, math.inf, float(u[0])), 6)  # the scan's servo halves its cost
    monkeypatch.setattr(pipeline, "ESCALATE_NOISES", 0.0)  # every first fit escalates ...
    monkeypatch.setattr(pipeline, "MAXITER_GLOBAL", 3)  # ... through a short search
    escalated = []
    real = pipeline.escalate

    def escalate(data, best, first, starts, seed, trace, *rest):
        escalated.append((data.servo.active, trace.lag_s > 0))  # (through a servo, after the pass through it)
        return real(data, best, first, starts, seed, trace, *rest)

    monkeypatch.setattr(pipeline, "escalate", escalate)
    kept = identify(t, u, w, maxiter=20)
    assert kept.servo_tau_s == pytest.approx(0.03, abs=0.008)
    assert escalated == [] and not kept.trace.global_search
    assert kept.trace.fold_deg is None and kept.trace.fold_outcome == ""  # the model through the servo's record
    monkeypatch.setattr(pipeline, "WAIT_MISS", 0.0)  # no servo cuts the miss decisively: the yardstick escalates
    judged = identify(t, u, w, maxiter=20)
    assert escalated == [(False, True)] and judged.servo_tau_s == pytest.approx(0.03, abs=0.008)
    assert judged.trace.fold_deg is None  # the record of the model kept, through the servo
    escalated.clear()
    monkeypatch.setattr(pipeline, "WAIT_MISS", 0.5)
    monkeypatch.setattr(pipeline, "lag_pays", lambda *a, **k: False)
    refused = identify(t, u, w, maxiter=20)
    assert refused.servo_tau_s == 0.0
    assert escalated == [(False, True)] and refused.trace.global_search  # after the pass, without the servo
    assert refused.trace.fold_deg == 1.0 and refused.trace.fold_outcome == "kept"


def test_a_servo_that_crosses_the_commands_jumps_at_its_rated_speed_is_found_capped():
    t = T[: T.size // 2]
    u = stepped_command(t, 5)  # jumps of up to 4.5 mm: at 60 mm/s the servo needs up to 75 ms for one
    _, w = noisy_log(servo_follow(t, u, 0.02, 60.0, float(u[0])), 6)
    res = identify(t, u, w, maxiter=60)
    assert res.servo_rate_mm_s == pytest.approx(60.0, rel=0.25)
    assert res.heldout_rms < 1.5 * res.noise
    assert res.fit_dict()["servo_rate_mm_s"] == res.servo_rate_mm_s


def test_a_servos_dead_band_is_found_where_it_stops_short_of_each_step():
    t = T[: T.size // 2]
    u = stepped_command(t, 5)  # each step the servo ends a half band short of the command, from its side
    # a 0.15 mm band: 10 us of pulse on a 10 mm horn, a worn hobby servo's
    _, w = noisy_log(servo_follow(t, u, 0.02, math.inf, float(u[0]), 0.15), 6)
    res = identify(t, u, w, maxiter=60)
    assert 0.07 <= res.servo_deadband_mm <= 0.3
    assert res.heldout_rms < 1.2 * res.noise
    assert res.fit_dict()["servo_deadband_mm"] == res.servo_deadband_mm


def test_a_servo_the_input_side_scan_misses_is_tried_where_the_model_without_it_misses_the_log():
    t = T[: T.size // 2]
    u = stepped_command(t, 2)  # through this servo the design's input-side costs favour the raw command
    _, w = noisy_log(servo_follow(t, u, 0.02, 100.0, float(u[0]), 0.03), 6)
    res = identify(t, u, w, maxiter=60)
    assert res.servo_tau_s == pytest.approx(0.02, abs=0.004)
    assert res.heldout_rms < 1.5 * res.noise  # 17x the noise without a servo


@pytest.mark.parametrize("command_seed", [6, 7], ids=["later-rounds", "while-above-the-noise"])
def test_the_servo_is_tuned_again_from_the_model_refined_through_it(command_seed):
    """A servo tuned from a model far from the data is off itself. Command seed 6: one round of tuning and
    refinement stops at a 25 ms servo without a cap, 1.3x the noise held out (fails with ``TUNE_ROUNDS = 1``).
    Command seed 7: the first round's 23 ms servo without a cap fits within 1.04x the noise on training and misses
    the held-out part 4.4x (fails with ``TUNE_ROUND_NOISES = 1.1``). The rounds after reach the truth."""
    t = T[: T.size // 2]
    u = stepped_command(t, command_seed)
    _, w = noisy_log(servo_follow(t, u, 0.02, 100.0, float(u[0]), 0.03), 6)
    res = identify(t, u, w, maxiter=60)
    assert res.heldout_rms < 1.15 * res.noise
    assert res.servo_tau_s == pytest.approx(0.02, abs=0.003)
    assert res.servo_rate_mm_s == pytest.approx(100.0, rel=0.1)


@pytest.mark.parametrize("seed", [0, 6])
def test_a_servos_lag_cap_and_band_are_found_together_on_the_bridges_stepped_log(seed):
    """The bridge's own cycle flying the SITL's wing on setpoint steps (lock-step): the servo's lag, rated speed
    and dead band each fit worse alone than none there, so only a joint tuning reaches the noise (one coordinate
    at a time settles near 25 ms, 115 mm/s and 0.2 mm, 1.2-1.6x the noise). Design seed 6 searched the model
    through the scan's servo without a dead band only, where the command's jitter reverses it: 3.6x the noise."""
    from warpbridge.sitl.lockstep import run_lockstep
    from warpbridge.sitl.scenarios import make_scenario
    from warpbridge.sitl.wing import WingSpec

    run, _ = run_lockstep(make_scenario("steps", seed=0), seed=0)
    servo = WingSpec().servo  # the truth: the SITL's servo
    res = identify(run.t, run.u_cmd["left"], run.measured["left"], seed=seed)
    assert res.heldout_rms < 1.15 * res.noise
    assert res.servo_tau_s == pytest.approx(servo.tau_s, abs=0.003)
    assert res.servo_rate_mm_s == pytest.approx(servo.max_speed_mm_s, rel=0.1)
    assert res.servo_deadband_mm < 0.15  # the SITL's is 2 us of pulse, 0.03 mm


def test_no_servo_lag_is_kept_where_the_tendon_follows_the_command(fitted):
    _, _, res = fitted  # a smooth random input and no lag: the scan finds nothing worth its parameter
    assert res.servo_tau_s == 0.0


def test_the_working_range_reaches_rest_on_a_one_sided_wing_and_widens_a_two_sided_one():
    from warpbridge.model.identification.checks import FOLD_MARGIN, working_range

    w = np.linspace(4.0, 10.0, 1001)  # its 0.5 and 99.5 percentiles: 4.03 and 9.97
    lo, hi = working_range(w, two_sided=False)
    assert lo == 0.0 and hi == pytest.approx(9.97 + FOLD_MARGIN * 5.94)
    lo, hi = working_range(-w, two_sided=False)  # a wing logged with the other sign
    assert hi == 0.0 and lo == pytest.approx(-9.97 - FOLD_MARGIN * 5.94)
    lo, hi = working_range(w - 7.0, two_sided=True)
    assert lo == pytest.approx(-2.97 - FOLD_MARGIN * 5.94) and hi == pytest.approx(-lo)


def test_only_a_backbone_folding_inside_the_range_counts_as_folding():
    from warpbridge.model.identification import fold_depth

    th = np.zeros((4, 9))
    # alpha1 (w - c)^2 + alpha2 (w - c): the vertex at c - alpha2 / (2 alpha1), c = 1
    th[:, 6] = [0.5, 0.5, -0.25, 0.0]
    th[:, 7] = [1.0, 3.0, 1.0, 1.0]  # vertices 0, -2, 3 and none (a straight backbone)
    d = fold_depth(th, 1.0, -1.0, 2.0)
    assert d[0] == pytest.approx(1.0 / 3.0) and d[1] == 0.0 and d[2] == 0.0 and d[3] == 0.0


def test_a_backbone_folding_where_the_wing_flies_is_searched_again_without_the_fold():
    """A bench log that covers only the upper part of the travel of a wing whose best fit folds below it: the
    model kept has no fold between rest and half a span beyond the log's warp, and the fit says what happened."""
    from warpbridge.model.identification.checks import FOLD_KEEP, working_range

    folding = BoucWenParams(a1=0.05, a2=-0.2, a3=1.0, az=P.az, A=P.A, n=P.n, b=P.b)  # vertex at 2 deg
    u = filtered_random(T[:4000], 1.0, 1.6, offset=3.6, seed=4)
    _, w = noisy_log(u, 3, params=folding)
    assert np.percentile(w, 0.5) > 3.0  # the log never goes near the fold
    res = identify(T[:4000], u, w, maxiter=60, polish_evals=600, seed=7)
    lo, hi = working_range(w, res.two_sided)
    assert res.trace.fold_deg is not None and lo < res.trace.fold_deg < hi  # the first search folded inside
    assert res.trace.fold_outcome == "kept"
    p = res.params
    vertex = -p.a2 / (2.0 * p.a1)
    assert not lo < vertex < hi
    fit = res.fit_dict()
    assert fit["backbone_fold_deg"] == res.trace.fold_deg and fit["working_range_deg"] == [lo, hi]
    assert fit["fold_search_kept"] is True
    first, unfolded = fit["fold_train_rms_deg"]
    assert unfolded <= FOLD_KEEP * first and res.train_rms == unfolded
    ramp = np.linspace(float(np.min(u)) - 1.0, float(np.max(u)), 500)
    w_ramp, _, flagged = forward(p, ramp)  # below the log's travel the model goes on down instead of holding
    assert flagged == 0 and w_ramp[0] < np.percentile(w, 0.5) - 0.5


def test_the_fold_check_refines_further_starts_apart_and_never_takes_a_fold_from_them():
    """``fold_check(more=...)``: the further starts (after an escalation, a global search's members) are refined in
    a search of their own, not ranked among the design's; the better fit without a fold is kept, and a result
    of theirs that still folds is not taken however well it fits."""
    from warpbridge.model.identification.checks import fold_check, folds
    from warpbridge.model.identification.data import read
    from warpbridge.model.identification.design import Starts
    from warpbridge.model.identification.refine import SearchTrace, evaluate
    from warpbridge.model.identification.space import normalised_to_theta

    folding = BoucWenParams(a1=0.05, a2=-0.2, a3=1.0, az=P.az, A=P.A, n=P.n, b=P.b)  # vertex at 2 deg
    u = filtered_random(T[:4000], 1.0, 1.6, offset=3.6, seed=4)
    _, w = noisy_log(u, 3, params=folding)
    data = read(T[:4000], u, w, 0.25)

    def theta(p):
        th = normalised_to_theta(data.norm.to_normalised(p), data.two_sided, data.norm.c)
        assert th is not None
        return th

    truth = theta(folding)
    # two straight backbones (no fold), one nearer the wing's than the other
    near = theta(BoucWenParams(a1=0.0, a2=0.6, a3=-2.0, az=P.az, A=P.A, n=P.n, b=P.b))
    far = theta(BoucWenParams(a1=0.0, a2=0.4, a3=-0.8, az=P.az, A=P.A, n=P.n, b=P.b))
    assert folds(data, truth) and not folds(data, near) and not folds(data, far)
    rms = {k: evaluate(data, th, 0.0).train_rms for k, th in (("truth", truth), ("near", near), ("far", far))}
    assert rms["truth"] < rms["near"] < rms["far"]
    calls = []

    def search(thetas, names, fold, stage):
        """No refinement: each search returns its first start (no delay), and says what it was given."""
        calls.append((np.array(thetas), list(names), stage))
        return thetas[0], 0.0

    design = Starts(thetas=np.vstack([truth, far]), input_rms=np.zeros(2), labels=["design", "line"],
                    evaluations=0)

    def check(more):
        calls.clear()
        trace = SearchTrace()
        kept = fold_check(data, evaluate(data, truth, 0.0), design, trace, search, more)
        return kept, trace

    # the design's folding start is left out; alone, the design's start without a fold is what is compared
    _, alone = check(None)
    assert len(calls) == 1 and calls[0][1] == ["line"] and np.array_equal(calls[0][0], far[None, :])
    assert alone.fold_train_rms == (rms["truth"], rms["far"])
    # further starts: searched in a call of their own, and the better on training kept
    _, further = check(np.vstack([near, far]))
    assert [c[1] for c in calls] == [["line"], ["global", "global"]]
    assert further.fold_train_rms == (rms["truth"], rms["near"])
    assert further.fold_outcome == "fits worse"  # FOLD_KEEP then decides, as for the design's starts
    # a further start that still folds after its search is not taken, although it fits best
    _, folded = check(truth[None, :])
    assert folded.fold_train_rms == (rms["truth"], rms["far"])


def test_a_fold_the_log_itself_shows_is_kept():
    """A backbone that turns at 16.7 deg and a log that reaches it: without the fold the fit is twice as bad on
    the training part, so the first search's model, fold and all, is kept and the fit says why."""
    from warpbridge.model.identification.checks import FOLD_KEEP

    turning = BoucWenParams(a1=-0.03, a2=1.0, a3=-1.0, az=P.az, A=P.A, n=P.n, b=P.b)  # vertex at 16.7 deg
    u = filtered_random(T[:4000], 1.0, 2.2, offset=6.5, seed=4)
    w = forward(turning, u)[0] + 0.05 * np.random.default_rng(3).standard_normal(4000)
    res = identify(T[:4000], u, w, maxiter=60, polish_evals=600, seed=7)
    first, unfolded = res.trace.fold_train_rms
    assert res.trace.fold_deg is not None and res.trace.fold_outcome == "fits worse"
    assert unfolded > FOLD_KEEP * first and res.train_rms == first
    p = res.params
    assert -p.a2 / (2.0 * p.a1) == pytest.approx(res.trace.fold_deg)  # the first model, its fold with it
    assert res.fit_dict()["fold_search_kept"] is False


def test_a_backbone_that_does_not_fold_is_searched_once(fitted):
    _, _, res = fitted
    assert res.trace.fold_deg is None and res.trace.fold_outcome == ""
    assert "backbone_fold_deg" not in res.fit_dict()


def test_a_fit_is_never_worse_than_the_straight_line_it_contains():
    """A wing without hysteresis (warp a line of the tendon plus noise): the model class holds the line, so the
    fit's training RMS is at most the line's, and it says when it cannot beat the line on held-out data."""
    t = np.arange(0, 20 * 100) / 100.0
    u = filtered_random(t, 1.0, 2.5, offset=4.5, seed=31)
    w = 1.7 * u - 0.4 + 0.05 * np.random.default_rng(5).standard_normal(t.size)
    res = identify(t, u, w)
    assert res.train_rms <= res.linear_train_rms * (1 + 1e-9)
    assert res.heldout_rms < 1.1 * 0.05
    assert np.all(np.isfinite(res.w_pred))


def test_a_fit_worse_than_the_line_is_refined_again_from_it(monkeypatch):
    """A failed refinement (made to return its start with a backbone that is no model of this wing) fits the
    training part worse than the line: the result comes from the line's start instead, never worse than it."""
    from warpbridge.model.identification.refine import Refiner

    u = filtered_random(T[:3000], 1.0, 2.5, offset=4.5, seed=4)
    _, w = noisy_log(u, 3)
    real = Refiner.run

    def failing(self, thetas, labels, n_refine):
        if self.stage == "line":
            return real(self, thetas, labels, n_refine)
        th = thetas[0].copy()
        th[6:9] = [0.0, 0.3, 3.0]  # far off the data
        return th, 1.0, labels[0]

    monkeypatch.setattr(Refiner, "run", failing)
    res = identify(T[:3000], u, w, maxiter=10, polish_evals=200)
    assert res.trace.line_restart
    assert res.train_rms <= res.linear_train_rms
    assert res.heldout_rms < 1.2 * 0.05  # refined from the line, the loop is found
    assert res.fit_dict()["line_restart"] is True


def test_every_parameter_gets_an_interval_and_the_undetermined_are_named(fitted):
    _, _, res = fitted
    unc = res.uncertainty
    assert unc is not None and set(unc.params) == {"a1", "a2", "a3", "az", "A", "n", "b1", "b2", "b3", "b4", "b5",
                                                   "b6"}
    for name in ("a1", "a2", "a3", "A", "n"):
        iv = unc.params[name]
        assert iv.lo < iv.value < iv.hi and iv.se > 0
    assert unc.params["az"].se == 0.0  # the scale is fixed
    assert unc.params["n"].lo < P.n < unc.params["n"].hi  # the paper's exponent lies inside the 95 % interval
    assert 1 <= unc.effective_samples <= unc.samples
    d = res.fit_dict()["uncertainty"]
    assert d["params"]["n"]["determined"] in (True, False) and d["level"] == 0.95
    assert set(d["undetermined"]) == set(unc.undetermined)


def test_a_log_with_one_reversal_level_says_so_and_leaves_parameters_open():
    """A sine of one amplitude turns back at the same two heights: the minor loops are not excited, which the
    excitation check says; a short one on a narrow band also leaves parameters undetermined."""
    t = np.arange(0, 20 * 100) / 100.0
    u = 4.5 + 2.5 * np.sin(2 * np.pi * 0.5 * t)
    _, w = noisy_log(u, 7)
    res = identify(t, u, w)
    assert res.excitation.poor and any("one level" in n for n in res.excitation.notes)
    narrow = 4.5 + 0.05 * np.sin(2 * np.pi * 0.5 * t)
    _, wn = noisy_log(narrow, 8)
    res2 = identify(t, narrow, wn, maxiter=10, polish_evals=200)
    assert any("narrow band" in n for n in res2.excitation.notes)
    assert res2.uncertainty is not None and res2.uncertainty.undetermined


def _wide_two_sided_log():
    t = np.arange(0, 30 * FS) / FS
    u = filtered_random(t, 1.0, 4.0, offset=0.5, seed=3)
    w = forward(P, u)[0] + 0.05 * np.random.default_rng(4).standard_normal(u.size)
    return t, u, w


def test_starts_that_disagree_escalate_to_a_global_search_and_the_lowest_training_error_is_kept():
    # a wide loop through zero warp behind 0.6 mm of play the model does not hold: the design's refined starts
    # settle in different minima, so the global search runs; the fit kept is the candidate that runs free best
    # on the training part
    t, u, _ = _wide_two_sided_log()
    w = forward(P, play(u, 0.6, float(u[0])))[0] + 0.05 * np.random.default_rng(4).standard_normal(u.size)
    res = identify(t, u, w)
    tr = res.trace
    assert res.two_sided
    assert tr.global_search and tr.global_generations > 0
    from_design, from_global = tr.global_train_rms
    assert tr.global_kept == (from_global < from_design)
    assert res.train_rms <= min(from_design, from_global) * (1 + 1e-9)  # later steps may only lower it
    assert res.fit_dict()["global_search"] is True
    assert res.train_rms < 1.5 * 0.05


def test_a_wide_two_sided_loop_needs_no_global_search():
    # the design's refined starts agree on the paper's wing through zero warp: the fit is at the noise without it
    t, u, w = _wide_two_sided_log()
    res = identify(t, u, w)
    assert res.two_sided and not res.trace.global_search
    assert res.train_rms < 1.05 * 0.05 and res.heldout_rms < 1.1 * 0.05


def test_the_global_search_is_deterministic_for_a_seed():
    from warpbridge.model.identification.global_search import global_search
    from warpbridge.model.identification.path import FitPath, Objective

    t, u, w = _wide_two_sided_log()
    uh, wh = (u - u.mean()) / np.ptp(u), w / np.ptp(w)
    obj = Objective(FitPath.build(uh, wh, u.size, 600, 30), 0.0)
    from warpbridge.model.identification.space import BOUNDS_TWO_SIDED
    lo, hi = np.array([b[0] for b in BOUNDS_TWO_SIDED]), np.array([b[1] for b in BOUNDS_TWO_SIDED])
    seeded = 0.5 * (lo + hi)[None, :]
    a = global_search(obj, lo, hi, seeded, 3, popsize=20, maxiter=5)
    b = global_search(obj, lo, hi, seeded, 3, popsize=20, maxiter=5)
    assert np.array_equal(a.thetas, b.thetas) and np.array_equal(a.costs, b.costs)
    assert np.all(np.diff(a.costs) >= 0) and a.costs[0] <= obj.one(seeded[0])  # the seeded start is in it


def test_the_logged_send_times_put_the_servo_where_it_was_on_a_fast_closed_loop_log():
    """A loaded loop writes each command 0-4 ms after its sensor read; on a fast sweep the servo moves enough
    in that time that a model holding each command from its row's time misses by more than the noise. Given
    the send times (the cycle log's ``<wing>_u_sent``), identify reaches the noise (0.03 deg)."""
    from warpbridge.sitl.servo_model import ServoModel, ServoSpec

    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(0.008, 0.012, 2000))  # 20 s of a 100 Hz loop's uneven cycles
    f = 0.3 + 2.7 * (t - t[0]) / (t[-1] - t[0])  # a sweep from 0.3 to 3 Hz
    phase = 2 * np.pi * np.cumsum(np.r_[0.0, f[:-1] * np.diff(t)])
    u = 4.5 + 2.0 * np.sin(phase) + 0.5 * np.sin(2.3 * phase)
    sent = rng.uniform(0.0, 0.004, t.size)
    spec = ServoSpec(deadband_us=0.0, quantum_us=0.0, tau_s=0.02, s_per_60deg=0.01)  # 20 ms, no cap reached
    servo = ServoModel(spec, t0=t[0], pulse0_us=spec.pulse_of(u[0]))
    x = [servo.mm]
    for k in range(1, t.size):  # the SITL's servo in substeps: the row before's command holds until the send
        for tk in np.linspace(t[k - 1], t[k - 1] + sent[k - 1], 5)[1:]:
            servo.step(tk, spec.pulse_of(u[k - 2] if k > 1 else u[0]))
        for tk in np.linspace(t[k - 1] + sent[k - 1], t[k], 21)[1:]:
            servo.step(tk, spec.pulse_of(u[k - 1]))
        x.append(servo.mm)
    _, w = noisy_log(np.array(x), 8, noise=0.03)
    res = identify(t, u, w, maxiter=60, sent=sent)
    assert res.servo_tau_s == pytest.approx(0.02, abs=0.005)
    assert res.heldout_rms < 1.15 * 0.03
    at_rows = identify(t, u, w, maxiter=60)
    assert at_rows.heldout_rms > 1.4 * res.heldout_rms
