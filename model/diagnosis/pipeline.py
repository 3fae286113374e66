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

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from warpbridge.model.diagnosis.left import left_over, left_over_note
from warpbridge.model.diagnosis.options import DiagnoseOptions
from warpbridge.model.diagnosis.problem import Split
from warpbridge.model.diagnosis.readings import (
    airspeed_note,
    bound_meaning,
    tension_band_notes,
    whole_loop_notes,
    widened_notes,
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
    rounds_along,
)
from warpbridge.model.diagnosis.sizing import WholeLogSizes
from warpbridge.model.diagnosis.start import bench_known_error, set_up
from warpbridge.model.diagnosis.stats import (
    input_independence,
    ljung_box,
    prewhiten,
)
from warpbridge.model.diagnosis.transfer import carry_check, decide_carried
from warpbridge.model.diagnosis.where import Cells, cells, gap_closed, split
from warpbridge.model.effects import (
    slack_side_name,
)
from warpbridge.model.modelfile import FitQuality, ModelFile

log = logging.getLogger(__name__)


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

    alt_raised: list[float] = []
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
            alt_raised.append(alt_carried.raised_by_ms if alt_carried else 0.0)
    sized = WholeLogSizes(prob, opt.max_evals, progress)
    sized.expect([path] + alt_paths)
    alternatives = [Alternative(decision=d, verdict=list(alt.named), floor_raised_by_ms=up,
                                kept_unnamed=sorted(alt.unnamed), heldout_rms_after_deg=math.sqrt(alt.fit.score_mse),
                                to_aero_load=[{"effect": b} | r.to_dict() for b, r in alt.to_load.items()],
                                effects={n: sized.of(alt).values([n])[n] for n in alt.named})
                    for d, alt, up in zip(opt.alternatives, alt_paths, alt_raised, strict=True)]
    raised = carried.raised_by_ms if carried is not None else 0.0
    e_known = math.sqrt(e_m ** 2 + raised)  # the known error the report judges by: raised where it did not carry
    if raised > 0:  # the rest of the report on the raised floor
        floor2 = floor2 + raised
        where = split(t, u, r0, cl, analysed, noise, e_known)
    selected = list(path.named)
    cur = path.fit
    rounds, ambiguities, chosen_conf = rounds_along(ex.at_floor(floor2), path, opt)
    w_aug = cur.w_pred if selected else w_nom
    r1 = w - w_aug

    shrink = split(t, u, r0, cl, sp.score, noise, e_known, r_after=r1)
    mse0, mse1 = prob.mse(w_nom, sp.score), prob.mse(w_aug, sp.score)
    shrinkage = Shrinkage(math.sqrt(mse0), math.sqrt(mse1), gap_closed(mse0, mse1, noise ** 2),
                          gap_closed(mse0, mse1, floor2),
                          {k: v for k, v in shrink.items() if k not in ("scores", "dominant", "dominant_cell")})
    whole = sized.of(path)  # the verdict's effects sized on every analysed sample; ``cur`` is the held-out one
    hits = whole.bound_hits() if selected else []
    for h in hits:
        h["meaning"] = bound_meaning(h)
        chosen_conf[h["effect"]] = chosen_conf.get(h["effect"], 0.0) * opt.bound_confidence
    cand = candidate_table(names, skipped, rounds, path, chosen_conf, cur, nominal, hits)
    notes = list(path.notes)
    if raised > 0:
        nom = carry.nominal
        notes.append(f"the bench's model-error correction does not carry to this log: it lowers the squared error "
                     f"by {nom.bench_gain:.2g} deg^2 on the bench but {nom.field_gain:.2g} here "
                     f"(p={nom.p_value:.2g}); the part it did not carry is model error the bench could not see, "
                     f"so the known error is taken as {e_known:.3f} deg "
                     f"instead of {e_m:.3f} (a second bench log of another realisation of the input measures "
                     f"it: identify --check)")
        if not carried.settled:
            notes.append("the raise did not settle: the verdict asks for a different raise than the one it was "
                         "decided at, and the lower raise gives another verdict; the verdict of the higher one is "
                         "kept (the stricter floor)")
    for h in hits:
        notes.append(h["meaning"])
    notes += widened_notes(cur, selected)
    by_airspeed = [{"effect": b} | r.to_dict() for b, r in path.kept_by_airspeed.items()]
    notes += tension_band_notes(selected, airspeed_checked=bool(by_airspeed))
    if "friction" not in path.unnamed:  # else the kept friction's note gives the band's whole factor
        notes += whole_loop_notes(selected, cur.effects)
    notes += [airspeed_note(b, r) for b, r in path.kept_by_airspeed.items()]
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
    report = Report(
        verdict=list(selected), effects={n: whole.values([n])[n] for n in selected},
        effects_on_training_blocks={n: cur.values([n])[n] for n in selected},
        samples=int(t.size), duration_s=float(t[-1] - t[0]),
        noise_deg=noise, model_error_deg=e_m, floor_deg=math.sqrt(floor2),
        model_error_from_check=check_note(model, noise, opt.use_model_error),
        model_error_carried=carry_note(carry, carried, e_known),
        decision=opt.decision,
        initial_state=InitialState(z0, slack_taken_up_by=slack_side_name(side) if model.effects.has_slack else None),
        model_error_model=em_summary(model.model_error, em is not None),
        residual_is_noise=residual_is_noise,
        tests=Tests(white, indep),
        where=where, candidates=cand, bound_hits=hits, ambiguities=ambiguities, dropped=path.dropped,
        kept_unnamed={n: {"fitted": whole.values([n])[n]} | v.to_dict() for n, v in path.unnamed.items()},
        band_gain_by_airspeed=by_airspeed, shrinkage=shrinkage, left_over=left, alternatives=alternatives,
        split=SplitInfo([b + 1 for b in sp.pattern], sp.start, int(sp.train.sum()), int(sp.score.sum()),
                        int(sp.chunks.max() + 1)),
        nominal_effects=base.to_dict(), notes=notes, model_evaluations=prob.evaluations)
    return Diagnosis(list(selected), report.to_dict(), augmented, t, u, w, w_nom, w_aug, sp, cl, report)
