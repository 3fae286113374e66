"""The report: the rounds along the chosen path with confidences and ambiguities, the candidate table and
the readings of the known error's sources."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from warpbridge.model.diagnosis.check import known_error_on_check
from warpbridge.model.diagnosis.left import LeftOver, left_over_note
from warpbridge.model.diagnosis.options import Decision, DiagnoseOptions
from warpbridge.model.diagnosis.problem import BoundHit, Fit
from warpbridge.model.diagnosis.readings import (
    airspeed_note,
    read_bounds,
    tension_band_notes,
    whole_loop_notes,
    widened_notes,
)
from warpbridge.model.diagnosis.records import Record
from warpbridge.model.diagnosis.search import Explorer, Judged
from warpbridge.model.diagnosis.selection import Dropped, Path
from warpbridge.model.diagnosis.start import bench_known_error
from warpbridge.model.diagnosis.stats import TestResult
from warpbridge.model.diagnosis.summary import summary_lines
from warpbridge.model.diagnosis.transfer import Carried, Carry, Transfer
from warpbridge.model.diagnosis.where import ResidualSplit
from warpbridge.model.effect_registry import EFFECT_FIELDS, SEPARATE
from warpbridge.model.model_error import ErrorModel
from warpbridge.model.modelfile import ModelFile

REPORT_FORMAT = "warpbridge-diagnosis/1"

# what separates two effects that explain a log about equally well when the registry names nothing closer
DEFAULT_SEPARATE = ("a richer excitation: a random input with sharper reversals at several amplitudes and speeds, "
                    "holds, and (for airspeed effects) a varying airspeed")


@dataclass(frozen=True)
class ErrorModelSummary(Record):
    """The model-error model MODEL.json carries (``present``) and whether the diagnosis applied it."""

    OPTIONAL = ("feature_sets", "bench_rms_before_deg", "bench_rms_after_deg", "known_error_deg")
    present: bool
    used: bool
    feature_sets: list[str] | None = None
    bench_rms_before_deg: float | None = None
    bench_rms_after_deg: float | None = None
    known_error_deg: float | None = None


@dataclass(frozen=True)
class CheckNote(Record):
    """The check log's part in the known error: its value, whether it set it, and the log's name."""

    known_error_deg: float
    set_it: bool
    log: str | None


@dataclass(frozen=True, kw_only=True)
class CarryNote(Record):
    """The transfer check of the bench's model-error correction, and the known error it leaves."""

    OPTIONAL = ("already_measured_ms", "verdict", "settled")
    nominal: Transfer
    short: bool
    raised_by_ms: float
    known_error_deg: float
    already_measured_ms: float | None = None
    verdict: Transfer | None = None
    settled: bool | None = None


INITIAL_STATE_METHOD = ("estimated from the log's opening stretch (algebraic start, clamped to the reachable band, "
                        "refined on the prediction error)")


@dataclass(frozen=True)
class InitialState(Record):
    """The hysteretic state at the log's first sample, and where a play's slack was taken up."""

    OPTIONAL = ("slack_taken_up_by",)
    z0: float
    method: str = INITIAL_STATE_METHOD
    slack_taken_up_by: str | None = None


@dataclass(frozen=True)
class Tests(Record):
    """The residual tests of the nominal model."""

    whiteness: TestResult
    input_independence: TestResult


@dataclass(frozen=True)
class CandidateAlone(Record):
    """A candidate fitted alone in round 1."""

    fitted: dict
    heldout_rms_before_deg: float
    heldout_rms_after_deg: float
    heldout_gain_ms: float
    p_value: float
    share_of_gap: float
    at_bound: list[BoundHit]


@dataclass(frozen=True)
class CandidateRound(Record):
    """A candidate in one round of the chosen path, fitted with the effects chosen before it."""

    KEYS = {"with_": "with"}
    round: int
    with_: list[str]
    fitted: dict
    heldout_rms_after_deg: float
    heldout_gain_ms: float
    p_value: float
    share_of_gap: float
    confidence: float


@dataclass(frozen=True)
class CandidateChosen(Record):
    """The round a named effect was chosen in and what it did there."""

    round: int
    heldout_rms_before_deg: float | None
    heldout_rms_after_deg: float
    p_value: float
    share_of_gap: float


@dataclass(frozen=True, kw_only=True)
class Candidate(Record):
    """One candidate of the vocabulary: skipped (``reason``), or tried, alone and along the chosen path."""

    OPTIONAL = ("reason", "alone", "chosen")
    effect: str
    parameters: list[str]
    in_verdict: bool
    tried: bool
    reason: str | None = None
    alone: CandidateAlone | None = None
    rounds: list[CandidateRound] = field(default_factory=list)
    at_bound: list[BoundHit] = field(default_factory=list)
    fitted: dict | None = None
    confidence: float = 0.0
    chosen: CandidateChosen | None = None

    def to_dict(self) -> dict:
        if self.tried:
            return super().to_dict()
        return {"effect": self.effect, "parameters": self.parameters, "in_verdict": self.in_verdict,
                "tried": False, "reason": self.reason, "confidence": self.confidence}


