"""Diagnosis of the gap between a model and a log: where it is, which effect explains it, how far.

0. **Start.** The hysteretic state at the log's first sample is estimated
   from its opening stretch (``model.initial_state``, with the model's effects
   and error correction), not assumed at rest; so is, for every candidate with
   a play (backlash, capstan stall), the edge its slack starts on (a log may
   open just after a release: ``diag_fit.Problem.input_path``). When MODEL.json carries a
   model-error model (``model.model_error``: what the nominal model got wrong
   on the bench, as a function of warp level, direction, travel since the
   last reversal and rate), its correction is part of the nominal prediction,
   and what it still gets wrong on the bench is the model's known error.
1. **Where.** The corrected model (with the effects it already carries) is
   free-run on the logged tendon input; the residual is split by hysteresis
   phase, warp level, frequency band, time and airspeed
   (``model.diag_where``) against the floor it should reach: the noise
   estimated from the log's second differences plus the model's known error,
   so a model that never fitted perfectly is not blamed on a new effect.
2. **Which.** Every effect of the vocabulary is fitted as an augmentation
   (``model.diag_fit``) on alternating training blocks of the log and scored
   on the blocks in between (the two blocks where the command moves fastest
   fall one on each side: a slew limit or a delay that shows only there is
   both fitted and tested). Greedy forward selection: a round fits every
   remaining effect jointly with those already chosen and takes the best by a
   penalised held-out criterion (effective samples x log MSE + 2 per extra
   parameter) among those one test admits (``Decision``): a held-out gain
   significant in a forecast-encompassing test (``diag_stats.paired_gain``,
   Bonferroni over the effects tried), material against the floor, and closing
   a share of the gap the round starts from. The same test admits the first
   effect, every later one, and keeps each in a backward pass (refit without
   it); a final joint refit polishes the chosen parameters. When no effect
   passes alone, two that hide each other (each leaves the other's slow,
   structured error, which weakens its evidence) may enter together: the pair
   passes the test against the nominal and each passes it once the other is
   fitted (``enter_together``). Candidates whose
   held-out error is statistically indistinguishable from the chosen one are
   reported as ambiguous, with the excitation that would separate them; a
   parameter fitted at a bound of its search is reported and halves the
   effect's confidence. A delay that shortened beside a friction that weakened,
   by no more than the friction's share of the bench's delay, is the friction's
   rate-dependent part (a lubricated sheath's viscous drag, ``viscous_lag``):
   kept in the model, not named. So is a friction chosen after a pre-tension
   whose band moved with the rig's compliance, and by at least as much: a
   sheath's band follows the tension it carries (``tension_band``). A capstan
   stall that less than doubles across the log's travel and that the held-out
   test cannot tell from a fixed play is named as that play, backlash, its
   limit (``stall_as_play``).
3. **How far.** Held-out RMS before and after, and the share of the gap closed
   ``(MSE_nominal - MSE_augmented) / (MSE_nominal - noise^2)``, overall and in
   every cell of step 1.
4. **How large.** Once the scored blocks have chosen the effects, their sizes
   are fitted again on every analysed sample, from where the training fit
   ended (``diag_fit.Problem.refit_whole``): the report's effects and the
   augmented model carry these, as a model chosen by cross-validation is
   refitted on all of its data; the held-out figures of step 3 stay those of
   the training fit (``effects_on_training_blocks``).

No I/O: ``diagnose`` returns a ``Diagnosis`` with the report (a JSON-ready
dict), the augmented ``ModelFile`` and the residual series for plotting;
progress goes to an optional callback.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Hashable
from concurrent.futures import as_completed
from contextlib import contextmanager
from dataclasses import dataclass, field, replace

import numpy as np

from warpbridge.model.diag_fit import Fit, Problem, Split, effect_of
from warpbridge.model.diag_left import left_over, left_over_note
from warpbridge.model.diag_pool import FitPool
from warpbridge.model.diag_stats import (
    PairedGain,
    effective_n,
    input_independence,
    ljung_box,
    paired_gain,
    prewhiten,
)
from warpbridge.model.diag_transfer import Transfer, raised_floor, transfer
from warpbridge.model.diag_where import Cells, cells, gap_closed, split
from warpbridge.model.effects import (
    CAPSTAN_FIELDS,
    EFFECT_FIELDS,
    EFFECT_NAMES,
    Effects,
    slack_side_name,
)
from warpbridge.model.initial_state import estimate_plant_start, reachable_band
from warpbridge.model.input_check import known_error_on_check
from warpbridge.model.model_error import ErrorModel
from warpbridge.model.modelfile import FitQuality, ModelFile
from warpbridge.model.plant import Plant
from warpbridge.model.signals import noise_floor

log = logging.getLogger(__name__)

REPORT_FORMAT = "warpbridge-diagnosis/1"

# what separates effects that explain a log about equally well
SEPARATE: dict[frozenset, str] = {
    frozenset({"delay", "sensor_lag"}): "steps or a sharp doublet: a delay shifts the whole response, a sensor lag "
                                        "rounds its onset; a sweep to several Hz shows the delay's phase growing "
                                        "linearly with frequency while the lag's amplitude rolls off",
    frozenset({"delay", "rate_limit"}): "the same excitation at two speeds or amplitudes: a slew limit only bites "
                                        "when the tendon moves fast, a delay acts at every speed",
    frozenset({"sensor_lag", "rate_limit"}): "the same excitation at two speeds or amplitudes: a slew limit only "
                                             "bites on fast tendon motion, a sensor lag at every speed",
    frozenset({"friction", "backlash"}): "minor loops of several sizes at several mean tendon positions: backlash is "
                                         "a fixed dead band at every reversal, friction scales the loop width with "
                                         "the excursion or grows the dead band with the tension",
    frozenset({"friction", "pretension"}): "several amplitudes around several mean tendon positions: pre-tension "
                                           "moves the curve and changes its slope, friction only widens the loop",
    frozenset({"backlash", "pretension"}): "small reversals at several positions: backlash acts at every "
                                           "reversal, a pre-tension change shifts the curve everywhere",
    frozenset({"pretension", "aero_load"}): "runs at two or more distinct airspeeds (or one at rest): an aero load "
                                            "grows with dynamic pressure, pre-tension does not",
    frozenset({"pretension", "drift"}): "return to the same tendon position at intervals over a long log: drift "
                                        "grows with time, a pre-tension offset does not",
    frozenset({"drift", "aero_load"}): "vary the airspeed up and down over the log rather than in one direction: "
                                       "drift follows time, aero load follows dynamic pressure",
    frozenset({"backlash", "delay"}): "reversals at several speeds: backlash is rate independent, a delay grows "
                                      "with speed",
    frozenset({"backlash", "sensor_lag"}): "reversals at several speeds: backlash is rate independent, a sensor lag "
                                           "grows with speed",
}
DEFAULT_SEPARATE = ("a richer excitation: a random input with sharper reversals at several amplitudes and speeds, "
                    "holds, and (for airspeed effects) a varying airspeed")


@dataclass(frozen=True)
class Decision:
    """When held-out evidence names an effect; one test admits the first effect, every later one, and
    keeps each in the backward pass.

    A step from model 0 to model 1 (one more effect) is admitted when, on the scored blocks, model 1's
    gain in MSE is significant at ``alpha`` (Bonferroni over the effects tried), at least ``min_gain`` x
    the floor (noise^2 plus the model's known error^2) and at least ``min_share`` of the gap model 0
    leaves above that floor, and at least ``min_total`` of the gap the nominal model leaves (the same test
    for the first effect, where model 0 is the nominal, and every later one: an effect that only mops up
    what the first left over, a form the operators do not quite have, is not named). With ``parsimony``,
    of the admitted candidates the held-out test cannot tell apart the one with the fewest parameters is
    named. The benchmark chooses these on plant families other
    than the one it scores (leave-one-family-out) and prints each fold's choice; the defaults are the
    decision four of its five folds chose when they were set (docs/results.md gives the latest run's choices;
    none has chosen parsimony or ``min_total``)."""

    alpha: float = 0.05
    min_share: float = 0.1
    min_gain: float = 0.5
    parsimony: bool = False  # of admitted candidates the held-out test cannot tell apart, name the fewest parameters
    min_total: float = 0.0  # share of the nominal's gap each effect must close

    def to_dict(self) -> dict:
        d = {"alpha": self.alpha, "min_share": self.min_share, "min_gain": self.min_gain}
        if self.parsimony:  # absent: False (the decisions before this switch keep their keys)
            d["parsimony"] = True
        if self.min_total:  # absent: 0 (likewise)
            d["min_total"] = self.min_total
        return d

    @classmethod
    def from_dict(cls, d: dict) -> Decision:
        kw: dict = {k: float(d[k]) for k in ("alpha", "min_share", "min_gain", "min_total") if k in d}
        return cls(**kw, parsimony=bool(d.get("parsimony", False)))


# a capstan stall growing less than this across the log's travel is taken for a fixed play when the held-out
# test cannot tell them apart (``stall_as_play``): its zero more than the travel's span below the travel
STALL_AS_PLAY_GROWTH = 2.0

# the first round's candidates (largest held-out gain first) that each lead a pair entering together
# (``enter_together``)
TOGETHER_LEADS = 3

# a small grid around the default, for ``alternatives`` (how the verdict depends on the decision)
DECISION_GRID: tuple[Decision, ...] = tuple(
    Decision(a, s, g, p, m) for m in (0.0, 0.03) for p in (False, True) for a in (0.001, 0.01, 0.05)
    for s in (0.1, 0.25, 0.5) for g in (0.25, 0.5, 1.0, 2.0))


@dataclass
class DiagnoseOptions:
    """Search and decision settings; the defaults are statistical conventions checked leave-one-family-out."""

    max_effects: int = 3
    decision: Decision = field(default_factory=Decision)
    alternatives: tuple[Decision, ...] = ()  # also report the verdict each of these decisions gives
    ambiguity_alpha: float = 0.05  # a runner-up not worse than the winner at this level is an equal explanation
    max_evals: int = 120  # Nelder-Mead evaluations per joint fit
    joint_refits: int = 2  # candidates per round refitted jointly with the effects already chosen
    effects: tuple[str, ...] = EFFECT_NAMES  # the candidates
    use_model_error: bool = True  # apply the model-error model MODEL.json carries, if any
    workers: int = 1  # processes fitting a round's candidates side by side (the verdict does not depend on it)


@dataclass
class Judged:
    """One candidate in one round: its fit and how it compares with the model the round starts from."""

    name: str
    fit: Fit
    gain: PairedGain
    share: float  # of the gap above the floor that the round's starting model leaves
    penalised: float
    confidence: float = 0.0
    ambiguous_with_best: bool = False


@dataclass
class Diagnosis:
    """What ``diagnose`` found: the report dict, the augmented model and series for plots."""

    verdict: list[str]
    report: dict
    model: ModelFile
    t: np.ndarray = field(repr=False)
    u: np.ndarray = field(repr=False)
    w: np.ndarray = field(repr=False)
    w_nominal: np.ndarray = field(repr=False)
    w_augmented: np.ndarray = field(repr=False)
    split: Split = field(repr=False)
    cells: Cells = field(repr=False)


def model_error(fit: FitQuality, noise: float) -> float:
    """The model's own error beyond noise that identification measured (0 if it did not say)."""
    held = fit.heldout_rms_deg
    nz = fit.noise_deg if math.isfinite(fit.noise_deg) else noise
    if not math.isfinite(held) or not math.isfinite(nz):
        return 0.0
    return math.sqrt(max(held ** 2 - nz ** 2, 0.0))


def known_error(model: ModelFile, noise: float, use_model_error: bool) -> float:
    """What the nominal model (with its model-error correction, if used) is known to get wrong beyond noise:
    on its bench log, or on the check log of another input ``identify --check`` scored it on, if larger."""
    bench = bench_known_error(model, noise, use_model_error)
    check = known_error_on_check(model.fit.extra, use_model_error and model.model_error is not None)
    return max(bench, check) if math.isfinite(check) else bench


def bench_known_error(model: ModelFile, noise: float, use_model_error: bool) -> float:
    """The known error measured on the bench log alone (the model-error model's, or identify's held-out)."""
    em = model.model_error if use_model_error else None
    if em is not None and math.isfinite(em.known_error_deg):
        return em.known_error_deg
    return model_error(model.fit, noise)


LATENCY_FIELDS = {"delay": "delay_s", "sensor_lag": "sensor_tau_s"}  # effects that each add latency


def shared_latency_start(eff: Effects, selected: tuple[str, ...], name: str, base: Effects) -> Effects:
    """Where a joint fit of latency effect ``name`` with a chosen one starts: the chosen one's latency beyond
    the nominal's shared half and half between the two.

    A delay and a sensor lag each stand in for both (over a slow input a lag is about a delay): once one is
    chosen it carries the latency of both, and the other, screened with it held, comes back at nothing, a
    point the joint fit cannot leave (neither moves alone without a loss). From the half-and-half split the
    fit can go either way: to one of them (the other back to nothing) or to both."""
    if name not in LATENCY_FIELDS:
        return eff
    chosen = next((s for s in selected if s in LATENCY_FIELDS and s != name), None)
    if chosen is None:
        return eff
    fc, fn = LATENCY_FIELDS[chosen], LATENCY_FIELDS[name]
    excess = getattr(eff, fc) - getattr(base, fc)
    if not excess > 0:
        return eff
    return replace(eff, **{fc: getattr(base, fc) + 0.5 * excess, fn: getattr(base, fn) + 0.5 * excess})


def _neutral(eff: Effects, name: str, base: Effects) -> Effects:
    """``eff`` with effect ``name`` back at the nominal model's own value."""
    return replace(eff, **{f: getattr(base, f) for f in EFFECT_FIELDS[name][0]})


def initial_state(t, u, w, airspeed, model: ModelFile, em: ErrorModel | None) -> tuple[float, float]:
    """(z0, the play's slack side) that explain the log's first samples with the model, its effects and its
    error correction (``initial_state.estimate_plant_start``)."""
    return estimate_plant_start(Plant(model.params, model.effects, em), t, u, w, airspeed)


ALONE_SHARE = 0.1  # a candidate that alone closes this share of the training gap is refitted from its own fit


def hand_out_order(jobs: list) -> list[int]:
    """The order the pool gets ``jobs`` in (its queue is first in, first out): the longest first by their
    ``expected_runs``, since a stage ends when its last job does, and a long job started last leaves the other
    workers idle until then. The fits, and the report, do not depend on it."""
    return sorted(range(len(jobs)), key=lambda i: -getattr(jobs[i], "expected_runs", 0))


class Explorer:
    """The candidate fits of every round the decisions ask for, each computed once."""

    def __init__(self, prob: Problem, names: list[str], base: Effects, nominal: Fit, floor2: float,
                 opt: DiagnoseOptions, progress) -> None:
        self.prob, self.names, self.base, self.opt, self.progress = prob, names, base, opt, progress
        self.w = prob.w
        self.floor2 = floor2
        self.nominal = nominal
        self.rounds_done: dict[tuple[str, ...], list[Judged]] = {}
        self.fits: dict[tuple, Fit] = {(): nominal}
        self.neff_cache: dict[tuple[str, ...], float] = {}
        self.pool: FitPool | None = None  # set by ``workers`` for opt.workers > 1
        self.speculative: dict[tuple, tuple[Fit, Fit]] = {}  # ``prefetch_without``'s (cur, fit) by ``without``'s key

    @contextmanager
    def workers(self):
        """Fit on ``opt.workers`` worker processes inside this block (``diag_pool``; threads where processes
        cannot be forked)."""
        if self.opt.workers <= 1:
            yield self
            return
        with FitPool(self.prob, self.opt.workers) as pool:
            self.pool = pool
            try:
                yield self
            finally:
                self.pool = None

    def gain(self, old: Fit, new: Fit) -> PairedGain:
        return paired_gain(self.w - old.w_pred, self.w - new.w_pred, self.prob.split.chunks)

    def share(self, old: Fit, gain: float) -> float:
        gap = old.score_mse - self.floor2
        return gain / gap if gap > 0 and math.isfinite(gain) else 0.0

    def admits(self, d: Decision, old: Fit, new: Fit, g: PairedGain | None = None) -> bool:
        """The one test: significant, material, a share of the remaining gap and of the nominal's."""
        g = g or self.gain(old, new)
        level = d.alpha / max(len(self.names), 1)
        return (g.p_value < level and g.gain >= d.min_gain * self.floor2
                and self.share(old, g.gain) >= d.min_share
                and (d.min_total <= 0.0 or self.share(self.nominal, g.gain) >= d.min_total))

    def ties(self, g: PairedGain, d: Decision) -> bool:
        """True when the held-out gain ``g`` of one candidate over another is not significant at the ambiguity
        level, or not material under ``d``: the two are equal explanations."""
        return g.p_value > self.opt.ambiguity_alpha or g.gain < d.min_gain * self.floor2

    def fit_of(self, selected: tuple[str, ...]) -> Fit:
        if selected not in self.fits:
            self.round(selected[:-1])
        return self.fits[selected]

    def round(self, selected: tuple[str, ...]) -> list[Judged]:
        """Every remaining effect fitted jointly with ``selected`` and judged against ``selected``'s fit."""
        return self.rounds([selected])[0]

    def rounds(self, selections: list[tuple[str, ...]]) -> list[list[Judged]]:
        """``round`` of each selection, their fits handed out together (the beam's two second rounds: one
        stage's tail keeps fewer workers idle than two)."""
        todo = list(dict.fromkeys(s for s in selections if s not in self.rounds_done))
        for s in todo:
            self.fit_of(s)
        labels = [self._label(s) for s in todo]
        # screen with the chosen effects held (their linear parameters still move), then refit the most
        # promising jointly: effects interact, and a chosen one may have soaked up part of the new one
        screens = self.each("; ".join(labels), {(s, c): self._screen_job(s, c) for s in todo
                                                for c in self._remaining(s)})
        fits = {s: {c: screens[(s, c)] for c in self._remaining(s)} for s in todo}
        refits = {s: self._refit_jobs(s, fits[s]) for s in todo if s}
        joint = self.each("; ".join(f"{lb}, joint refits" for s, lb in zip(todo, labels, strict=True) if s),
                          {(s, k): job for s, jobs in refits.items() for k, job in jobs.items()})
        for s in refits:
            for c in fits[s]:
                for k in (c, (c, "reverse")):  # the refit from the chosen effects' fit, then the reverse one
                    f = joint.get((s, k))
                    if f is not None and f.train_mse <= fits[s][c].train_mse:
                        fits[s][c] = f
        for s in todo:
            self.rounds_done[s] = self._judge(s, fits[s])
        return [self.rounds_done[s] for s in selections]

    @staticmethod
    def _label(selected: tuple[str, ...]) -> str:
        return "round 1" if not selected else f"round {len(selected) + 1} (after {' + '.join(selected)})"

    def _remaining(self, selected: tuple[str, ...]) -> list[str]:
        return [n for n in self.names if n not in selected]

    def _screen_job(self, selected: tuple[str, ...], c: str) -> dict:
        """``c`` fitted beside ``selected`` held at its fit, from the grid of ``c``'s own parameters."""
        return dict(names=selected + (c,), start=self.fits[selected].effects, grid_for=c, free_nonlinear=(c,),
                    max_evals=self.opt.max_evals)

    def _refit_jobs(self, selected: tuple[str, ...], fits: dict[str, Fit]) -> dict[Hashable, dict]:
        """The joint refits of a round's most promising screens (by the training fit), keyed by candidate, and
        by (candidate, "reverse") for those started from the candidate's own fit."""
        starts = {c: shared_latency_start(fits[c].effects, selected, c, self.base) for c in fits}
        top = sorted(fits, key=lambda k: fits[k].train_mse)[:self.opt.joint_refits]
        # a latency effect beside a chosen one is refitted from the shared split even when its screen
        # (at nothing, the chosen one carrying both) ranks it low
        top += [c for c in fits if c not in top and starts[c] is not fits[c].effects]
        jobs: dict[Hashable, dict] = {c: dict(names=selected + (c,), start=starts[c], grid_for="",
                                              max_evals=self.opt.max_evals) for c in top}
        if len(selected) == 1:
            # and from the other side: the new effect as it fitted alone, the chosen one searched afresh on
            # its grid. Started from the chosen one's fit, the joint search can stay where that one has
            # soaked up the new one's part (a backlash wide enough for a friction band too, a drift bent to
            # follow a load), which the new one alone does not. Also for every candidate that alone closed a
            # tenth of the nominal's gap on the training blocks: held at the chosen one's fit, a screen can
            # rank such a one low (a play beside a pre-tension fitted with no play), from its own fit not
            gap = self.nominal.train_mse - self.floor2
            alone = [c for c in fits if (c,) in self.fits and gap > 0
                     and self.nominal.train_mse - self.fits[(c,)].train_mse >= ALONE_SHARE * gap]
            reverse = list(dict.fromkeys(top + alone))
            jobs |= {(c, "reverse"): dict(names=selected + (c,), start=self.fits[(c,)].effects,
                                          grid_for=selected[0], free_nonlinear=selected,
                                          max_evals=self.opt.max_evals) for c in reverse}
        return jobs

    def _judge(self, selected: tuple[str, ...], fits: dict[str, Fit]) -> list[Judged]:
        """Each candidate's fit judged against ``selected``'s (held-out gain, share, penalised likelihood)."""
        cur, prob = self.fits[selected], self.prob
        best_mse = min((f.score_mse for f in fits.values()), default=math.inf)
        best_fit = next((f for f in fits.values() if f.score_mse == best_mse), cur)
        neff = effective_n((self.w - best_fit.w_pred)[prob.split.score])
        judged = []
        for c in self._remaining(selected):
            f = fits[c]
            g = self.gain(cur, f)
            ok = f.score_mse > 0 and cur.score_mse > 0 and math.isfinite(f.score_mse)
            pen = neff * math.log(cur.score_mse / f.score_mse) - 2 * f.params_of[c] if ok else -math.inf
            judged.append(Judged(c, f, g, self.share(cur, g.gain), pen))
            self.fits[selected + (c,)] = f
        return judged

    def each(self, label: str, jobs: dict[Hashable, dict]) -> dict[Hashable, Fit]:
        """``prob.fit(**kwargs)`` for every job, each form of each on one of ``opt.workers`` workers (the fits
        are independent: the results are those of one after the other)."""
        plans = {c: self.prob.fit_jobs(**kw) for c, kw in jobs.items()}
        flat = [job for plan in plans.values() for job in plan]
        results = iter(self.run(flat, label))
        return {c: self.prob.best_of([next(results) for _ in plan]) for c, plan in plans.items()}

    def run(self, jobs: list[Callable[[], Fit]], label: str = "") -> list[Fit]:
        """The results of argument-free jobs, in order: on the worker pool when there is one."""
        n = len(jobs)
        tell = self.progress if self.progress and label else (lambda *_: None)
        tell(label, 0, n)
        if self.pool is None or n <= 1:
            out = []
            for job in jobs:
                out.append(job())
                tell(label, len(out), n)
            return out
        futs = {i: self.pool.submit(jobs[i]) for i in hand_out_order(jobs)}
        for i, _ in enumerate(as_completed(futs.values())):
            tell(label, i + 1, n)
        return [self.pool.result(futs[i], job) for i, job in enumerate(jobs)]

    def without(self, selected: tuple[str, ...], drop: str, cur: Fit) -> Fit:
        key = ("without", selected, drop)
        if key not in self.fits:
            if self.progress:
                self.progress("backward check", 0, 1)
            kept, fit = self.speculative.pop(key, (None, None))
            self.fits[key] = fit if kept is cur else self.prob.fit(**self._without_job(selected, drop, cur),
                                                                   run=self.run)
        return self.fits[key]

    def _without_job(self, selected: tuple[str, ...], drop: str, cur: Fit) -> dict:
        """``prob.fit``'s arguments for ``selected`` less ``drop``, started from ``cur`` with ``drop`` neutral."""
        return dict(names=tuple(x for x in selected if x != drop), start=_neutral(cur.effects, drop, self.base),
                    grid_for="", max_evals=self.opt.max_evals)

    def prefetch_without(self, selected: tuple[str, ...], cur: Fit) -> None:
        """Fit ``without(selected, s, cur)`` for every s side by side (on the worker pool), kept aside until
        asked for with the same ``cur``: the backward pass asks for them one at a time and may stop early."""
        if self.pool is None:
            return
        todo = [s for s in selected if ("without", selected, s) not in self.fits
                and self.speculative.get(("without", selected, s), (None,))[0] is not cur]
        fits = self.each("backward check" if todo else "",
                         {s: self._without_job(selected, s, cur) for s in todo})
        for s, f in fits.items():
            self.speculative[("without", selected, s)] = (cur, f)

    def final(self, selected: tuple[str, ...], cur: Fit) -> Fit:
        key = ("final", selected)
        if key not in self.fits:
            if self.progress:
                self.progress("joint refit", 0, 1)
            f = self.prob.fit(selected, start=cur.effects, grid_for="", max_evals=2 * self.opt.max_evals,
                              run=self.run)
            self.fits[key] = f if f.train_mse <= cur.train_mse else cur
        return self.fits[key]


@dataclass
class Path:
    """What one decision makes of the explored rounds."""

    selected: tuple[str, ...]
    fit: Fit
    chosen_round: dict[str, int]
    chosen_from: dict[str, Fit]  # the fit each chosen effect was judged against
    start_mse: list[float]
    dropped: list[dict]
    notes: list[str]
    together: dict[str, PairedGain] = field(default_factory=dict)  # the first of a pair that entered together:
    # its test given the second
    from_runner_up: bool = False  # round 2 went on from the first round's runner-up
    to_load: dict[str, dict] = field(default_factory=dict)  # effects given to the aero load: their airspeed split
    kept_by_airspeed: dict[str, dict] = field(default_factory=dict)  # named beside the load: their split
    unnamed: dict[str, dict] = field(default_factory=dict)  # chosen and kept in the model as another effect's part

    @property
    def named(self) -> tuple[str, ...]:
        """The verdict: the chosen effects less those kept as another one's part (``viscous_lag``)."""
        return tuple(x for x in self.selected if x not in self.unnamed)


def decide(ex: Explorer, d: Decision, max_effects: int) -> Path:
    """Greedy forward selection under decision ``d`` (with a beam of two in round 2, and a pair entering
    together when no effect passes alone), a backward pass with the same test, then a joint refit."""
    sel: tuple[str, ...] = ()
    cur = ex.nominal
    chosen_round: dict[str, int] = {}
    chosen_from: dict[str, Fit] = {}
    start_mse: list[float] = []
    notes: list[str] = []
    runner_up: Judged | None = None
    together: dict[str, PairedGain] = {}
    entered_together: tuple[str, ...] = ()
    from_runner_up = False
    play_note = ""  # ``stall_as_play``'s reason, said only if the backlash it named stays in the verdict
    for rnd in range(min(max_effects, len(ex.names))):
        if len(sel) >= max_effects:
            break
        # the beam's two second rounds (below) fitted side by side
        judged = ex.rounds([sel, (runner_up.name,)])[0] if rnd == 1 and runner_up is not None else ex.round(sel)
        start_mse.append(cur.score_mse)
        acc = [j for j in judged if ex.admits(d, cur, j.fit, j.gain)]
        if not acc and not sel and max_effects >= 2:
            pair = enter_together(ex, d, judged)
            if pair is not None:
                lead, second, g_lead = pair
                notes.append(f"no effect alone passed the test, but {lead.name} and {second.name} together do, "
                             f"and each adds a significant, material share once the other is fitted: each hides "
                             f"the other")
                sel = (lead.name, second.name)
                chosen_round = {lead.name: 1, second.name: 2}
                chosen_from = {lead.name: ex.nominal, second.name: lead.fit}
                start_mse.append(lead.fit.score_mse)
                together = {lead.name: g_lead}
                entered_together = sel
                cur = second.fit
                continue
        if rnd == 1 and runner_up is not None:
            # a beam of two in the second round: the first round's winner may imitate two effects at once,
            # and then only its runner-up leads to the right pair
            alt = ex.round((runner_up.name,))
            alt_acc = [j for j in alt if ex.admits(d, runner_up.fit, j.fit, j.gain)]
            a_best = max(alt_acc, key=lambda j: j.penalised) if alt_acc else None
            m_best = max(acc, key=lambda j: j.penalised) if acc else None
            if a_best is not None and (m_best is None or a_best.fit.score_mse < m_best.fit.score_mse) \
                    and ex.admits(d, cur, a_best.fit):
                notes.append(f"round 2 went on from the first round's runner-up {runner_up.name} instead of "
                             f"{sel[0]}: together with a second effect it explains the log better")
                chosen_round = {runner_up.name: 1}
                chosen_from = {runner_up.name: ex.nominal}
                from_runner_up = True
                sel = (runner_up.name,)
                cur = runner_up.fit
                start_mse[-1] = cur.score_mse
                acc = alt_acc
        if not acc:
            break
        best = max(acc, key=lambda j: j.penalised)
        if d.parsimony:  # the simplest of the equal explanations
            equal = [j for j in acc if j is best or ex.ties(ex.gain(j.fit, best.fit), d)]
            best = min(equal, key=lambda j: (j.fit.params_of[j.name], -j.penalised))
        swap = unstrained_equal(ex, d, best, acc)
        if swap is not None:
            notes.append(strain_note(best, swap, rnd + 1))
            best = swap
        play = stall_as_play(ex, d, best, acc)
        if play is not None:
            play_note = play["reason"]
            best = play["judged"]
        if rnd == 0:
            # the runner-up gets a second round of its own only when it explains nearly as much (at least half
            # the winner's gain): only then can the winner be imitating it together with another effect
            others = sorted((j for j in acc if j is not best and j.gain.gain >= 0.5 * best.gain.gain),
                            key=lambda j: -j.penalised)
            runner_up = others[0] if others else None
        chosen_from[best.name] = cur
        chosen_round[best.name] = len(sel) + 1
        sel = sel + (best.name,)
        cur = best.fit
    dropped: list[dict] = []
    changed = True
    while changed and len(sel) >= 2:
        changed = False
        ex.prefetch_without(sel, cur)
        for s in sel:
            f = ex.without(sel, s, cur)
            g = ex.gain(f, cur)
            if not ex.admits(d, f, cur, g):
                dropped.append({"effect": s, "gain_ms_when_kept": g.gain, "p_value": g.p_value,
                                "share_when_kept": ex.share(f, g.gain),
                                "reason": "once the others are fitted it adds no significant, material share "
                                          "of the gap"})
                sel = tuple(x for x in sel if x != s)
                chosen_round.pop(s, None)
                cur = f
                changed = True
                break
    to_load: dict[str, dict] = {}
    kept_by_airspeed: dict[str, dict] = {}
    for b in [b for b in LOAD_COUPLED if b in sel and "aero_load" in sel]:
        f0 = ex.without(sel, b, cur)
        r = gain_by_airspeed(ex.w, f0.w_pred, cur.w_pred, ex.prob.q, ex.prob.split.score)
        if r is None:
            continue
        if not grows_with_load(r):
            kept_by_airspeed[b] = r
            continue
        dropped.append({"effect": b, "reason": f"its held-out gain grows faster than the dynamic pressure "
                                               f"({_ratio_text(r)}): what the load's tension changes in a "
                                               f"tendon sheath (its friction band, capstan law, and the "
                                               f"tendon's compliance), so it is the aero load's",
                        "gain_by_airspeed": r})
        to_load[b] = r
        sel = tuple(x for x in sel if x != b)
        chosen_round.pop(b, None)
        cur = f0
    if len(sel) == 1 and sel[0] in entered_together and not ex.admits(d, ex.nominal, cur):
        # what is left of a pair that entered together was never admitted alone
        dropped.append({"effect": sel[0], "reason": "entered together with an effect dropped since, and alone "
                                                    "it adds no significant, material share of the gap"})
        sel, chosen_round, cur = (), {}, ex.nominal
    together = {k: v for k, v in together.items() if k in sel}
    kept_by_airspeed = {k: v for k, v in kept_by_airspeed.items() if k in sel}
    if sel:
        cur = ex.final(sel, cur)
    if play_note and "backlash" in sel and "friction" not in sel:
        notes.append(play_note)
    unnamed: dict[str, dict] = {}
    viscous = viscous_lag(sel, cur.effects, ex.base)
    if viscous is not None:  # chosen and fitted as any effect, but the friction's: not named
        unnamed["delay"] = viscous
        notes.append(viscous["reason"])
    # the effect that won the first round on its own and kept its place (not a runner-up taken for its pair,
    # not one of two that entered together)
    first_alone = sel[0] if sel and not entered_together and not from_runner_up and chosen_round.get(sel[0]) == 1 \
        else None
    tension = tension_band(sel, first_alone, cur.effects, ex.base, ex.prob)
    if tension is not None:  # likewise: the band followed the tension
        unnamed["friction"] = tension
        notes.append(tension["reason"])
    from_runner_up = from_runner_up and bool(sel) and chosen_round.get(sel[0]) == 1
    # an effect dropped leaves a gap in the round numbers: the rounds the report shows follow ``sel``
    chosen_round = {n: k + 1 for k, n in enumerate(sorted(sel, key=chosen_round.get))}
    return Path(sel, cur, chosen_round, chosen_from, start_mse, dropped, notes, together, from_runner_up, to_load,
                kept_by_airspeed, unnamed)


def strained(j: Judged) -> bool:
    """True when the candidate's own fitted parameter sits at an edge of its search that has the generic
    reading (a drift settling faster than a quarter of the log, a friction past its range ...): the effect
    larger than the model allows, or standing in for another. Edges ``BOUND_HINTS`` reads otherwise (two
    equal sensor lags, a tendon going slack within the travel) are states a true effect can be in."""
    return any(h["effect"] == j.name and (h["parameter"], h["bound"]) not in BOUND_HINTS
               for h in j.fit.bound_hits())


def unstrained_equal(ex: Explorer, d: Decision, best: Judged, acc: list[Judged]) -> Judged | None:
    """The candidate to name instead of a strained round winner (else None): the best-scoring of those the
    held-out test cannot tell from it (``Explorer.ties``) whose own fit is not strained. Of two equal
    explanations, one that needs its parameter pushed to the edge of what the effect can do is the weaker."""
    if not strained(best):
        return None
    equal = [j for j in acc if j is not best and not strained(j)
             and ex.ties(ex.gain(*sorted((j.fit, best.fit), key=lambda f: -f.score_mse)), d)]
    return max(equal, key=lambda j: j.penalised) if equal else None


def strain_note(strained_one: Judged, named: Judged, rnd: int) -> str:
    """What the report says when ``unstrained_equal`` named another candidate than the round's winner."""
    edges = ", ".join(f"{h['parameter']} at the {h['bound']} edge of its search" for h in
                      strained_one.fit.bound_hits() if h["effect"] == strained_one.name)
    return (f"round {rnd}: {strained_one.name} explained the log no better than {named.name} on the held-out "
            f"blocks, with {edges} (larger than the effect can be, or standing in for another): {named.name} "
            f"is named, the two reported as equally good")


def stall_as_play(ex: Explorer, d: Decision, best: Judged, acc: list[Judged]) -> dict | None:
    """The backlash to name instead of a capstan stall the held-out test cannot tell from it (else None).

    A capstan stall is a play at every reversal that grows with the tension (``capstan_zero_mm`` where the
    tendon goes slack, the ratios its growth per mm above it); with its zero far below the travel and small
    ratios it tends to a fixed play, a backlash: the backlash is the stall's limit, one parameter against
    three. When friction wins a round in that form with a stall that less than doubles across the log's
    travel (its zero more than the travel's span below it: closer to a fixed play than to one in proportion
    to the travel), only by a margin the held-out test does not find (not significant at the ambiguity
    level, or not material), and backlash passes the round's test too, nothing in the log shows the play
    growing with the tension, and the play is named (``decide`` says why in a note when the backlash stays
    in the verdict). A stall that grows more across the travel, a stall the model already carried on the
    bench, and a friction in its band form (the loop widens, no play) keep their place."""
    eff = best.fit.effects
    if best.name != "friction" or not eff.has_capstan \
            or all(getattr(eff, f) == getattr(ex.base, f) for f in CAPSTAN_FIELDS):  # a stall of the bench's
        return None
    lo, hi = ex.prob.travel  # the log's travel, as the fit's search takes it
    above = lo - eff.capstan_zero_mm
    growth = (hi - eff.capstan_zero_mm) / above if above > 0 else math.inf
    if not growth < STALL_AS_PLAY_GROWTH:
        return None
    play = next((j for j in acc if j.name == "backlash"), None)
    if play is None or not ex.ties(ex.gain(play.fit, best.fit), d):
        return None
    return {"judged": play,
            "reason": f"friction's capstan stall (a play growing with the tension, x{eff.capstan_pull_ratio:.3g} "
                      f"pulling and x{eff.capstan_release_ratio:.3g} releasing per mm above "
                      f"{eff.capstan_zero_mm:.3g} mm, x{growth:.2f} across the log's travel) explains the log no "
                      f"better than a fixed play on the held-out blocks: the play is the stall's limit and "
                      f"nothing shows it growing with the tension, so backlash is named (to tell them apart: "
                      f"minor loops at several mean tendon positions; a stall's play grows with the tension, a "
                      f"backlash's does not)"}


def viscous_lag(selected: tuple[str, ...], eff: Effects, base: Effects) -> dict | None:
    """The delay chosen beside a weaker friction when it is that friction's rate-dependent part (else None).

    A sheath's drag on the tendon grows with its sliding speed (a lubricant's shear), and like its Coulomb
    part it presses with the normal force, so a change of the bend, the wrap or the tension scales both.
    The drag lags the pull; the rate-independent model can hold a lag only in its transport delay, which
    identify fits on the bench together with the link's and the servo's latency (a first-order lag taken
    as a delay: an approximation). So when the band narrows (friction scale s < 1) and the delay shortens
    with it, by no more than the share (1 - s) of the bench's delay that a drag could at most have held
    (all of it being drag: a generous bound), the shorter delay is read as the friction's: it stays in the
    model (it predicts the log), is reported apart from the verdict, and a note says what to check. A delay
    that grew stays named, and so does one beside a stronger friction: a slower link and a stronger drag
    lengthen the lag alike. What this rule gets wrong: a field link faster than the bench's (another
    logger or radio) beside a friction that weakened, and a change of lubricant, which moves the drag and
    the Coulomb part apart (then the delay grows and stays named)."""
    if not {"friction", "delay"} <= set(selected) or eff.has_capstan:
        return None
    s, d0, d1 = eff.friction_scale, base.delay_s, eff.delay_s
    if not (0.0 < s < 1.0 and d0 > 0.0 and d1 < d0 and d0 - d1 <= (1.0 - s) * d0):
        return None
    return {"friction_scale": s, "bench_delay_s": d0, "delay_s": d1,
            "reason": f"the delay shortened with the friction ({1e3 * d0:.1f} -> {1e3 * d1:.1f} ms while the "
                      f"band narrowed to x{s:.2f}): a sheath's drag lags the pull in proportion to its speed and "
                      f"weakens with the friction, and the bench's delay held that lag with the link's and the "
                      f"servo's latency; the shorter delay is read as the friction's rate-dependent part, kept in "
                      f"the model but not named (if the field's link or logger is faster than the bench's, it "
                      f"may be that instead: compare their latencies)"}


def band_in_travel(eff: Effects, width: float, u: np.ndarray | None = None) -> float:
    """The hysteresis band's width in tendon travel (mm) of a model whose band, without effects, is ``width``
    wide: scaled by friction's band form and by a whole-loop pre-tension's 1 / gain, widened by a capstan
    stall's play (pulling plus releasing) averaged over the log's travel ``u`` (the form's own travel)."""
    band = width * eff.friction_scale / (eff.pretension_gain if eff.pretension_loop else 1.0)
    if eff.has_capstan:
        tension = float(np.mean(np.maximum(np.asarray(u) - eff.capstan_zero_mm, 0.0)))
        band += (eff.capstan_pull_ratio + eff.capstan_release_ratio) * tension
    return band


def model_band_width(params, w: np.ndarray) -> float:
    """The Bouc-Wen band's width in tendon travel, az (z_hi - z_lo), weighted over the log's warp signs (its
    saturation levels depend on sgn w)."""
    pos = float(np.mean(np.asarray(w) >= 0.0))
    width = 0.0
    for sign, share in ((1.0, pos), (-1.0, 1.0 - pos)):
        if share > 0.0:
            lo, hi = reachable_band(params, sign)
            width += share * abs(params.az) * (hi - lo)
    return width


def tension_band(selected: tuple[str, ...], first_alone: str | None, eff: Effects,
                 base: Effects, prob=None) -> dict | None:
    """The friction chosen after a pre-tension when its band change is what the tension change does to a sheath
    (else None).

    In a tendon sheath the force a stretch of sheath holds grows with the tension through it (capstan law), so
    the hysteresis band, in tendon travel, scales with the tension the rig carries at each warp: a wing
    re-rigged stiffer (or softer) pulls harder (or less) for the same warp and widens (or narrows) the band by
    the same factor. The same tension stretches the tendon: the backbone's travel per degree scales too, but
    only in the share ``sigma`` of it that is the tendon's stretch (the rest is the wing's geometry): a band
    factor F goes with a compliance factor 1 + sigma (F - 1), 0 < sigma <= 1, the same way and less
    (``pretension_loop = 1`` is sigma = 1). Against the model's own effects, the band in travel is
    friction_scale (over the gain in the whole-loop form) and the compliance 1 / gain; a capstan stall widens it
    by its play averaged over the log's travel, against the band of the Bouc-Wen model (``band_in_travel``,
    ``model_band_width``; ``prob``: the ``Problem`` with the log and the model). When the pre-tension won the
    first round on its own (it explains the log's change alone; the friction refines it) and the band and the
    compliance moved the same way, the band by at least as much, the friction is read as the tension's: kept in
    the model (it predicts the log), reported apart from the verdict with its band and compliance factors and
    ``stretch_share``, the ratio of their logarithms (sigma for small changes), with a note. A friction that
    moved against the compliance, or less than it, or a path the pre-tension did not lead alone (the friction
    first, a runner-up's path, two that entered together), keeps it named, and so does a stall without the
    model's band to judge it against. What this rule gets wrong: a sheath whose own friction changed (wear,
    lubricant, routing) the same way as a re-rigging, by more than the re-rigging's share; measuring the tension
    at rest tells them apart."""
    if not {"friction", "pretension"} <= set(selected) or first_alone != "pretension":
        return None
    width, u = 1.0, None  # the band form's factors do not depend on the band's width or the travel
    if eff.has_capstan or base.has_capstan:
        if prob is None:
            return None
        width, u = model_band_width(prob.params, prob.w), prob.u
        if not (math.isfinite(width) and width > 0.0):
            return None
    compliance = math.log(base.pretension_gain / eff.pretension_gain)
    band = math.log(band_in_travel(eff, width, u) / band_in_travel(base, width, u))
    if not (compliance * band > 0.0 and abs(band) >= abs(compliance)):
        return None
    sigma = compliance / band
    way = "widened" if band > 0 else "narrowed"
    return {"band_factor": math.exp(band), "compliance_factor": math.exp(compliance), "stretch_share": sigma,
            "reason": f"the friction band {way} (x{math.exp(band):.2f}) with the rig's compliance (x"
                      f"{math.exp(compliance):.2f} travel per degree) after the pre-tension changed: in a tendon "
                      f"sheath the band follows the tension (capstan law) and the tendon's stretch, {sigma:.0%} "
                      f"of the travel here, follows it too; the friction change is read as the pre-tension's, "
                      f"kept in the model but not named (if the sheath itself changed, its bend, wear or "
                      f"lubricant, measure the tendon's tension at rest against the bench's: a band that "
                      f"changed more than the tension is the sheath's own)"}


def enter_together(ex: Explorer, d: Decision, judged: list[Judged]) -> tuple[Judged, Judged, PairedGain] | None:
    """Two effects that hide each other, when no effect alone passes the test: the unexplained one leaves
    slow, structured error that weakens the evidence for the other. Each of the first round's
    ``TOGETHER_LEADS`` candidates of largest held-out gain leads in turn, and it and a second effect enter
    together when the pair passes the test against the nominal, the second passes it against the first
    alone (as in round 2), and the first passes it against the second alone (as in the backward pass).
    Returns (first, second, the first's gain given the second) or None."""
    # led by the held-out gain, not the penalised one: with nothing significant alone, the penalty for a
    # candidate's parameters says little about which of two hidden effects it is, and the gain says how
    # much of the log it explains
    leads = sorted((j for j in judged if j.gain.gain > 0), key=lambda j: -j.gain.gain)
    for lead in leads[:TOGETHER_LEADS]:
        seconds = sorted((j for j in ex.round((lead.name,))
                          if ex.admits(d, lead.fit, j.fit, j.gain) and ex.admits(d, ex.nominal, j.fit)),
                         key=lambda j: -j.penalised)
        for second in seconds[:2]:
            pair = (lead.name, second.name)
            alone = ex.without(pair, lead.name, second.fit)
            g = ex.gain(alone, second.fit)
            if ex.admits(d, alone, second.fit, g):
                return lead, second, g
    return None


@dataclass
class Setup:
    """What every decision of a diagnosis starts from: the fitting problem (log, nominal model, its initial
    state and error correction), the floor (noise and the model's known error) and the candidates."""

    prob: Problem
    ex: Explorer
    noise: float
    e_m: float
    skipped: dict[str, str]
    z0: float  # the initial state estimated from the log's opening stretch
    slack_side: float  # where the play's slack is taken up at the start (``initial_state``)
    error_model: ErrorModel | None  # the model-error correction applied (None: not used)


def set_up(t, u, w, airspeed, model: ModelFile, opt: DiagnoseOptions,
           progress: Callable[[str, int, int], None] | None = None) -> Setup:
    """Check a cleaned log and set up its diagnosis against ``model`` (``diagnose``'s first step)."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    u = np.ascontiguousarray(u, dtype=np.float64)
    w = np.ascontiguousarray(w, dtype=np.float64)
    if not (t.size == u.size == w.size) or (airspeed is not None and np.size(airspeed) != t.size):
        raise ValueError("t, u, warp (and airspeed) must have the same length")
    if t.size < 100:
        raise ValueError(f"log too short to diagnose: {t.size} samples (need at least 100)")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(u)) and np.all(np.isfinite(w))):
        raise ValueError("t, u and warp must be finite")
    if np.ptp(u) <= 0:
        raise ValueError("the tendon input never changes: nothing to diagnose")
    if progress:
        progress("initial state", 0, 1)
    em = model.model_error if opt.use_model_error else None
    z0, side = initial_state(t, u, w, airspeed, model, em)
    prob = Problem(t, u, w, airspeed, model.params, model.effects, z0, error_model=em, slack_side=side)
    sp = prob.split
    if sp.score.sum() < 20 or sp.train.sum() < 20:
        raise ValueError("log too short after the warm-up to split into training and scoring blocks")
    base = model.effects
    w_nom = prob.predict(base)
    noise = noise_floor(w)
    e_m = known_error(model, noise, opt.use_model_error)
    names = [n for n in opt.effects if n != "aero_load" or prob.has_airspeed]
    why = "the log has no airspeed" if airspeed is None else "the airspeed is zero throughout the log"
    skipped = {n: why for n in opt.effects if n not in names}
    nominal = Fit((), base, w_nom, prob.mse(w_nom, sp.train), prob.mse(w_nom, sp.score), 0)
    ex = Explorer(prob, names, base, nominal, noise ** 2 + e_m ** 2, opt, progress)
    return Setup(prob, ex, noise, e_m, skipped, z0, side, em)


CARRY_ROUNDS = 4  # decisions re-made at most, each with the floor raised by what the correction did not carry


@dataclass
class Carry:
    """Whether the bench's model-error correction carries to this log (``model.diag_transfer``): the same
    problem without the correction, the correction's bench gain, its gain on the nominal here, and what
    the known error already holds beyond the bench's (deg^2: a check log of another input measured it)."""

    bare: Problem
    bench_gain: float
    nominal: Transfer
    measured_ms: float = 0.0

    def of(self, ex: Explorer, fit: Fit) -> Transfer:
        """The correction's gain here given ``fit``'s effects."""
        return transfer(ex.w, self.bare.predict(fit.effects), fit.w_pred, ex.prob.split.chunks, self.bench_gain)

    def raise_for(self, ex: Explorer, path: Path) -> tuple[float, Transfer]:
        """What the floor rises by (deg^2) for ``path``'s verdict, beyond what the known error already
        holds, and the correction's gain given the verdict's effects."""
        tr = self.of(ex, path.fit) if path.selected else self.nominal
        return max(raised_floor(self.nominal, tr) - self.measured_ms, 0.0), tr


def carry_check(ex: Explorer, em: ErrorModel | None, slack_side: float, measured_ms: float = 0.0) -> Carry | None:
    """The transfer check of the correction ``em`` on the explorer's log, whose nominal takes up its slack
    on ``slack_side`` (None without a correction); ``measured_ms`` is what the known error already holds
    beyond the bench's (``identify --check``): a shortfall raises the floor only past it."""
    prob = ex.prob
    if em is None or prob.error_model is None or not (
            math.isfinite(em.rms_before_deg) and math.isfinite(em.rms_after_deg)):
        return None
    bare = Problem(prob.t, prob.u, prob.w, prob.airspeed, prob.params, prob.base, prob.z0, split=prob.split,
                   error_model=None, slack_side=slack_side)
    bench_gain = em.rms_before_deg ** 2 - em.rms_after_deg ** 2
    nominal = transfer(ex.w, bare.predict(ex.base), ex.nominal.w_pred, prob.split.chunks, bench_gain)
    return Carry(bare, bench_gain, nominal, max(measured_ms, 0.0))


def decide_carried(ex: Explorer, d: Decision, max_effects: int, carry: Carry | None) -> tuple[Path, dict | None]:
    """``decide``, then, when the correction's gain on the nominal falls significantly short of the bench's,
    the same with the floor raised by what it did not carry given the verdict's effects (the smaller of
    the two shortfalls, both significant), until the raise a verdict asks for is the one it was decided
    at. When a verdict asks for less than its floor, the lower floor is tried: its verdict is taken if it
    is the same one; else the higher floor's stands (the verdict that names less). ``ex.floor2`` is left
    as it was; the second value says what was raised and whether it settled (None: the correction
    carries, or there is none)."""
    path = decide(ex, d, max_effects)
    if carry is None or not carry.nominal.short:
        return path, None
    base, extra, settled = ex.floor2, 0.0, False
    try:
        for _ in range(CARRY_ROUNDS):
            up, tr = carry.raise_for(ex, path)
            if math.isclose(up, extra, rel_tol=1e-9, abs_tol=1e-15):
                settled = True
                break
            ex.floor2 = base + up
            lower = decide(ex, d, max_effects)
            if up < extra:  # the verdict asks for less than the floor it was decided at
                if lower.named == path.named:
                    path, extra = lower, up
                    up, tr = carry.raise_for(ex, path)
                    settled = math.isclose(up, extra, rel_tol=1e-9, abs_tol=1e-15)
                break
            path, extra = lower, up
        else:
            up, tr = carry.raise_for(ex, path)
            settled = math.isclose(up, extra, rel_tol=1e-9, abs_tol=1e-15)
    finally:
        ex.floor2 = base
    return path, {"raised_by_ms": extra, "settled": settled, "nominal": carry.nominal.to_dict(),
                  "verdict": tr.to_dict()}


def diagnose(t, u, w, airspeed, model: ModelFile, options: DiagnoseOptions | None = None,
             progress: Callable[[str, int, int], None] | None = None) -> Diagnosis:
    """Diagnose the gap between ``model`` and a cleaned log (t s increasing, u mm, w deg, airspeed m/s or None).

    ``progress(stage, i, n)`` is called as the work advances (no I/O here)."""
    opt = options or DiagnoseOptions()
    su = set_up(t, u, w, airspeed, model, opt, progress)
    prob, ex, noise, e_m, skipped = su.prob, su.ex, su.noise, su.e_m, su.skipped
    z0, side, em = su.z0, su.slack_side, su.error_model
    t, u, w = prob.t, prob.u, prob.w
    sp, base, names, nominal, floor2 = prob.split, ex.base, ex.names, ex.nominal, ex.floor2
    w_nom = nominal.w_pred
    r0 = w - w_nom
    analysed = sp.train | sp.score
    cl = cells(t, u, w_nom, airspeed)
    where = split(t, u, r0, cl, analysed, noise, e_m)
    ra = r0[analysed]
    white = ljung_box(ra)
    indep = input_independence(prewhiten(u[analysed]), ra[1:])

    alternatives = []
    # what a check log already put in the known error beyond the bench's: the shortfall raises it only past that
    measured = e_m ** 2 - bench_known_error(model, noise, opt.use_model_error) ** 2
    carry = carry_check(ex, em, side, measured)
    alt_paths = []
    with ex.workers():
        path, carried = decide_carried(ex, opt.decision, opt.max_effects, carry)
        for k, d in enumerate(opt.alternatives):
            if progress:
                progress("alternative decisions", k, len(opt.alternatives))
            alt, alt_carried = (path, carried) if d == opt.decision else decide_carried(ex, d, opt.max_effects, carry)
            alt_paths.append(alt)
            alternatives.append({"decision": d.to_dict(), "verdict": list(alt.named),
                                 "floor_raised_by_ms": alt_carried["raised_by_ms"] if alt_carried else 0.0,
                                 "kept_unnamed": sorted(alt.unnamed),
                                 "heldout_rms_after_deg": math.sqrt(alt.fit.score_mse),
                                 "to_aero_load": [{"effect": b} | r for b, r in alt.to_load.items()]})
    sized = WholeLogSizes(prob, opt.max_evals, progress)
    sized.expect([path] + alt_paths)
    for a, alt in zip(alternatives, alt_paths, strict=True):
        a["effects"] = {n: sized.of(alt).values([n])[n] for n in alt.named}
    raised = carried["raised_by_ms"] if carried is not None else 0.0
    e_known = math.sqrt(e_m ** 2 + raised)  # the known error the report judges by: raised where it did not carry
    if raised > 0:  # the rest of the report on the raised floor
        ex.floor2 = floor2 = floor2 + raised
        where = split(t, u, r0, cl, analysed, noise, e_known)
    selected = list(path.named)
    cur = path.fit
    rounds, ambiguities, chosen_conf = _main_rounds(ex, path, opt)
    w_aug = cur.w_pred if selected else w_nom
    r1 = w - w_aug

    shrink = split(t, u, r0, cl, sp.score, noise, e_known, r_after=r1)
    mse0, mse1 = prob.mse(w_nom, sp.score), prob.mse(w_aug, sp.score)
    shrinkage = {
        "heldout_rms_before_deg": math.sqrt(mse0), "heldout_rms_after_deg": math.sqrt(mse1),
        "gap_closed": gap_closed(mse0, mse1, noise ** 2),
        "gap_closed_beyond_model_error": gap_closed(mse0, mse1, floor2),
        "where": {k: v for k, v in shrink.items() if k not in ("scores", "dominant", "dominant_cell")},
    }
    whole = sized.of(path)  # the verdict's effects sized on every analysed sample; ``cur`` is the held-out one
    hits = whole.bound_hits() if selected else []
    for h in hits:
        h["meaning"] = _bound_meaning(h)
        chosen_conf[h["effect"]] = chosen_conf.get(h["effect"], 0.0) * BOUND_CONFIDENCE
    cand = _candidate_table(names, skipped, rounds, path, chosen_conf, cur, nominal, hits)
    notes = list(path.notes)
    if raised > 0:
        nom = carry.nominal
        notes.append(f"the bench's model-error correction does not carry to this log: it lowers the squared error "
                     f"by {nom.bench_gain:.2g} deg^2 on the bench but {nom.field_gain:.2g} here "
                     f"(p={nom.p_value:.2g}); the part it did not carry is model error the bench could not see, "
                     f"so the known error is taken as {e_known:.3f} deg "
                     f"instead of {e_m:.3f} (a second bench log of another realisation of the input measures "
                     f"it: identify --check)")
        if not carried["settled"]:
            notes.append("the raise did not settle: the verdict asks for a different raise than the one it was "
                         "decided at, and the lower raise gives another verdict; the verdict of the higher one is "
                         "kept (the stricter floor)")
    for h in hits:
        notes.append(h["meaning"])
    notes += widened_notes(cur, selected)
    by_airspeed = [{"effect": b} | r for b, r in path.kept_by_airspeed.items()]
    notes += tension_band_notes(selected, airspeed_checked=bool(by_airspeed))
    if "friction" not in path.unnamed:  # else the kept friction's note gives the band's whole factor
        notes += whole_loop_notes(selected, cur.effects)
    notes += [airspeed_note(b) for b in by_airspeed]
    left = left_over(t, u, r1, sp, floor2, opt.decision.min_gain, airspeed)
    if (left_note := left_over_note(left, bool(selected))) is not None:
        notes.append(left_note)
    residual_is_noise = white.passed and indep.passed
    if not selected and not residual_is_noise:
        notes.append("the residual is structured but no effect explains a significant, material share of it: "
                     "it is the model's own error (re-identify on a richer log, or diagnose a longer one)")
    eff_out = whole.effects if selected else base
    extra = {"method": "warpbridge diagnose", "verdict": list(selected), "nominal_heldout_rms_deg": math.sqrt(mse0)}
    if "travel_mm" in model.fit.extra:  # the nominal's parameters were identified there, whatever the effects add
        extra["travel_mm"] = model.fit.extra["travel_mm"]
    fitq = FitQuality(train_rms_deg=math.sqrt(prob.mse(w_aug, sp.train)), heldout_rms_deg=math.sqrt(mse1),
                      noise_deg=noise, extra=extra)
    meta = dict(model.meta)
    meta["augmented_by"] = "warpbridge diagnose"
    meta["verdict"] = list(selected)
    augmented = ModelFile(params=model.params, effects=eff_out, z0=model.z0, fit=fitq, meta=meta,
                          model_error=model.model_error)
    report = {
        "format": REPORT_FORMAT,
        "verdict": list(selected),
        "effects": {n: whole.values([n])[n] for n in selected},
        "effects_sized_on": "every analysed sample (training and scored blocks), once the scored blocks had "
                            "chosen them; `effects_on_training_blocks` are the sizes the held-out figures are of",
        "effects_on_training_blocks": {n: cur.values([n])[n] for n in selected},
        "samples": int(t.size), "duration_s": float(t[-1] - t[0]),
        "noise_deg": noise, "model_error_deg": e_m, "floor_deg": math.sqrt(floor2),
        "model_error_from_check": _check_note(model, noise, opt.use_model_error),
        "model_error_carried": _carry_note(carry, carried, e_known),
        "decision": opt.decision.to_dict(),
        "initial_state": {"z0": z0, "method": "estimated from the log's opening stretch (algebraic start, "
                                              "clamped to the reachable band, refined on the prediction error)"}
        | ({"slack_taken_up_by": slack_side_name(side)} if model.effects.has_slack else {}),
        "model_error_model": _em_summary(model.model_error, em is not None),
        "residual_is_noise": residual_is_noise,
        "tests": {"whiteness": white.to_dict(), "input_independence": indep.to_dict()},
        "where": where,
        "candidates": cand,
        "bound_hits": hits,
        "ambiguities": ambiguities,
        "dropped": path.dropped,
        "kept_unnamed": {n: {"fitted": whole.values([n])[n]} | v for n, v in path.unnamed.items()},
        "band_gain_by_airspeed": by_airspeed,
        "shrinkage": shrinkage,
        "left_over": left,
        "alternatives": alternatives,
        "split": {"scheme": "10 blocks, 4 scored (2, 5, 7, 10 unless the two where the command moves fastest "
                            "would then be on the same side)", "scored_blocks": [b + 1 for b in sp.pattern],
                  "warmup_samples": sp.start,
                  "train_samples": int(sp.train.sum()), "score_samples": int(sp.score.sum()),
                  "score_chunks": int(sp.chunks.max() + 1)},
        "nominal_effects": base.to_dict(),
        "notes": notes,
        "model_evaluations": prob.evaluations,
    }
    report["summary"] = summary_lines(report)
    return Diagnosis(list(selected), report, augmented, t, u, w, w_nom, w_aug, sp, cl)


class WholeLogSizes:
    """Each verdict's effects sized on the whole analysed log (``Problem.refit_whole``), once per distinct fit;
    a verdict of no effect is its own fit."""

    def __init__(self, prob: Problem, max_evals: int, progress: Callable[[str, int, int], None] | None) -> None:
        self.prob, self.max_evals, self.progress = prob, max_evals, progress
        self._done: dict[str, Fit] = {}

    @staticmethod
    def _key(p: Path) -> str:
        return repr((p.selected, p.fit.effects))

    def expect(self, paths: list[Path]) -> None:
        """Refit every distinct verdict of ``paths`` now, with progress."""
        todo = {self._key(p): p for p in paths if p.selected and self._key(p) not in self._done}
        for k, (key, p) in enumerate(todo.items()):
            if self.progress:
                self.progress("sizing on the whole log", k, len(todo))
            self._done[key] = self.prob.refit_whole(p.fit, self.max_evals)

    def of(self, p: Path) -> Fit:
        if not p.selected:
            return p.fit
        self.expect([p])
        return self._done[self._key(p)]


# a change of the tension the sheath carries changes its friction too (capstan law: the force a stretch of
# sheath can hold grows with the tension through it): what changed it, and how to tell the two apart
TENSION_CHANGES = {
    "pretension": ("a re-tensioned rig", "measure the tendon's tension at rest against the bench's: a band that "
                                         "changed in proportion to it is the tension's, one that changed more is "
                                         "the sheath's own (its bend, routing, wear or lubrication)"),
    "aero_load": ("a load on the wing", "compare stretches flown slow and fast: a band that grows with the "
                                        "airspeed is the load's"),
}
BAND_EFFECTS = ("friction", "backlash")  # what a wider or narrower friction band is named as
# what a load on the wing changes in a tendon sheath besides the warp it bends back: the friction band and the
# tendon's compliance (its take-up of slack stiffens with tension), all through the tension the load adds
LOAD_COUPLED = (*BAND_EFFECTS, "pretension")


def tension_band_notes(selected: list[str], airspeed_checked: bool = False) -> list[str]:
    """Notes for a band effect named together with a change of the tendon's tension: in a tendon sheath the
    second may be the first's consequence, not a change of its own. With ``airspeed_checked`` the aero load's
    is left to ``airspeed_note`` (the log itself was checked)."""
    band = [b for b in BAND_EFFECTS if b in selected]
    notes = []
    for cause, (what, check) in TENSION_CHANGES.items():
        if cause == "aero_load" and airspeed_checked:
            continue
        if cause in selected and band:
            notes.append(f"{' and '.join(band)} named with {cause}: in a tendon sheath the friction grows with "
                         f"the tension (capstan law), so {what} widens or narrows the hysteresis band too, and "
                         f"the {' / '.join(band)} change may be the {cause}'s consequence rather than a change "
                         f"of its own; to tell them apart, {check}")
    return notes


def whole_loop_notes(selected: list[str], eff: Effects) -> list[str]:
    """A note for a pre-tension named in its whole-loop form: the band scaled with the backbone, which a
    re-tensioned rig and a sheath whose bend changed both do (capstan law), so the cause is the user's to
    tell apart."""
    if "pretension" not in selected or not eff.pretension_loop:
        return []
    g = eff.pretension_gain
    return [f"pretension named in its whole-loop form: the hysteresis band scaled with the backbone (x{1.0 / g:.2f} "
            f"in tendon travel), as the friction of a sheath follows its tension; a rig re-tensioned or pulling a "
            f"{'stiffer' if g < 1.0 else 'softer'} wing does that, and so does a sheath whose bend or routing "
            f"changed (more wrap: the far end loses more of the pull, band and compliance alike); to tell them "
            f"apart, compare the sheath's routing and the tendon's tension at rest with the bench's"]


def gain_by_airspeed(w: np.ndarray, w_without: np.ndarray, w_with: np.ndarray, q: np.ndarray,
                     mask: np.ndarray) -> dict | None:
    """What an effect gains (drop of the squared error, deg^2 per sample) on the slowest and the fastest
    third of the ``mask`` samples flown (q > 0) by dynamic pressure ``q`` (kPa). None when fewer than 30
    such samples, or when the two thirds hardly differ in airspeed (the fast third's mean q under 1.5x the
    slow third's)."""
    flying = mask & (q > 0)
    qm = q[flying]
    if qm.size < 30:
        return None
    g = ((w - w_without) ** 2 - (w - w_with) ** 2)[flying]
    order = np.argsort(qm, kind="stable")
    third = qm.size // 3
    slow, fast = order[:third], order[-third:]
    q_slow, q_fast = float(np.mean(qm[slow])), float(np.mean(qm[fast]))
    if not q_fast > 1.5 * q_slow:
        return None
    g_slow, g_fast = float(np.mean(g[slow])), float(np.mean(g[fast]))
    return {"q_slow_kpa": q_slow, "q_fast_kpa": q_fast, "gain_slow_ms": g_slow, "gain_fast_ms": g_fast,
            "fast_over_slow": g_fast / g_slow if g_slow > 0 else None}  # None: no gain (or a loss) when slow


def grows_with_load(r: dict) -> bool:
    """An effect's gain grows faster than the dynamic pressure between the slow and the fast third.

    A heuristic from two readings: a change of the sheath's own friction or rig gains about alike at any
    airspeed (ratio ~1); a band or a compliance the load changes (in proportion to it: capstan law) gains
    roughly as the square of the change, ~(q_fast / q_slow)^2 (roughly: the fitted constant takes up part of
    it, and the slow third's gain can even turn negative). The line is drawn halfway between the two on a
    log scale, g_fast / g_slow > q_fast / q_slow (compared multiplied out, so no division by a zero gain)."""
    return r["gain_fast_ms"] * r["q_slow_kpa"] > max(r["gain_slow_ms"], 0.0) * r["q_fast_kpa"]


def _ratio_text(r: dict) -> str:
    q = (f"{r['q_fast_kpa'] / r['q_slow_kpa']:.1f}x the dynamic pressure ({r['q_slow_kpa']:.2f} -> "
         f"{r['q_fast_kpa']:.2f} kPa)")
    if r["fast_over_slow"] is None:
        return (f"nothing (or a loss) on the slowest third of the log, {r['gain_fast_ms']:.2g} deg^2 on the "
                f"fastest, at {q}")
    return f"{r['fast_over_slow']:.1f}x as much on the fastest third of the log as on the slowest, at {q}"


def airspeed_note(r: dict) -> str:
    """The report's reading of ``gain_by_airspeed`` for an effect kept beside an aero load."""
    return (f"{r['effect']} beside aero_load: on the held-out blocks it gains {_ratio_text(r)}; what the load's "
            f"tension changes (the band, capstan law, or the compliance) would gain faster than the pressure "
            f"grows, so this is a change of its own")


BOUND_CONFIDENCE = 0.5  # confidence factor of an effect whose fitted parameter sits at a bound of its search


BOUND_HINTS = {  # what an edge of a search means where the generic reading does not hold
    ("capstan_zero_mm", "upper"): "the tendon would go slack within the log's travel",
    ("sensor_stage_ratio", "upper"): "two equal lags: the sensor may have more stages, or a delay as well",
}


def widened_notes(fit: Fit, selected: tuple[str, ...] | list[str]) -> list[str]:
    """What the report says of a named effect whose search went past its first limit (``Problem._search_wider``)."""
    out = []
    for b in fit.boxes:
        if b.field not in fit.widened:
            continue
        effect = effect_of(b.field)
        if effect in selected:
            out.append(f"{effect}: {b.field} fitted {getattr(fit.effects, b.field):.4g}, past the edge of its first "
                       f"search: searched again over {b.lo:.4g}..{b.hi:.4g}")
    return out


def _bound_meaning(h: dict) -> str:
    hint = BOUND_HINTS.get((h["parameter"], h["bound"]),
                           "the effect is larger than the model allows, or another effect is at work")
    return (f"{h['effect']}: {h['parameter']} sits at the {h['bound']} bound of its search ({h['limit']:.4g}): "
            f"{hint}; confidence halved")


def _em_summary(em: ErrorModel | None, used: bool) -> dict:
    if em is None:
        return {"present": False, "used": False}
    return {"present": True, "used": used, "feature_sets": list(em.sets),
            "bench_rms_before_deg": em.rms_before_deg, "bench_rms_after_deg": em.rms_after_deg,
            "known_error_deg": em.known_error_deg}


def _main_rounds(ex: Explorer, path: Path, opt: DiagnoseOptions) -> tuple[list[list[Judged]], list[dict], dict]:
    """The rounds along the chosen path, with ranks, ambiguities and confidences."""
    d = opt.decision
    rounds: list[list[Judged]] = []
    ambiguities: list[dict] = []
    chosen_conf: dict[str, float] = {}
    order = sorted(path.chosen_round, key=path.chosen_round.get)
    prefixes = [tuple(order[:k]) for k in range(len(order) + 1)]
    for k, pre in enumerate(prefixes):
        if pre not in ex.rounds_done:
            break
        judged = ex.rounds_done[pre]
        cur = ex.fit_of(pre) if pre else ex.nominal
        rounds.append(judged)
        # an effect given to the aero load is the load's: not a candidate of its own, nor a rival
        acc = [j for j in judged if ex.admits(d, cur, j.fit, j.gain) and j.name not in path.to_load]
        for j in judged:
            j.confidence = 0.0
            j.ambiguous_with_best = False
            j.share = ex.share(cur, j.gain.gain)  # the round may have been judged on a floor raised since
        if not acc:
            if k < len(order) and order[k] in path.together:  # entered as a pair: its test given the other
                j = next(j for j in judged if j.name == order[k])
                j.confidence = chosen_conf[j.name] = 1.0 - path.together[j.name].p_value
            continue
        best = next((j for j in acc if k < len(order) and j.name == order[k]), max(acc, key=lambda j: j.penalised))
        floor_gain = d.min_gain * ex.floor2
        support = {j.name: 1.0 - j.gain.p_value for j in judged}
        best_conf = support[best.name]
        # a runner-up taken for what it explains with a second effect is not made less likely by a candidate
        # that explains more alone
        rivals = [] if k == 0 and path.from_runner_up else [j for j in acc if j is not best]
        for j in rivals:
            # is the better-scoring of the two better than the other? (best may be the simpler of equals)
            worse, better = (j, best) if j.fit.score_mse >= best.fit.score_mse else (best, j)
            g = ex.gain(worse.fit, better.fit)
            p = g.p_value
            j.ambiguous_with_best = ex.ties(g, d)
            if j.ambiguous_with_best and g.gain < floor_gain and floor_gain > 0:
                p = min(1.0, max(p, 0.5 * (1.0 - g.gain / floor_gain)))
            p_best = p if better is best else 1.0 - p  # chance that j is as good as best
            j.confidence = support[j.name] * min(1.0, 2.0 * p_best)
            best_conf = min(best_conf, support[best.name] * min(1.0, 2.0 * (1.0 - p_best)))
        best.confidence = best_conf
        if best.name in path.selected:
            chosen_conf[best.name] = best_conf
            alts = [j for j in acc if j is not best and j.ambiguous_with_best]
            if alts:
                ambiguities.append(_ambiguity(best, alts, k + 1))
    return rounds, ambiguities, chosen_conf


def _ambiguity(best: Judged, alts: list[Judged], rnd: int) -> dict:
    names = [best.name] + [a.name for a in alts]
    how = []
    for a in alts:
        how.append({"effects": [best.name, a.name],
                    "excitation": SEPARATE.get(frozenset({best.name, a.name}), DEFAULT_SEPARATE)})
    return {"round": rnd, "chosen": best.name, "equally_good": names,
            "heldout_rms_deg": {j.name: math.sqrt(j.fit.score_mse) for j in [best, *alts]},
            "to_separate": how}


def _candidate_table(names, skipped, rounds: list[list[Judged]], path: Path, chosen_conf: dict[str, float],
                     final: Fit, nominal: Fit, hits: list[dict]) -> list[dict]:
    out = []
    selected = path.named
    first = {j.name: j for j in rounds[0]} if rounds else {}
    for n in list(names) + list(skipped):
        row: dict = {"effect": n, "parameters": list(EFFECT_FIELDS[n][0]), "in_verdict": n in selected}
        if n in skipped:
            row.update({"tried": False, "reason": skipped[n], "confidence": 0.0})
            out.append(row)
            continue
        row["tried"] = True
        j1 = first.get(n)
        if j1 is not None:
            alone_hits = j1.fit.bound_hits()
            for h in alone_hits:
                h["meaning"] = _bound_meaning(h)
            row["alone"] = {"fitted": j1.fit.values([n])[n],
                            "heldout_rms_before_deg": math.sqrt(nominal.score_mse),
                            "heldout_rms_after_deg": math.sqrt(j1.fit.score_mse),
                            "heldout_gain_ms": j1.gain.gain, "p_value": j1.gain.p_value,
                            "share_of_gap": j1.share, "at_bound": alone_hits}
        per_round = []
        for k, judged in enumerate(rounds):
            for j in judged:
                if j.name == n:
                    per_round.append({"round": k + 1, "with": [x for x in j.fit.names if x != n],
                                      "fitted": j.fit.values(), "heldout_rms_after_deg": math.sqrt(j.fit.score_mse),
                                      "heldout_gain_ms": j.gain.gain, "p_value": j.gain.p_value,
                                      "share_of_gap": j.share, "confidence": j.confidence})
        row["rounds"] = per_round
        row["at_bound"] = [h for h in hits if h["effect"] == n] if n in selected else row.get("alone", {}).get(
            "at_bound", [])
        if n in selected:
            row["fitted"] = final.values([n])[n]
            row["confidence"] = chosen_conf.get(n, 0.0)
            rnd = path.chosen_round.get(n)
            chosen = [r for r in per_round if r["round"] == rnd]
            if chosen:
                prev = math.sqrt(path.start_mse[rnd - 1]) if rnd - 1 < len(path.start_mse) else None
                row["chosen"] = {"round": rnd, "heldout_rms_before_deg": prev,
                                 "heldout_rms_after_deg": chosen[0]["heldout_rms_after_deg"],
                                 "p_value": chosen[0]["p_value"], "share_of_gap": chosen[0]["share_of_gap"]}
        else:
            row["fitted"] = j1.fit.values([n])[n] if j1 is not None else None
            row["confidence"] = max((r["confidence"] for r in per_round), default=0.0)
        out.append(row)
    return out


def _fmt_params(d: dict) -> str:
    return ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in d.items())


