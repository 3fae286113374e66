"""The generalized Bouc-Wen model both ways: round trip, rate independence, robustness, stepper parity."""

import numpy as np
import pytest

from warpbridge.model.boucwen import BoucWenParams, Stepper, forward, inverse
from warpbridge.model.excitation import filtered_random, multisine_reversals

P = BoucWenParams.paper()


def triangle_path(fs: float, vertices, seg_s: float = 0.5) -> np.ndarray:
    """Piecewise-linear warp through ``vertices``, one vertex every ``seg_s``, sampled at fs (vertices on the grid)."""
    n = int(round(seg_s * fs))
    parts = [np.linspace(a, b, n, endpoint=False) for a, b in zip(vertices[:-1], vertices[1:], strict=True)]
    return np.concatenate(parts + [np.array([vertices[-1]])])


def test_forward_inverts_inverse_to_1e6_deg():
    t = np.arange(0, 30, 1 / 500)
    w = multisine_reversals(t, (4.0, 1.5, 0.6), (0.5, 1.3, 3.1), offset=8.0)
    u, _ = inverse(P, w)
    w2, _, flagged = forward(P, u, w0=w[0])
    assert flagged == 0
    assert np.max(np.abs(w2 - w)) < 1e-6


def test_inverse_of_forward_round_trips():
    t = np.arange(0, 20, 1 / 500)
    u = filtered_random(t, 1.0, 2.5, offset=4.5, seed=3)
    w, _, flagged = forward(P, u)
    assert flagged == 0
    u2, _ = inverse(P, w)
    assert np.max(np.abs(u2 - u)) < 1e-6