@dataclass(frozen=True)
class Separation(Record):
    """The excitation that tells two equally good explanations apart."""

    effects: list[str]
    excitation: str


@dataclass(frozen=True)
class Ambiguity(Record):
    """Candidates of one round the held-out test cannot tell from the one chosen."""

    round: int
    chosen: str
    equally_good: list[str]
    heldout_rms_deg: dict[str, float]
    to_separate: list[Separation]


@dataclass(frozen=True, kw_only=True)
class Alternative(Record):
    """The verdict another decision gives on the same search."""

    decision: Decision
    verdict: list[str]
    floor_raised_by_ms: float
    kept_unnamed: list[str]
    heldout_rms_after_deg: float
    to_aero_load: list[dict]
    effects: dict


@dataclass(frozen=True)
class Shrinkage(Record):
    """How far the verdict closes the gap on the scored blocks, overall and in every cell."""

    heldout_rms_before_deg: float
    heldout_rms_after_deg: float
    gap_closed: float | None
    gap_closed_beyond_model_error: float | None
    where: ResidualSplit


SPLIT_SCHEME = ("10 blocks, 4 scored (2, 5, 7, 10 unless the two where the command moves fastest would then be on "
                "the same side)")


@dataclass(frozen=True)
class SplitInfo(Record):
    """The training and scored blocks."""

    scored_blocks: list[int]
    warmup_samples: int
    train_samples: int
    score_samples: int
    score_chunks: int
    scheme: str = SPLIT_SCHEME

    def to_dict(self) -> dict:
        return {"scheme": self.scheme} | {k: v for k, v in super().to_dict().items() if k != "scheme"}


EFFECTS_SIZED_ON = ("every analysed sample (training and scored blocks), once the scored blocks had chosen them; "
                    "`effects_on_training_blocks` are the sizes the held-out figures are of")


@dataclass(frozen=True, kw_only=True)
class Report(Record):
    """REPORT.json as a tree of records (docs/report-format.md, field by field); ``to_dict`` adds the text
    summary."""

    format: str = REPORT_FORMAT
    verdict: list[str]
    effects: dict
    effects_sized_on: str = EFFECTS_SIZED_ON
    effects_on_training_blocks: dict
    samples: int
    duration_s: float
    noise_deg: float
    model_error_deg: float
    floor_deg: float
    model_error_from_check: CheckNote | None
    model_error_carried: CarryNote | None
    decision: Decision
    initial_state: InitialState
    model_error_model: ErrorModelSummary
    residual_is_noise: bool
    tests: Tests
    where: ResidualSplit
    candidates: list[Candidate]
    bound_hits: list[BoundHit]
    ambiguities: list[Ambiguity]
    dropped: list[Dropped]
    kept_unnamed: dict
    band_gain_by_airspeed: list[dict]
    shrinkage: Shrinkage
    left_over: LeftOver | None
    alternatives: list[Alternative]
    split: SplitInfo
    nominal_effects: dict
    notes: list[str]
    model_evaluations: int

    def to_dict(self) -> dict:
        out = super().to_dict()
        out["summary"] = summary_lines(out)
        return out


def em_summary(em: ErrorModel | None, used: bool) -> ErrorModelSummary:
    if em is None:
        return ErrorModelSummary(False, False)
    return ErrorModelSummary(True, used, list(em.sets), em.rms_before_deg, em.rms_after_deg, em.known_error_deg)


def rounds_along(ex: Explorer, path: Path, opt: DiagnoseOptions) -> tuple[list[list[Judged]], list[Ambiguity], dict]:
    """The rounds along the chosen path as ``ex``'s floor judges them (copies of the explored ones), with
    ambiguities and the chosen effects' confidences."""
    d = opt.decision
    rounds: list[list[Judged]] = []
    ambiguities: list[Ambiguity] = []
    chosen_conf: dict[str, float] = {}
    order = sorted(path.chosen_round, key=path.chosen_round.get)
    prefixes = [tuple(order[:k]) for k in range(len(order) + 1)]
    for k, pre in enumerate(prefixes):
        if pre not in ex.rounds_done:
            break
        cur = ex.fit_of(pre) if pre else ex.nominal
        # the round's candidates as this floor judges them (the round may have been explored on another), in
        # copies: the explored round stays as it was
        judged = [replace(j, confidence=0.0, ambiguous_with_best=False, share=ex.share(cur, j.gain.gain))
                  for j in ex.rounds_done[pre]]
        rounds.append(judged)
        # an effect given to the aero load is the load's: not a candidate of its own, nor a rival
        acc = [j for j in judged if ex.admits(d, cur, j.fit, j.gain) and j.name not in path.to_load]
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


def _ambiguity(best: Judged, alts: list[Judged], rnd: int) -> Ambiguity:
    how = [Separation([best.name, a.name], SEPARATE.get(frozenset({best.name, a.name}), DEFAULT_SEPARATE))
           for a in alts]
    return Ambiguity(rnd, best.name, [best.name] + [a.name for a in alts],
                     {j.name: math.sqrt(j.fit.score_mse) for j in [best, *alts]}, how)