def _carry_note(carry: Carry | None, carried: dict | None, e_known: float) -> dict | None:
    """The report's reading of the transfer check, with the known error it leaves (None without a correction
    to check)."""
    if carry is None:
        return None
    out = {"nominal": carry.nominal.to_dict(), "short": carry.nominal.short, "raised_by_ms": 0.0,
           "known_error_deg": e_known}
    if carry.measured_ms > 0:
        out["already_measured_ms"] = carry.measured_ms
    if carried is not None:
        out |= {k: carried[k] for k in ("verdict", "raised_by_ms", "settled")}
    return out


def _check_note(model: ModelFile, noise: float, use_model_error: bool) -> dict | None:
    """The check log's part in the known error: its value and whether it set it, i.e. exceeds the bench's
    (None without a check)."""
    check = known_error_on_check(model.fit.extra, use_model_error and model.model_error is not None)
    if not math.isfinite(check):
        return None
    chk = model.fit.extra.get("check", {})
    return {"known_error_deg": check, "set_it": check > bench_known_error(model, noise, use_model_error),
            "log": chk.get("log")}


def summary_lines(rep: dict) -> list[str]:
    """A readable summary of a report, one line each."""
    lines = []
    where = rep["where"]
    sh = rep["shrinkage"]
    chk = rep.get("model_error_from_check")
    on_check = (", measured on its check log of another input" + (f" ({chk['log']})" if chk.get("log") else "")
                if chk and chk.get("set_it") else "")
    lines.append(f"residual RMS {where['rms_deg']:.4f} deg against a floor of {where['floor_deg']:.4f} deg "
                 f"(noise {rep['noise_deg']:.4f}, model's known error {rep['model_error_deg']:.4f}{on_check})")
    em = rep.get("model_error_model") or {}
    if em.get("used"):
        lines.append(f"bench model error: {em['bench_rms_before_deg']:.4f} deg RMS on the bench, "
                     f"{em['bench_rms_after_deg']:.4f} with its correction ({', '.join(em['feature_sets']) or 'none'})"
                     "; the field is judged against the corrected model")
    if where.get("dominant"):
        sc = where["scores"]
        parts = ", ".join(f"{k} {v:.0%}" for k, v in sorted(sc.items(), key=lambda kv: -kv[1]))
        lines.append(f"where: dominated by {where['dominant']} ({where['dominant_cell']}); "
                     f"share of the excess explained by: {parts}")
    else:
        lines.append("where: no excess over the floor")
    tw, ti = rep["tests"]["whiteness"], rep["tests"]["input_independence"]
    lines.append(f"residual tests: whiteness {'passed' if tw['passed'] else 'failed'} (p={tw['p_value'] or 0:.2g}), "
                 f"input independence {'passed' if ti['passed'] else 'failed'} (p={ti['p_value'] or 0:.2g})")
    for c in rep["candidates"]:
        if not c.get("tried"):
            lines.append(f"  {c['effect']:<11} not tried: {c['reason']}")
            continue
        a = c.get("alone") or {}
        mark = "*" if c["in_verdict"] else " "
        line = (f"{mark} {c['effect']:<11} alone: held-out RMS {a.get('heldout_rms_before_deg', math.nan):.4f} -> "
                f"{a.get('heldout_rms_after_deg', math.nan):.4f} deg, p={a.get('p_value', 1.0):.2g}, "
                f"{a.get('share_of_gap', 0.0):.0%} of the gap")
        ch = c.get("chosen")
        if ch and ch["round"] > 1:
            before = ch["heldout_rms_before_deg"]
            line += (f"; chosen in round {ch['round']}: "
                     + (f"{before:.4f} -> " if before is not None else "-> ")
                     + f"{ch['heldout_rms_after_deg']:.4f} deg, p={ch['p_value']:.2g}")
        line += f"; confidence {c['confidence']:.2f}; {_fmt_params(c['fitted'] or {})}"
        lines.append(line)
    for amb in rep["ambiguities"]:
        lines.append(f"ambiguous: {' / '.join(amb['equally_good'])} explain the log about equally; to separate them:")
        for h in amb["to_separate"]:
            lines.append(f"  {' vs '.join(h['effects'])}: {h['excitation']}")
    for d in rep["dropped"]:
        lines.append(f"dropped {d['effect']}: {d['reason']}")
    for h in rep.get("bound_hits", []):
        lines.append(f"at a bound: {h['meaning']}")
    verdict = rep["verdict"]
    if verdict:
        gc = sh["gap_closed"]
        lines.append(f"verdict: {', '.join(verdict)}; held-out RMS {sh['heldout_rms_before_deg']:.4f} -> "
                     f"{sh['heldout_rms_after_deg']:.4f} deg, gap closed "
                     + (f"{gc:.0%}" if gc is not None else "n/a"))
        nominal = rep.get("nominal_effects") or {}
        for n, p in rep["effects"].items():  # e.g. a field delay on top of the rig's own, which identify found
            was = nominal.get(n)
            lines.append(f"  {n}: {_fmt_params(p)}" + (f" (the model had {_fmt_params(was)})" if was else ""))
        for n, k in (rep.get("kept_unnamed") or {}).items():  # in the augmented model, as the note says
            lines.append(f"  kept in the model, not named: {n}: {_fmt_params(k['fitted'])}")
    else:
        lines.append("verdict: [] (no effect explains the gap beyond noise and the model's known error)")
    lines.extend(f"note: {n}" for n in rep["notes"])
    return lines
