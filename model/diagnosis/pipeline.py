"""Diagnosis of the gap between a model and a log: where it is, which effect explains it, how far.

0. **Start.** The hysteretic state at the log's first sample is estimated
   from its opening stretch (``model.initial_state``, with the model's effects
   and error correction), not assumed at rest; so is, for every candidate with
   a play (backlash, capstan stall), the edge its slack starts on (a log may
   open just after a release: ``problem.Problem.input_path``). When MODEL.json carries a
   model-error model (``model.model_error``: what the nominal model got wrong
   on the bench, as a function of warp level, direction, travel since the
   last reversal and rate), its correction is part of the nominal prediction,
   and what it still gets wrong on the bench is the model's known error.
1. **Where.** The corrected model (with the effects it already carries) is
   free-run on the logged tendon input; the residual is split by hysteresis
   phase, warp level, frequency band, time and airspeed
   (``model.diagnosis.where``) against the floor it should reach: the noise
   estimated from the log's second differences plus the model's known error,
   so a model that never fitted perfectly is not blamed on a new effect.
2. **Which.** Every effect of the vocabulary is fitted as an augmentation
   (``model.diagnosis.problem``) on alternating training blocks of the log and scored
   on the blocks in between (the two blocks where the command moves fastest
   fall one on each side: a slew limit or a delay that shows only there is
   both fitted and tested). Greedy forward selection: a round fits every
   remaining effect jointly with those already chosen and takes the best by a
   penalised held-out criterion (effective samples x log MSE + 2 per extra
   parameter) among those one test admits (``Decision``): a held-out gain
   significant in a forecast-encompassing test (``stats.paired_gain``,
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
   ended (``problem.Problem.refit_whole``): the report's effects and the
   augmented model carry these, as a model chosen by cross-validation is
   refitted on all of its data; the held-out figures of step 3 stay those of
   the training fit (``effects_on_training_blocks``).

No I/O: ``diagnose`` returns a ``Diagnosis`` with the report (a JSON-ready
dict), the augmented ``ModelFile`` and the residual series for plotting;
progress goes to an optional callback.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from warpbridge.model.diagnosis.blocks import Split
from warpbridge.model.diagnosis.left import left_over
from warpbridge.model.diagnosis.options import Decision, DiagnoseOptions
from warpbridge.model.diagnosis.readings import (
    read_bounds,
)
from warpbridge.model.diagnosis.report import (
    Alternative,
    InitialState,
    Report,
    Shrinkage,
    SplitInfo,
    Tests,
    candidate_table,
    carry_note,
    check_note,
    em_summary,
    report_notes,
    rounds_along,
)
from warpbridge.model.diagnosis.selection import Path
from warpbridge.model.diagnosis.sizing import WholeLogSizes
from warpbridge.model.diagnosis.start import Setup, bench_known_error, set_up
from warpbridge.model.diagnosis.stats import (
    TestResult,
    input_independence,
    ljung_box,
    prewhiten,
)
from warpbridge.model.diagnosis.transfer import Carried, Carry, carry_check, decide_carried
from warpbridge.model.diagnosis.where import Cells, ResidualSplit, cells, gap_closed, split
from warpbridge.model.effects import (
    Effects,
    slack_side_name,
)
from warpbridge.model.modelfile import FitQuality, ModelFile


@dataclass
class Diagnosis:
    """What ``diagnose`` found: the report (REPORT.json's dict, and ``records``, the tree it is written
    from), the augmented model and series for plots."""

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
    records: Report | None = field(default=None, repr=False)  # the report as its tree of records


@dataclass(frozen=True)
class Gap:
    """Where the nominal model's gap lies (stage 1): the residual split over the cells against the bench's
    floor, and the residual tests."""

    cells: Cells
    residual: np.ndarray = field(repr=False)  # measured less the nominal's prediction, deg
    analysed: np.ndarray = field(repr=False)  # the training and scored samples
    where: ResidualSplit
    whiteness: TestResult
    input_independence: TestResult


def where_it_lies(su: Setup, airspeed) -> Gap:
    """Stage 1: the nominal's residual split by phase, level, band, time and airspeed, and tested."""
    prob, nominal = su.prob, su.ex.nominal
    r0 = prob.w - nominal.w_pred
    analysed = prob.split.train | prob.split.score
    cl = cells(prob.t, prob.u, nominal.w_pred, airspeed)
    ra = r0[analysed]
    return Gap(cl, r0, analysed, split(prob.t, prob.u, r0, cl, analysed, su.noise, su.e_m), ljung_box(ra),
               input_independence(prewhiten(prob.u[analysed]), ra[1:]))