def candidate_table(names, skipped, rounds: list[list[Judged]], path: Path, chosen_conf: dict[str, float],
                    final: Fit, nominal: Fit, hits: list[BoundHit]) -> list[Candidate]:
    """Every candidate of the vocabulary: the skipped ones with why, the tried ones alone (round 1), in each
    round of the chosen path, and, when named, the round it was chosen in."""
    out = []
    selected = path.named
    first = {j.name: j for j in rounds[0]} if rounds else {}
    for n in list(names) + list(skipped):
        params, named = list(EFFECT_FIELDS[n][0]), n in selected
        if n in skipped:
            out.append(Candidate(effect=n, parameters=params, in_verdict=named, tried=False, reason=skipped[n]))
            continue
        j1 = first.get(n)
        alone = None
        if j1 is not None:
            alone_hits = read_bounds(j1.fit.bound_hits())
            alone = CandidateAlone(j1.fit.values([n])[n], math.sqrt(nominal.score_mse), math.sqrt(j1.fit.score_mse),
                                   j1.gain.gain, j1.gain.p_value, j1.share, alone_hits)
        per_round = [CandidateRound(k + 1, [x for x in j.fit.names if x != n], j.fit.values(),
                                    math.sqrt(j.fit.score_mse), j.gain.gain, j.gain.p_value, j.share, j.confidence)
                     for k, judged in enumerate(rounds) for j in judged if j.name == n]
        chosen = None
        if named:
            at_bound = [h for h in hits if h.effect == n]
            fitted, confidence = final.values([n])[n], chosen_conf.get(n, 0.0)
            rnd = path.chosen_round.get(n)
            this = [r for r in per_round if r.round == rnd]
            if this:
                prev = math.sqrt(path.start_mse[rnd - 1]) if rnd - 1 < len(path.start_mse) else None
                chosen = CandidateChosen(rnd, prev, this[0].heldout_rms_after_deg, this[0].p_value,
                                         this[0].share_of_gap)
        else:
            at_bound = alone.at_bound if alone is not None else []
            fitted = j1.fit.values([n])[n] if j1 is not None else None
            confidence = max((r.confidence for r in per_round), default=0.0)
        out.append(Candidate(effect=n, parameters=params, in_verdict=named, tried=True, alone=alone, rounds=per_round,
                             at_bound=at_bound, fitted=fitted, confidence=confidence, chosen=chosen))
    return out


def carry_note(carry: Carry | None, carried: Carried | None, e_known: float) -> CarryNote | None:
    """The report's reading of the transfer check, with the known error it leaves (None without a correction
    to check)."""
    if carry is None:
        return None
    measured = carry.measured_ms if carry.measured_ms > 0 else None
    if carried is None:
        return CarryNote(nominal=carry.nominal, short=carry.nominal.short, raised_by_ms=0.0, known_error_deg=e_known,
                         already_measured_ms=measured)
    return CarryNote(nominal=carry.nominal, short=carry.nominal.short, raised_by_ms=carried.raised_by_ms,
                     known_error_deg=e_known, already_measured_ms=measured, verdict=carried.verdict,
                     settled=carried.settled)


def check_note(model: ModelFile, noise: float, use_model_error: bool) -> CheckNote | None:
    """The check log's part in the known error: its value and whether it set it, i.e. exceeds the bench's
    (None without a check)."""
    check = known_error_on_check(model.fit.extra, use_model_error and model.model_error is not None)
    if not math.isfinite(check):
        return None
    chk = model.fit.extra.get("check", {})
    return CheckNote(check, check > bench_known_error(model, noise, use_model_error), chk.get("log"))


def report_notes(path: Path, carry: Carry | None, carried: Carried | None, e_m: float, e_known: float,
                 hits: list[BoundHit], fit: Fit, left: LeftOver | None, residual_is_noise: bool) -> list[str]:
    """The report's notes, in order: the selection's own, the floor transfer's, the search edges', the
    widened searches', the tension and load readings', what is left over, and a residual no effect explains."""
    selected = list(path.named)
    notes = list(path.notes)
    if carried is not None and carried.raised_by_ms > 0:
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
    notes += [h.meaning for h in hits]
    notes += widened_notes(fit, selected)
    notes += tension_band_notes(selected, airspeed_checked=bool(path.kept_by_airspeed))
    if "friction" not in path.unnamed:  # else the kept friction's note gives the band's whole factor
        notes += whole_loop_notes(selected, fit.effects)
    notes += [airspeed_note(b, r) for b, r in path.kept_by_airspeed.items()]
    if (left_note := left_over_note(left, bool(selected))) is not None:
        notes.append(left_note)
    if not selected and not residual_is_noise:
        notes.append("the residual is structured but no effect explains a significant, material share of it: "
                     "it is the model's own error (re-identify on a richer log, or diagnose a longer one)")
    return notes