@pytest.mark.parametrize("direction", ["inverse", "forward"])
def test_output_does_not_depend_on_sample_rate_when_reversals_are_sampled(direction):
    rng = np.random.default_rng(0)
    vertices = np.concatenate([[2.0], 2 + 10 * rng.random(24)])
    out = {}
    for fs in (100, 500, 2000):
        w = triangle_path(fs, vertices)
        if direction == "inverse":
            y, _ = inverse(P, w)
        else:
            u, _ = inverse(P, w)
            y, _, _ = forward(P, u, w0=w[0])
        out[fs] = y[:: fs // 100]
    # inverse output is tendon mm (1e-3 mm ~ 1e-3 deg of warp); forward output is warp deg
    tol = 1e-3 if direction == "inverse" else 1e-5
    for fs in (500, 2000):
        assert np.max(np.abs(out[fs] - out[100])) < tol


def test_smooth_input_at_100_500_2000_hz_agrees_within_a_hundredth_of_a_degree():
    out = {}
    for fs in (100, 500, 2000):
        t = np.arange(0, 20 * fs) / fs
        u = 4.5 + 2.0 * np.sin(2 * np.pi * 1.0 * t) + 0.8 * np.sin(2 * np.pi * 2.3 * t)
        w, _, flagged = forward(P, u)
        assert flagged == 0
        out[fs] = w[:: fs // 100]
    assert np.max(np.abs(out[500] - out[100])) < 0.01
    assert np.max(np.abs(out[2000] - out[100])) < 0.01


@pytest.mark.parametrize("amplitude", [0.1, 1.0, 5.0, 12.0, 25.0])
def test_no_nan_for_any_amplitude_or_reversal_density(amplitude):
    rng = np.random.default_rng(int(amplitude * 10))
    t = np.arange(0, 10, 1 / 500)
    w = amplitude * (0.5 + 0.5 * np.sin(2 * np.pi * 2.0 * t)) + 0.05 * rng.standard_normal(t.size)
    u, z = inverse(P, w)
    assert np.all(np.isfinite(u)) and np.all(np.isfinite(z))
    # and the forward map on a tendon path with a reversal every sample (pure jitter)
    uj = 4.0 + amplitude * 0.2 * rng.standard_normal(t.size)
    wj, zj, _ = forward(P, uj)
    assert np.all(np.isfinite(wj)) and np.all(np.isfinite(zj))


def test_explicit_euler_would_blow_up_but_the_model_stays_bounded():
    # one huge step right after a reversal: |z|^n Psi ~ 60 per deg
    w = np.array([10.0, 0.5, 12.0, 0.5, 12.0])
    u, z = inverse(P, w)
    lo, hi = -1.36, 1.51  # the paper model's saturation levels of z
    assert np.all(z > lo - 1e-6) and np.all(z < hi + 1e-6)


def test_nan_samples_hold_the_state():
    w = np.array([5.0, 6.0, np.nan, 7.0])
    u, _ = inverse(P, w)
    assert np.isfinite(u).all()
    assert u[2] == u[1]


def test_stepper_gives_identical_results_to_the_array_maps():
    t = np.arange(0, 5, 1 / 500)
    w = multisine_reversals(t, offset=8.0)
    u, _ = inverse(P, w)
    s = Stepper(P, w0=w[0])
    u_step = np.array([s.inverse_step(x) for x in w])
    assert np.array_equal(u_step, u)
    wf, _, _ = forward(P, u, w0=w[0])
    s2 = Stepper(P, w0=w[0])
    w_step = np.array([s2.forward_step(x) for x in u])
    assert np.array_equal(w_step, wf)


def test_scale_redundancy_gives_the_same_output():
    t = np.arange(0, 5, 1 / 500)
    w = multisine_reversals(t, offset=8.0)
    u1, _ = inverse(P, w)
    for c in (0.3, 1.0 / P.az, 7.0):
        u2, _ = inverse(P.scaled(c), w)
        assert np.max(np.abs(u2 - u1)) < 1e-4  # integration tolerance is set in units of z
    assert P.canonical().az == pytest.approx(1.0)


def test_hysteresis_loop_has_the_papers_shape():
    # loading branch lies right of the unloading branch: more tendon needed on the way up
    leg = np.linspace(2.0, 12.0, 400)
    w = np.concatenate([leg, leg[::-1], leg])
    u, _ = inverse(P, w)
    up = u[-400:]
    down = u[400:800][::-1]
    width = up - down
    assert np.all(width[20:-20] > 0.5)  # mm: a real loop, not a line
    assert np.all(np.diff(up) > 0)  # monotone on the working range


def test_params_validate_and_round_trip():
    d = P.to_dict()
    assert BoucWenParams.from_dict(d) == P
    with pytest.raises(ValueError):
        BoucWenParams.from_dict({**d, "n": 0.5})
    with pytest.raises(ValueError):
        BoucWenParams.from_dict({k: v for k, v in d.items() if k != "A"})
    with pytest.raises(ValueError):
        BoucWenParams.from_dict({**d, "b": [1, 2, 3]})


def test_a_long_move_from_rest_into_a_stiff_saturation_stays_accurate():
    """Large A and n: z is soft near 0 and very stiff at saturation, so a step sized where it starts
    would jump straight past saturation (this once returned NaN); it must match a chain of tiny steps."""
    from warpbridge.model import kernels as K

    p = BoucWenParams(a1=-0.0205, a2=0.712, a3=0.7958, az=0.5369, A=8.29, n=4.33,
                      b=(23.46, -11.37, 0.773, -3.935, 14.75, -11.14)).to_array()
    for z0, w1 in ((0.0, 6.88), (0.1, 5.9), (-0.9, 7.5)):
        big = K.integrate_z(p, 5.0, z0, w1)
        z = z0
        for a, b in zip(np.linspace(5.0, w1, 4001)[:-1], np.linspace(5.0, w1, 4001)[1:], strict=True):
            z = K.integrate_z(p, a, z, b)
        assert np.isfinite(big) and abs(big - z) < 1e-6, (z0, w1, big, z)


def test_a_sample_beyond_the_range_from_a_near_flat_start_stops_at_the_edge_within_one_march():
    """A candidate a diagnosis fit drew on a 383 deg sheath: held at the range's edge at w ~ 0, where the
    slope du/dw is 6e-7, the next releasing sample cannot be followed (past w = 0 the hysteretic term turns
    u back). A Newton guess from that slope lands 1.5e6 deg away; trial warps that far each ran out of
    sub-steps before the bisection came back (210 000 sub-steps for this one sample). The sample must stay
    at the edge and cost less than one march's sub-step allowance."""
    from warpbridge.model import kernels as K

    p = np.array([0.04882922073694175, 7.59596870033999e-08, 3.5620759518609826, 1.0, 55.2110080890175,
                  4.994154015953744, 1.6361126872335243e21, 8.180563435771711e20, -6.929481894915029e20,
                  8.180563435771711e20, -6.929481894915029e20, -1.38589637906185e21])
    w0, z0, u = 6.842125925439273e-15, -0.04376482399996928, 3.403994620743479
    assert K.output_u(p, w0, z0) - u > 0.1  # a release the model must follow by 0.11 mm
    w, z, _, status, used = K._forward_solve(p, w0, z0, -1.0, u, -1, K.TOL_Z)
    assert status == 1 and w == w0 and z == z0
    assert used < K.MAX_SUBSTEPS


# a candidate a diagnosis fit drew on a LuGre rig, held at its range's edge: on a release |z| grows without
# bound (Psi > 0 with z against the motion, |z|^n Psi > A), passing any cap 1.7e-13 deg from the start
LUGRE_CANDIDATE = np.array([0.008997178380463764, 0.610308641392281, -0.4597136022554469, 1.0, 117.3167819696055,
                            4.975502231065359, 5.007772332134897e19, 2.5038592922966987e19, 9.951167080672473e20,
                            2.5038592922966987e19, 9.951167080672473e20, 1.9902328797654677e21])
LUGRE_EDGE = (7.725389614747737, 0.004280361061038601)


def test_a_release_into_a_blow_up_stops_at_the_edge_within_one_march():
    """Each march past the blow-up crawled through 4238 ever shorter sub-steps to the cap on |z| before it
    counted as diverged, and the bisection back to the edge took 33 of them (135 623 sub-steps for one
    sample). A march bound to pass the blow-up ends at once: the sample stays at the edge, and cheaply."""
    from warpbridge.model import kernels as K

    w0, z0 = LUGRE_EDGE
    u = 4.7287308451585925
    assert K.output_u(LUGRE_CANDIDATE, w0, z0) - u > 0.05
    w, z, _, status, used = K._forward_solve(LUGRE_CANDIDATE, w0, z0, -1.0, u, -1, K.TOL_Z)
    assert status == 1 and w == w0 and z == z0
    assert used < K.MAX_SUBSTEPS


def test_a_march_short_of_a_blow_up_is_integrated_as_before_and_one_past_it_ends_at_once():
    """With the blow-up ending on, a march short of the blow-up gives bit for bit what the march without it
    gives; a march past it is NaN either way, but ends in a few sub-steps instead of crawling to the cap."""
    from warpbridge.model import kernels as K

    w0, z0 = LUGRE_EDGE
    for w1 in (w0 - 1e-14, w0 - 1.5e-13):
        ended = K._march(LUGRE_CANDIDATE, w0, z0, -1.0, w1, K.MAX_SUBSTEPS, K.TOL_Z, True)
        crawled = K._march(LUGRE_CANDIDATE, w0, z0, -1.0, w1, K.MAX_SUBSTEPS, K.TOL_Z, False)
        assert np.isfinite(ended[0]) and ended == crawled
    w1 = w0 - 1e-12
    ended = K._march(LUGRE_CANDIDATE, w0, z0, -1.0, w1, K.MAX_SUBSTEPS, K.TOL_Z, True)
    crawled = K._march(LUGRE_CANDIDATE, w0, z0, -1.0, w1, K.MAX_SUBSTEPS, K.TOL_Z, False)
    assert np.isnan(ended[0]) and np.isnan(crawled[0])
    assert ended[5] < 100 and crawled[5] > 1000


@pytest.mark.parametrize("z0", [1e-4, 1e-3, -1e-4, 0.0])
@pytest.mark.parametrize("h", [0.25, 0.1, 0.02])
def test_one_move_leaving_zero_matches_a_chain_of_tiny_moves(z0, h):
    """Near z = 0 the hysteretic state is soft but curves sharply on its way out: one move must land
    where many tiny ones do, whatever the sample spacing."""
    from warpbridge.model import kernels as K

    p = P.to_array()
    big = K.integrate_z(p, 0.5, z0, 0.5 + h)
    z = z0
    grid = np.linspace(0.5, 0.5 + h, 4001)
    for a, b in zip(grid[:-1], grid[1:], strict=True):
        z = K.integrate_z(p, a, z, b)
    # a 0.25 deg move is a huge sample step; 2e-5 in z is 1e-5 mm of tendon (the kernels once erred by 2e-3)
    assert abs(big - z) < 2e-5, (big, z)


@pytest.mark.parametrize("effects", ["none", "slack", "capstan", "sensor", "released"])
def test_plant_stepper_gives_identical_results_to_plant_simulate(effects):
    from warpbridge.model.effects import PULLED, RELEASED, Effects
    from warpbridge.model.plant import Plant, PlantStepper

    e = {"none": Effects(),
         "slack": Effects(backlash_mm=0.2, pretension_offset_mm=0.3, pretension_gain=0.9),
         "capstan": Effects(backlash_mm=0.1, capstan_pull_ratio=0.04, capstan_release_ratio=0.02,
                            capstan_zero_mm=1.0),
         "sensor": Effects(sensor_tau_s=0.03, sensor_stage_ratio=0.6, drift_deg_s=0.01),
         "released": Effects(backlash_mm=0.4, capstan_pull_ratio=0.04, capstan_release_ratio=0.02)}[effects]
    plant = Plant(P, e, slack_side=RELEASED if effects == "released" else PULLED)
    t = np.arange(0, 6, 1 / 500)
    u = filtered_random(t, 1.0, 2.5, offset=4.5, seed=4)
    w_true, w_meas = plant.simulate(t, u)
    s = PlantStepper(plant, t[0], u[0])
    steps = np.array([s.step(tk, uk) for tk, uk in zip(t, u, strict=True)])
    assert np.array_equal(steps[:, 0], w_true)
    np.testing.assert_allclose(steps[:, 1], w_meas, rtol=0, atol=1e-12)


def test_the_fits_budgeted_cost_holds_a_saturated_sample_where_the_forward_map_does():
    # a backbone that turns back at 10 deg (a1 < 0), driven past its top: the forward map holds the warp at the
    # edge on those samples (flagged) and goes on; the search's cost must score the same warps, not reject the
    # model (the best fits of measured logs saturate on a few samples)
    from warpbridge.model import kernels as K

    p = BoucWenParams(a1=-0.05, a2=1.0, a3=0.0, az=1.0, A=1.0, n=2.0, b=(0.3, 0.0, 0.0, 0.0, 0.2, 0.0))
    t = np.arange(0, 4000) / 500.0
    u = 3.0 + 3.5 * np.sin(2 * np.pi * 0.5 * t)  # beyond the model's monotone range near each crest
    w, _, flagged = forward(p, u, w0=0.0, z0=0.0)
    assert 0 < flagged < u.size // 4
    w_meas = w + 0.05 * np.random.default_rng(0).standard_normal(u.size)
    pa = p.to_array()
    want = float(np.sum((w - w_meas) ** 2))
    for tol in (1e-6, 1e-8):
        got = K.forward_sse_budget(pa, u, w_meas, np.ones(u.size), 0.0, 0.0, 10 ** 7, tol)
        assert got == pytest.approx(want, rel=1e-3)