@dataclass(frozen=True)
class Decided:
    """Stages 2 and 3: the verdict's path and each alternative decision's, with what the floor transfer
    raised for them, and every distinct verdict sized on the whole log."""

    carry: Carry | None
    path: Path
    carried: Carried | None
    alternatives: list[tuple[Decision, Path, float]]  # (decision, its path, the floor it raised, deg^2)
    sized: WholeLogSizes

    @property
    def raised(self) -> float:
        return self.carried.raised_by_ms if self.carried is not None else 0.0


def decide_all(su: Setup, model: ModelFile, opt: DiagnoseOptions, progress) -> Decided:
    """The search and the selection under the decision and each alternative, with the floor transfer (a
    check log's measured error counts against the shortfall), then the verdicts sized on every sample."""
    ex = su.ex
    measured = su.e_m ** 2 - bench_known_error(model, su.noise, opt.use_model_error) ** 2
    carry = carry_check(ex, su.error_model, su.slack_side, measured)
    alternatives = []
    with ex.workers():
        path, carried = decide_carried(ex, opt.decision, opt.max_effects, carry)
        for k, d in enumerate(opt.alternatives):
            if progress:
                progress("alternative decisions", k, len(opt.alternatives))
            alt, alt_carried = (path, carried) if d == opt.decision else decide_carried(ex, d, opt.max_effects, carry)
            alternatives.append((d, alt, alt_carried.raised_by_ms if alt_carried else 0.0))
    sized = WholeLogSizes(su.prob, opt.max_evals, progress)
    sized.expect([path] + [alt for _, alt, _ in alternatives])
    return Decided(carry, path, carried, alternatives, sized)


def alternatives_of(decided: Decided) -> list[Alternative]:
    """The report's verdict under each alternative decision."""
    return [Alternative(decision=d, verdict=list(alt.named), floor_raised_by_ms=up, kept_unnamed=sorted(alt.unnamed),
                        heldout_rms_after_deg=math.sqrt(alt.fit.score_mse),
                        to_aero_load=[{"effect": b} | r.to_dict() for b, r in alt.to_load.items()],
                        effects={n: decided.sized.of(alt).values([n])[n] for n in alt.named})
            for d, alt, up in decided.alternatives]


def augmented_model(model: ModelFile, effects: Effects, selected: list[str], train_rms: float, heldout_rms: float,
                    nominal_rms: float, noise: float) -> ModelFile:
    """MODEL.json of the nominal model with the verdict's effects, and how it fits the log."""
    extra = {"method": "warpbridge diagnose", "verdict": list(selected), "nominal_heldout_rms_deg": nominal_rms}
    if "travel_mm" in model.fit.extra:  # the nominal's parameters were identified there, whatever the effects add
        extra["travel_mm"] = model.fit.extra["travel_mm"]
    fitq = FitQuality(train_rms_deg=train_rms, heldout_rms_deg=heldout_rms, noise_deg=noise, extra=extra)
    meta = dict(model.meta)
    meta["augmented_by"] = "warpbridge diagnose"
    meta["verdict"] = list(selected)
    return ModelFile(params=model.params, effects=effects, z0=model.z0, fit=fitq, meta=meta,
                     model_error=model.model_error)


