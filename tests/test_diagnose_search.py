"""The diagnosis's search over effects: where a round's joint refits start, which lead a pair enters under.

The fits here are given (a stand-in problem whose fit depends on where it starts), so what is tested is the
search's bookkeeping, not the fitting."""

from __future__ import annotations

import dataclasses
from concurrent.futures import Future
from types import SimpleNamespace

import numpy as np
import pytest

from warpbridge.model.diagnosis.blocks import make_split
from warpbridge.model.diagnosis.options import Decision, DiagnoseOptions
from warpbridge.model.diagnosis.problem import Fit
from warpbridge.model.diagnosis.report import rounds_along
from warpbridge.model.diagnosis.search import Explorer, Judged, hand_out_order
from warpbridge.model.diagnosis.selection import decide, enter_together
from warpbridge.model.effects import Effects

FS = 100.0
T = np.arange(3000) / FS
U = np.sin(2 * np.pi * 0.3 * T)
DRIFT = 0.4 * (1.0 - np.exp(-T / 8.0))  # a warming zero
LOAD = 0.3 * np.sin(2 * np.pi * 0.05 * T + 1.0)  # an aerodynamic moment following a slow airspeed
NOISE = 0.02 * np.random.default_rng(0).standard_normal(T.size)
W = DRIFT + LOAD + NOISE
SPLIT = make_split(T, U)
OWN_LOAD = Effects(aero_deg_per_kpa=1.0)  # the load's fit alone: its own size


class StandInProblem:
    """A problem whose fits are given by ``outcome(names, start)``; it records where each fit started."""

    def __init__(self, w: np.ndarray) -> None:
        self.w, self.split = w, SPLIT
        self.starts: list[tuple[tuple[str, ...], Effects]] = []

    def fit_jobs(self, names, start=None, free_nonlinear=None, max_evals=200, grid_for=None):
        names = tuple(names)
        start = start or Effects()
        self.starts.append((names, start))
        return [lambda: self.outcome(names, start)]

    @staticmethod
    def best_of(fits):
        return min(fits, key=lambda f: f.train_mse)


class SoakedProblem(StandInProblem):
    """Drift and aero load on a log where a drift fitted first bends to follow part of the load. A joint fit
    started from the drift's fit stays there (the load at a third of its size); one started from the load's
    own fit finds both. Backlash explains nothing."""

    def __init__(self) -> None:
        super().__init__(W)

    def outcome(self, names: tuple[str, ...], start: Effects) -> Fit:
        has_drift, has_load = "drift" in names, "aero_load" in names
        if has_drift and has_load and start.aero_deg_per_kpa == OWN_LOAD.aero_deg_per_kpa:
            pred, eff = DRIFT + LOAD, Effects(drift_deg_s=0.05, aero_deg_per_kpa=1.0)
        elif has_drift:  # bent to follow the load, alone or with a load held at a third
            pred = DRIFT + 0.5 * LOAD + (0.1 * LOAD if has_load else 0.0)
            eff = Effects(drift_deg_s=0.06, aero_deg_per_kpa=0.3 if has_load else 0.0)
        elif has_load:
            pred, eff = LOAD, OWN_LOAD
        else:
            pred, eff = np.zeros_like(W), Effects()
        r = W - pred
        return Fit(names, eff, pred, float(np.mean(r[SPLIT.train] ** 2)), float(np.mean(r[SPLIT.score] ** 2)),
                   len(names), params_of={n: 1 for n in names})


def explorer(prob, names=("drift", "aero_load", "backlash")) -> Explorer:
    nominal = prob.outcome((), Effects())
    return Explorer(prob, list(names), Effects(), nominal, 0.02 ** 2, DiagnoseOptions(), None)


def test_a_second_effect_the_first_soaked_up_is_refitted_from_its_own_fit():
    prob = SoakedProblem()
    ex = explorer(prob)
    first = {j.name: j for j in ex.round(())}
    assert max(first.values(), key=lambda j: j.gain.gain).name == "drift"
    second = {j.name: j for j in ex.round(("drift",))}
    load = second["aero_load"]
    assert load.fit.effects.aero_deg_per_kpa == 1.0  # the pair from the load's own fit, not the stuck one
    assert load.fit.score_mse < 1.5 * np.mean(NOISE[SPLIT.score] ** 2)
    assert (("drift", "aero_load"), OWN_LOAD) in prob.starts  # the reverse refit was asked for
    # a round after two chosen effects refits only from where the chosen ones are
    prob.starts.clear()
    ex.round(("drift", "aero_load"))
    assert all(start.drift_deg_s > 0 for _, start in prob.starts)


