"""What a verdict leaves: the scored block that holds most of the residual above the floor, and why."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from warpbridge.bridge.commands.diagnose_plot import plot_diagnosis
from warpbridge.model.boucwen import BoucWenParams, inverse
from warpbridge.model.diagnosis import diagnose
from warpbridge.model.diagnosis.blocks import make_split
from warpbridge.model.diagnosis.left import left_over, left_over_note
from warpbridge.model.diagnosis.options import DiagnoseOptions
from warpbridge.model.effects import Effects, servo_travel
from warpbridge.model.excitation import filtered_random
from warpbridge.model.modelfile import FitQuality, ModelFile
from warpbridge.model.plant import Plant

FS = 200.0
NOISE = 0.03
P = BoucWenParams.paper()


def log_input(seed: int = 0, seconds: float = 20.0, bandwidth_hz: float = 1.0):
    t = np.arange(int(seconds * FS)) / FS
    u, _ = inverse(P, filtered_random(t, bandwidth_hz, 4.5, 7.0, seed=seed))
    return t, u


def scored_blocks(sp):
    return [(i0, i1) for i0, i1, kind in sp.blocks if kind == "score"]


def test_white_residual_at_the_floor_leaves_nothing():
    t, u = log_input()
    sp = make_split(t, u)
    r = NOISE * np.random.default_rng(1).standard_normal(t.size)
    assert left_over(t, u, r, sp, NOISE ** 2, 0.5) is None


def test_an_excess_in_one_scored_block_is_placed_there():
    t, u = log_input()
    sp = make_split(t, u)
    r = NOISE * np.random.default_rng(2).standard_normal(t.size)
    i0, i1 = scored_blocks(sp)[1]
    r[i0:i1] += 0.2 * np.sin(np.linspace(0, 20, i1 - i0))
    lo = left_over(t, u, r, sp, NOISE ** 2, 0.5)
    assert lo is not None and lo.mostly
    assert lo.share_of_excess > 0.9
    assert lo.block_s == [pytest.approx(t[i0]), pytest.approx(t[i1 - 1])]
    assert "held out against a floor" in left_over_note(lo, named=True)


def test_an_excess_spread_over_every_scored_block_is_not_placed_in_one():
    t, u = log_input()
    sp = make_split(t, u)
    r = NOISE * np.random.default_rng(3).standard_normal(t.size)
    r[sp.score] += 0.1 * np.sin(2 * np.pi * 0.7 * t[sp.score])
    lo = left_over(t, u, r, sp, NOISE ** 2, 0.5)
    assert lo is not None and not lo.mostly
    assert lo.share_of_excess < 0.5
    assert left_over_note(lo, named=False) is None


def test_a_block_past_the_training_travel_and_airspeed_says_so():
    t, u = log_input()
    sp = make_split(t, u)
    i0, i1 = scored_blocks(sp)[0]
    u = u.copy()
    u[i0:i1] += u.max() - u.min()  # that block's tendon travels beyond all the others
    v = np.full(t.size, 12.0)
    v[i0:i1] = 20.0
    r = NOISE * np.random.default_rng(4).standard_normal(t.size)
    r[i0:i1] += 0.3
    lo = left_over(t, u, r, sp, NOISE ** 2, 0.5, v)
    assert {"tendon travel", "airspeed"} <= set(lo.beyond_training)
    note = left_over_note(lo, named=True)
    assert "outside the training blocks' range" in note and "flies faster there" in note


def fast_excursion_log(seed: int = 5):
    """A log whose command moves fast once, in a block the split scores: a servo slewing a little faster
    than the log's other blocks move is reached there alone."""
    t, base = log_input(seed, bandwidth_hz=0.5)
    for k in range(10):  # the excursion's place: the first that leaves its block scored
        tc = t[-1] * (k + 0.5) / 10
        bump = 3.0 * np.exp(-0.5 * ((t - tc) / 0.04) ** 2)  # about 3x the log's fastest motion elsewhere
        u = base + bump
        sp = make_split(t, u)
        block = next(b for b in sp.blocks if b[0] <= np.searchsorted(t, tc) < b[1])
        if block[2] == "score":
            return t, u, tc, sp
    raise AssertionError("no placement left the excursion in a scored block")


@pytest.mark.slow
def test_a_slew_limit_reached_in_one_scored_block_is_reported_where_it_lies(tmp_path, saved_figures):
    t, u, tc, sp = fast_excursion_log()
    speed = np.abs(np.gradient(u, t))
    near = np.abs(t - tc) < 0.5
    rate = 0.5 * (float(np.max(speed[~near])) + float(np.max(speed[near])))  # reached in the excursion only
    _, w = Plant(P, Effects(rate_mm_s=rate)).simulate(t, u, None)
    w = w + NOISE * np.random.default_rng(6).standard_normal(t.size)
    model = ModelFile(params=P, fit=FitQuality(train_rms_deg=NOISE, heldout_rms_deg=NOISE, noise_deg=NOISE))
    d = diagnose(t, u, w, None, model, DiagnoseOptions(workers=1))
    lo = d.report["left_over"]
    assert lo is not None and lo["mostly"]
    assert lo["block_s"][0] <= tc <= lo["block_s"][1]
    assert "faster motion" in lo["beyond_training"]
    assert any("moves faster there" in n for n in d.report["notes"])
    assert any("moves faster there" in line for line in d.report["summary"])
    plot_diagnosis(tmp_path / "r.png", d)  # the figure marks that block and shows its window
    assert (tmp_path / "r.png").stat().st_size > 10_000
    # with the rig's servo in the model, the loops are drawn against the travel through it (not the field's effects)
    rig = replace(d.model.effects, servo_tau_s=0.05, servo_rate_mm_s=40.0, rate_mm_s=rate)
    plot_diagnosis(tmp_path / "servo.png", replace(d, model=replace(d.model, effects=rig)))
    for noise in (True, False):  # nothing named: the title says noise only when the residual tests say so
        plot_diagnosis(tmp_path / "none.png", replace(d, report=d.report | {"verdict": [], "residual_is_noise": noise}))
    figures = saved_figures[1:]  # after the first figure above
    assert figures[0].get_suptitle() == f"verdict: {', '.join(d.report['verdict'])}"
    assert figures[1].get_suptitle() == "verdict: none: the residual is noise"
    assert "noise" not in figures[2].get_suptitle()
    (loops,) = [ax for ax in figures[0].axes if ax.get_title().startswith("loops")]
    assert loops.get_xlabel().endswith("u through its servo")
    sc = d.split.score
    np.testing.assert_allclose(loops.lines[0].get_xdata(), servo_travel(t, u, 0.05, 40.0, float(u[0]))[sc])