def diagnose(t, u, w, airspeed, model: ModelFile, options: DiagnoseOptions | None = None,
             progress: Callable[[str, int, int], None] | None = None) -> Diagnosis:
    """Diagnose the gap between ``model`` and a cleaned log (t s increasing, u mm, w deg, airspeed m/s or None).

    ``progress(stage, i, n)`` is called as the work advances (no I/O here)."""
    opt = options or DiagnoseOptions()
    su = set_up(t, u, w, airspeed, model, opt, progress)  # stage 0
    prob, ex, noise, e_m = su.prob, su.ex, su.noise, su.e_m
    t, u, w, sp, nominal = prob.t, prob.u, prob.w, prob.split, ex.nominal
    gap = where_it_lies(su, airspeed)  # stage 1
    decided = decide_all(su, model, opt, progress)  # stages 2-4
    path, carried, raised = decided.path, decided.carried, decided.raised
    alternatives = alternatives_of(decided)
    # the known error the report judges by: raised where the bench's correction did not carry, and the rest of
    # the report on that floor
    e_known = math.sqrt(e_m ** 2 + raised)
    floor2 = ex.floor2 + raised
    where = split(t, u, gap.residual, gap.cells, gap.analysed, noise, e_known) if raised > 0 else gap.where
    selected = list(path.named)
    cur = path.fit
    rounds, ambiguities, chosen_conf = rounds_along(ex.at_floor(floor2), path, opt)
    w_aug = cur.w_pred if selected else nominal.w_pred
    r1 = w - w_aug
    shrink = split(t, u, gap.residual, gap.cells, sp.score, noise, e_known, r_after=r1)
    mse0, mse1 = prob.mse(nominal.w_pred, sp.score), prob.mse(w_aug, sp.score)
    shrinkage = Shrinkage(math.sqrt(mse0), math.sqrt(mse1), gap_closed(mse0, mse1, noise ** 2),
                          gap_closed(mse0, mse1, floor2),
                          shrink.cells_only())
    whole = decided.sized.of(path)  # the verdict's effects sized on every analysed sample; ``cur``: held-out
    hits = read_bounds(whole.bound_hits()) if selected else []
    for h in hits:
        chosen_conf[h.effect] = chosen_conf.get(h.effect, 0.0) * opt.bound_confidence
    cand = candidate_table(ex.names, su.skipped, rounds, path, chosen_conf, cur, nominal, hits)
    left = left_over(t, u, r1, sp, floor2, opt.decision.min_gain, airspeed)  # stage 5
    residual_is_noise = gap.whiteness.passed and gap.input_independence.passed
    notes = report_notes(path, decided.carry, carried, e_m, e_known, hits, cur, left, residual_is_noise)
    augmented = augmented_model(model, whole.effects if selected else ex.base, selected,
                                math.sqrt(prob.mse(w_aug, sp.train)), math.sqrt(mse1), math.sqrt(mse0), noise)
    report = Report(
        verdict=list(selected), effects={n: whole.values([n])[n] for n in selected},
        effects_on_training_blocks={n: cur.values([n])[n] for n in selected},
        samples=int(t.size), duration_s=float(t[-1] - t[0]),
        noise_deg=noise, model_error_deg=e_m, floor_deg=math.sqrt(floor2),
        model_error_from_check=check_note(model, noise, opt.use_model_error),
        model_error_carried=carry_note(decided.carry, carried, e_known),
        decision=opt.decision,
        initial_state=InitialState(su.z0, slack_taken_up_by=slack_side_name(su.slack_side)
                                   if model.effects.has_slack else None),
        model_error_model=em_summary(model.model_error, su.error_model is not None),
        residual_is_noise=residual_is_noise,
        tests=Tests(gap.whiteness, gap.input_independence),
        where=where, candidates=cand, bound_hits=hits, ambiguities=ambiguities, dropped=path.dropped,
        kept_unnamed={n: {"fitted": whole.values([n])[n]} | v.to_dict() for n, v in path.unnamed.items()},
        band_gain_by_airspeed=[{"effect": b} | r.to_dict() for b, r in path.kept_by_airspeed.items()],
        shrinkage=shrinkage, left_over=left, alternatives=alternatives,
        split=SplitInfo([b + 1 for b in sp.pattern], sp.start, int(sp.train.sum()), int(sp.score.sum()),
                        int(sp.chunks.max() + 1)),
        nominal_effects=ex.base.to_dict(), notes=notes, model_evaluations=prob.evaluations)
    return Diagnosis(list(selected), report.to_dict(), augmented, t, u, w, nominal.w_pred, w_aug, sp, gap.cells,
                     report)