PRE = 0.5 * U  # a pre-tension's gain on the warp
PLAY = 0.3 * np.sign(np.cos(2 * np.pi * 0.3 * T))  # a play's step at each reversal
W_PAIR = PRE + PLAY + NOISE
OWN = {"pretension": Effects(pretension_gain=1.5), "backlash": Effects(backlash_mm=0.3),
       "friction": Effects(friction_scale=1.5), "drift": Effects(drift_deg_s=0.01), "sensor_lag": Effects()}


class HiddenPlayProblem(StandInProblem):
    """Pre-tension and play. The pre-tension fitted first takes two fifths of the play's step with it; beside
    it, held at its fit, the play fits at zero, so the screen ranks it below a friction and a drift that each
    take a little more of the step. Started from the play's own fit (which alone closes most of the gap), the
    joint fit finds both. A sensor lag explains nothing alone or beside."""

    share = {"friction": 0.3, "drift": 0.1, "backlash": 0.0, "sensor_lag": 0.0}

    def __init__(self) -> None:
        super().__init__(W_PAIR)

    def outcome(self, names: tuple[str, ...], start: Effects) -> Fit:
        eff = Effects()
        for n in names:
            eff = dataclasses.replace(eff, **{k: v for k, v in vars(OWN[n]).items() if v != getattr(Effects(), k)})
        if names == ("pretension", "backlash") and start.backlash_mm == OWN["backlash"].backlash_mm:
            pred = PRE + PLAY
        elif names[:1] == ("pretension",):
            new = names[1] if len(names) > 1 else ""
            pred = PRE + (0.4 + self.share.get(new, 0.0)) * PLAY
            if new == "backlash":
                eff = dataclasses.replace(eff, backlash_mm=0.0)  # the play fitted at nothing
        elif names == ("backlash",):
            pred = PLAY + 0.3 * PRE
        elif names == ("friction",):
            pred = 0.5 * PLAY
        elif names == ("drift",):
            pred = 0.1 * PLAY
        else:
            pred = np.zeros_like(W_PAIR)
        r = W_PAIR - pred
        return Fit(names, eff, pred, float(np.mean(r[SPLIT.train] ** 2)), float(np.mean(r[SPLIT.score] ** 2)),
                   len(names), params_of={n: 1 for n in names})


def test_a_candidate_the_screen_ranks_low_is_refitted_from_its_own_fit_when_it_alone_closed_a_share():
    prob = HiddenPlayProblem()
    ex = explorer(prob, names=("pretension", "backlash", "friction", "drift", "sensor_lag"))
    first = {j.name: j for j in ex.round(())}
    assert max(first.values(), key=lambda j: j.gain.gain).name == "pretension"
    second = {j.name: j for j in ex.round(("pretension",))}
    screens = sorted(("backlash", "friction", "drift"), key=lambda c: second[c].fit.train_mse)
    assert second["backlash"].fit.effects.backlash_mm == OWN["backlash"].backlash_mm  # the pair, found
    assert second["backlash"].fit.score_mse < 1.5 * np.mean(NOISE[SPLIT.score] ** 2)
    assert screens[0] == "backlash"
    reverse = {names[-1] for names, start in prob.starts
               if names[:1] == ("pretension",) and len(names) == 2 and start == OWN[names[-1]]}
    assert "backlash" in reverse  # ranked third by its screen, below the two joint refits
    assert "sensor_lag" not in reverse  # closed nothing alone: no refit of its own


def fake_fit(names: tuple[str, ...], passes: bool) -> SimpleNamespace:
    return SimpleNamespace(names=names, passes=passes)


class PairExplorer:
    """Round 1 judged, each lead's second round given; an effect passes the test when its fit says so."""

    def __init__(self, seconds: dict[str, list[Judged]]) -> None:
        self.nominal = fake_fit((), False)
        self.opt = DiagnoseOptions()
        self.seconds = seconds
        self.leads: list[str] = []

    def round(self, selected):
        self.leads.append(selected[0])
        return self.seconds.get(selected[0], [])

    def admits(self, d, old, new, g=None):
        return new.passes

    def without(self, pair, drop, cur):
        return fake_fit(tuple(n for n in pair if n != drop), False)

    def gain(self, old, new):
        return SimpleNamespace(gain=1.0, p_value=0.0)


