"""The candidate search: every effect of the vocabulary fitted as an augmentation, round by round, each fit
computed once and judged against the model its round starts from."""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Hashable
from concurrent.futures import as_completed
from contextlib import contextmanager
from dataclasses import dataclass, replace

from warpbridge.model.diagnosis.options import Decision, DiagnoseOptions
from warpbridge.model.diagnosis.pool import FitPool
from warpbridge.model.diagnosis.problem import Fit, Problem
from warpbridge.model.diagnosis.stats import (
    PairedGain,
    effective_n,
    paired_gain,
)
from warpbridge.model.effect_registry import EFFECT_FIELDS, LATENCY_FIELDS
from warpbridge.model.effects import Effects


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
    return eff.with_values(**{f: getattr(base, f) for f in EFFECT_FIELDS[name][0]})


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

    def at_floor(self, floor2: float) -> Explorer:
        """This explorer judging against the floor ``floor2`` (deg^2) instead: its fits and rounds are shared
        (they do not depend on the floor), this one is left as it is."""
        view = copy.copy(self)
        view.floor2 = floor2
        return view

    @contextmanager
    def workers(self):
        """Fit on ``opt.workers`` worker processes inside this block (``pool``; threads where processes
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
                     and self.nominal.train_mse - self.fits[(c,)].train_mse >= self.opt.alone_share * gap]
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
