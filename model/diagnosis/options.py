"""What the diagnosis decides by: the decision that names an effect, and every other number of its policy,
each in one place with what it trades off."""

from __future__ import annotations

from dataclasses import dataclass, field


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


# a small grid around the default, for ``alternatives`` (how the verdict depends on the decision)
DECISION_GRID: tuple[Decision, ...] = tuple(
    Decision(a, s, g, p, m) for m in (0.0, 0.03) for p in (False, True) for a in (0.001, 0.01, 0.05)
    for s in (0.1, 0.25, 0.5) for g in (0.25, 0.5, 1.0, 2.0))


@dataclass(frozen=True)
class DiagnoseOptions:
    """The diagnosis's settings: the search, the decision and the policy numbers of its readings. The
    decision's defaults are statistical conventions checked leave-one-family-out; the rest were set on the
    blind benchmark's plant families and are not chosen per fold."""

    # ---- what is searched
    max_effects: int = 3  # effects a verdict names at most: more explains more and costs a round each
    effects: tuple[str, ...] | None = None  # the candidates (None: every registered one, ``candidates()``)
    use_model_error: bool = True  # apply the model-error model MODEL.json carries, if any
    # ---- the search (more: a better search, slower)
    max_evals: int = 120  # Nelder-Mead evaluations per joint fit
    joint_refits: int = 2  # candidates per round refitted jointly with the effects already chosen
    # a round-1 candidate that alone closes this share of the nominal's training gap is refitted in round 2 from
    # its own fit too (the reverse refit): lower finds pairs a screen ranked low, at a joint fit each
    alone_share: float = 0.1
    # the first round's candidates (largest held-out gain first) that each lead a pair entering together
    # (``enter_together``) when no effect passes alone: more pairs tried, a round each
    together_leads: int = 3
    workers: int = 1  # processes fitting a round's candidates side by side (the verdict does not depend on it)
    # ---- the decision (chosen leave-one-family-out; ``alternatives`` reports others beside it)
    decision: Decision = field(default_factory=Decision)
    alternatives: tuple[Decision, ...] = ()  # also report the verdict each of these decisions gives
    # a runner-up not worse than the winner at this level is an equal explanation: higher calls fewer ties
    ambiguity_alpha: float = 0.05
    # the first round's runner-up gets a second round of its own (a beam of two) only when it gains at least
    # this share of the winner's gain: lower tries more beams, at a round each
    runner_up_gain: float = 0.5
    # ---- the physical re-readings
    # a capstan stall growing less than this across the log's travel is taken for a fixed play when the held-out
    # test cannot tell them apart (``stall_as_play``): its zero more than the travel's span below the travel.
    # Higher names a backlash for more stalls
    stall_as_play_growth: float = 2.0
    # an effect beside an aero load is split by airspeed (``gain_by_airspeed``) only with at least this many
    # flown scored samples and the fast third's dynamic pressure at least ``load_spread`` x the slow third's:
    # lower reads the load's share on thinner evidence
    load_min_samples: int = 30
    load_spread: float = 1.5
    # ---- the floor transfer
    # level of the one-sided test that the field shows less of the bench correction's gain: higher raises the
    # floor on weaker evidence (fewer effects named where the bench's correction does not carry)
    transfer_alpha: float = 0.001
    carry_rounds: int = 4  # decisions re-made at most, each with the floor raised by what the correction did not carry
    # ---- the report
    bound_confidence: float = 0.5  # confidence factor of an effect whose fitted parameter sits at a bound of its search