def judged(name: str, gain: float, passes: bool = False, names: tuple[str, ...] = ()) -> Judged:
    return Judged(name, fake_fit(names or (name,), passes), SimpleNamespace(gain=gain, p_value=0.05), gain,
                  penalised=gain)


def test_two_effects_that_hide_each_other_enter_under_a_near_runner_up_lead():
    """Nothing passes alone; friction leads by a hair and no second effect passes beside it, while the
    pre-tension, nearly as large, has a load that does: the pair enters led by the pre-tension."""
    ex = PairExplorer({"friction": [judged("drift", 0.3, passes=False, names=("friction", "drift"))],
                       "pretension": [judged("aero_load", 0.3, passes=True, names=("pretension", "aero_load"))]})
    out = enter_together(ex, None, [judged("friction", 0.45), judged("pretension", 0.43), judged("delay", 0.1)])
    assert out is not None
    lead, second, _ = out
    assert (lead.name, second.name) == ("pretension", "aero_load")
    assert ex.leads == ["friction", "pretension"]


def test_the_leads_are_ranked_by_held_out_gain_not_by_the_penalised_one():
    """With nothing significant alone, the parameter penalty says little about which hidden effect a
    candidate is: the drift, third by the penalised gain but first by the held-out gain, leads first."""
    ex = PairExplorer({"drift": [judged("pretension", 0.3, passes=True, names=("drift", "pretension"))]})
    first = judged("aero_load", 0.2)
    first.penalised = 0.5
    second = judged("delay", 0.15)
    second.penalised = 0.4
    third = judged("drift", 0.35)
    third.penalised = 0.1
    out = enter_together(ex, None, [first, second, third])
    assert out is not None
    assert (out[0].name, out[1].name) == ("drift", "pretension")
    assert ex.leads == ["drift"]


def test_no_more_than_three_candidates_lead():
    """The fourth candidate by held-out gain does not lead, though its pair would pass."""
    ex = PairExplorer({"delay": [judged("aero_load", 0.3, passes=True, names=("delay", "aero_load"))]})
    cands = [judged("friction", 0.45), judged("pretension", 0.4), judged("drift", 0.3), judged("delay", 0.2)]
    assert enter_together(ex, None, cands) is None
    assert ex.leads == ["friction", "pretension", "drift"]


def test_a_candidate_that_explains_nothing_does_not_lead():
    """A candidate whose held-out gain is not positive never leads, though its pair would pass."""
    ex = PairExplorer({"backlash": [judged("aero_load", 0.3, passes=True, names=("backlash", "aero_load"))]})
    assert enter_together(ex, None, [judged("friction", 0.45), judged("backlash", 0.0)]) is None
    assert ex.leads == ["friction"]


class ImitatorProblem(SoakedProblem):
    """A drift and a sensor lag, and a slew limit that imitates most of both at once but nothing of either once
    it is fitted: it wins round 1, and only the runner-up (the drift) leads to the pair."""

    def __init__(self) -> None:
        super().__init__()
        self.w = W_IMITATED

    def fit(self, names, start=None, free_nonlinear=None, max_evals=200, grid_for=None, run=None):
        return self.outcome(tuple(names), start or Effects())

    def outcome(self, names: tuple[str, ...], start: Effects) -> Fit:
        drift, lag = "drift" in names, "sensor_lag" in names
        if drift and lag:
            pred = DRIFT_BIG + LOAD
        elif "rate_limit" in names:
            pred = 0.8 * (DRIFT_BIG + LOAD)
        else:
            pred = DRIFT_BIG * drift + LOAD * lag
        r = W_IMITATED - pred
        return Fit(names, Effects(drift_deg_s=0.1 * drift, sensor_tau_s=0.05 * lag), pred,
                   float(np.mean(r[SPLIT.train] ** 2)), float(np.mean(r[SPLIT.score] ** 2)), len(names),
                   params_of={n: 1 for n in names})


DRIFT_BIG = 0.5 * np.sin(2 * np.pi * 0.04 * T)
W_IMITATED = DRIFT_BIG + LOAD + NOISE


def test_a_runner_up_taken_for_its_pair_keeps_its_confidence():
    """Round 2 goes on from the runner-up: the report's confidence in it is its own test's, not lowered
    because the winner of round 1 explained more alone."""
    ex = explorer(ImitatorProblem(), ("rate_limit", "drift", "sensor_lag"))
    d = Decision()
    path = decide(ex, d, max_effects=3)
    assert sorted(path.named) == ["drift", "sensor_lag"]
    assert path.from_runner_up and any("runner-up drift" in n for n in path.notes)
    first = {j.name: j for j in ex.round(())}
    assert first["rate_limit"].gain.gain > first["drift"].gain.gain
    _, _, confidence = rounds_along(ex, path, DiagnoseOptions(decision=d))
    assert confidence["drift"] > 0.9 and confidence["sensor_lag"] > 0.9


def test_the_beams_second_rounds_fitted_together_judge_as_one_at_a_time():
    """``Explorer.rounds`` hands both second rounds' fits out in one stage (and their joint refits in a second),
    and judges each as ``round`` alone does."""
    stages: list[str] = []
    together = explorer(SoakedProblem())
    together.progress = lambda label, i, n: stages.append(label) if i == 0 else None
    pair = together.rounds([("drift",), ("aero_load",)])
    alone = explorer(SoakedProblem())
    for sel, judged_together in zip((("drift",), ("aero_load",)), pair, strict=True):
        judged_alone = alone.round(sel)
        assert [j.name for j in judged_together] == [j.name for j in judged_alone]
        for a, b in zip(judged_together, judged_alone, strict=True):
            assert a.fit.effects == b.fit.effects and a.fit.score_mse == b.fit.score_mse
            assert a.gain.gain == b.gain.gain and a.penalised == b.penalised
    # each round's own outcome on the stand-in: beside the drift, the load from its own fit (the pair); beside
    # the load, the drift fitted from the load's own size (the pair again)
    after_drift, after_load = ({j.name: j for j in judged} for judged in pair)
    assert after_drift["aero_load"].fit.effects.aero_deg_per_kpa == OWN_LOAD.aero_deg_per_kpa
    assert after_load["drift"].fit.effects == Effects(drift_deg_s=0.05, aero_deg_per_kpa=1.0)
    assert stages[1:] == ["round 2 (after drift); round 2 (after aero_load)",
                          "round 2 (after drift), joint refits; round 2 (after aero_load), joint refits"]
    assert together.rounds([("drift",)])[0] is pair[0]  # each round fitted once


class ImmediatePool:
    """A worker pool that runs each job as it is handed out, and records the order."""

    def __init__(self) -> None:
        self.handed: list[int] = []

    def submit(self, job) -> Future:
        self.handed.append(job.index)
        f: Future = Future()
        f.set_result(job())
        return f

    @staticmethod
    def result(future: Future, job):
        return future.result()


class Job:
    def __init__(self, index: int, runs: int | None) -> None:
        self.index = index
        if runs is not None:
            self.expected_runs = runs

    def __call__(self) -> int:
        return self.index


def test_the_longest_jobs_are_handed_out_first_and_the_results_come_back_as_asked():
    jobs = [Job(0, 30), Job(1, 120), Job(2, None), Job(3, 1), Job(4, 120)]
    assert hand_out_order(jobs) == [1, 4, 0, 3, 2]  # ties in the order asked; a job of unknown cost last
    ex = explorer(SoakedProblem())
    ex.pool = ImmediatePool()
    assert ex.run(jobs, "stage") == [0, 1, 2, 3, 4]
    assert ex.pool.handed == [1, 4, 0, 3, 2]


def test_the_report_judges_rounds_on_its_floor_without_changing_the_explored_ones():
    """A raised floor is a view of the search (``Explorer.at_floor``), and the report's rounds are copies: the
    explored rounds, and the explorer the caller holds, are as they were."""
    ex = explorer(ImitatorProblem(), ("rate_limit", "drift", "sensor_lag"))
    d = Decision()
    path = decide(ex, d, max_effects=3)
    explored = {pre: [(j.confidence, j.share, j.ambiguous_with_best) for j in js] for pre, js in ex.rounds_done.items()}
    raised = ex.at_floor(4.0 * ex.floor2)
    assert raised.floor2 == 4.0 * ex.floor2 and ex.floor2 == 0.02 ** 2
    assert raised.rounds_done is ex.rounds_done and raised.fits is ex.fits  # the search is shared, not redone
    rounds, _, _ = rounds_along(raised, path, DiagnoseOptions(decision=d))
    assert {pre: [(j.confidence, j.share, j.ambiguous_with_best) for j in js]
            for pre, js in ex.rounds_done.items()} == explored
    first = {j.name: j for j in rounds[0]}
    for j in ex.rounds_done[()]:  # each share is of the gap above the floor the report judges on
        assert first[j.name] is not j and first[j.name].share == pytest.approx(raised.share(ex.nominal, j.gain.gain))
