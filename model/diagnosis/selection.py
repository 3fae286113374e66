"""The selection: what one decision makes of the explored rounds (greedy forward selection with a beam of
two, a pair entering together, a backward pass with the same test, a joint refit)."""

from __future__ import annotations

from dataclasses import dataclass, field

from warpbridge.model.diagnosis.options import Decision
from warpbridge.model.diagnosis.problem import Fit
from warpbridge.model.diagnosis.readings import (
    LoadSplit,
    TensionBand,
    ViscousLag,
    gain_by_airspeed,
    grows_with_load,
    load_ratio_text,
    stall_as_play,
    tension_band,
    viscous_lag,
)
from warpbridge.model.diagnosis.records import Record
from warpbridge.model.diagnosis.search import Explorer, Judged
from warpbridge.model.diagnosis.stats import (
    PairedGain,
)
from warpbridge.model.effect_registry import BOUND_HINTS, LOAD_COUPLED, LOAD_EFFECT


@dataclass(frozen=True, kw_only=True)
class Dropped(Record):
    """An effect chosen and dropped again, and why: by the backward pass (its gain when kept), to the aero load
    (its gain by airspeed), or left alone of a pair."""

    OPTIONAL = ("gain_ms_when_kept", "p_value", "share_when_kept", "gain_by_airspeed")
    effect: str
    gain_ms_when_kept: float | None = None
    p_value: float | None = None
    share_when_kept: float | None = None
    reason: str
    gain_by_airspeed: LoadSplit | None = None


@dataclass
class Path:
    """What one decision makes of the explored rounds."""

    selected: tuple[str, ...]
    fit: Fit
    chosen_round: dict[str, int]
    chosen_from: dict[str, Fit]  # the fit each chosen effect was judged against
    start_mse: list[float]
    dropped: list[Dropped]
    notes: list[str]
    together: dict[str, PairedGain] = field(default_factory=dict)  # the first of a pair that entered together:
    # its test given the second
    from_runner_up: bool = False  # round 2 went on from the first round's runner-up
    to_load: dict[str, LoadSplit] = field(default_factory=dict)  # effects given to the aero load: their airspeed split
    kept_by_airspeed: dict[str, LoadSplit] = field(default_factory=dict)  # named beside the load: their split
    # chosen and kept in the model as another effect's part
    unnamed: dict[str, ViscousLag | TensionBand] = field(default_factory=dict)

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
            play_note = play.reason
            best = play.judged
        if rnd == 0:
            # the runner-up gets a second round of its own only when it explains nearly as much (at least half
            # the winner's gain): only then can the winner be imitating it together with another effect
            others = sorted((j for j in acc if j is not best and j.gain.gain >= ex.opt.runner_up_gain * best.gain.gain),
                            key=lambda j: -j.penalised)
            runner_up = others[0] if others else None
        chosen_from[best.name] = cur
        chosen_round[best.name] = len(sel) + 1
        sel = sel + (best.name,)
        cur = best.fit
    dropped: list[Dropped] = []
    changed = True
    while changed and len(sel) >= 2:
        changed = False
        ex.prefetch_without(sel, cur)
        for s in sel:
            f = ex.without(sel, s, cur)
            g = ex.gain(f, cur)
            if not ex.admits(d, f, cur, g):
                dropped.append(Dropped(effect=s, gain_ms_when_kept=g.gain, p_value=g.p_value,
                                       share_when_kept=ex.share(f, g.gain),
                                       reason="once the others are fitted it adds no significant, material share "
                                              "of the gap"))
                sel = tuple(x for x in sel if x != s)
                chosen_round.pop(s, None)
                cur = f
                changed = True
                break
    to_load: dict[str, LoadSplit] = {}
    kept_by_airspeed: dict[str, LoadSplit] = {}
    for b in [b for b in LOAD_COUPLED if b in sel and LOAD_EFFECT in sel]:
        f0 = ex.without(sel, b, cur)
        r = gain_by_airspeed(ex.w, f0.w_pred, cur.w_pred, ex.prob.q, ex.prob.split.score, ex.opt.load_min_samples,
                             ex.opt.load_spread)
        if r is None:
            continue
        if not grows_with_load(r):
            kept_by_airspeed[b] = r
            continue
        dropped.append(Dropped(effect=b, reason=f"its held-out gain grows faster than the dynamic pressure "
                                                f"({load_ratio_text(r)}): what the load's tension changes in a "
                                                f"tendon sheath (its friction band, capstan law, and the "
                                                f"tendon's compliance), so it is the aero load's",
                               gain_by_airspeed=r))
        to_load[b] = r
        sel = tuple(x for x in sel if x != b)
        chosen_round.pop(b, None)
        cur = f0
    if len(sel) == 1 and sel[0] in entered_together and not ex.admits(d, ex.nominal, cur):
        # what is left of a pair that entered together was never admitted alone
        dropped.append(Dropped(effect=sel[0], reason="entered together with an effect dropped since, and alone "
                                                     "it adds no significant, material share of the gap"))
        sel, chosen_round, cur = (), {}, ex.nominal
    together = {k: v for k, v in together.items() if k in sel}
    kept_by_airspeed = {k: v for k, v in kept_by_airspeed.items() if k in sel}
    if sel:
        cur = ex.final(sel, cur)
    if play_note and "backlash" in sel and "friction" not in sel:
        notes.append(play_note)
    unnamed: dict[str, ViscousLag | TensionBand] = {}
    viscous = viscous_lag(sel, cur.effects, ex.base)
    if viscous is not None:  # chosen and fitted as any effect, but the friction's: not named
        unnamed["delay"] = viscous
        notes.append(viscous.reason)
    # the effect that won the first round on its own and kept its place (not a runner-up taken for its pair,
    # not one of two that entered together)
    first_alone = sel[0] if sel and not entered_together and not from_runner_up and chosen_round.get(sel[0]) == 1 \
        else None
    tension = tension_band(sel, first_alone, cur.effects, ex.base, ex.prob)
    if tension is not None:  # likewise: the band followed the tension
        unnamed["friction"] = tension
        notes.append(tension.reason)
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
    return any(h.effect == j.name and (h.parameter, h.bound) not in BOUND_HINTS
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
    edges = ", ".join(f"{h.parameter} at the {h.bound} edge of its search" for h in
                      strained_one.fit.bound_hits() if h.effect == strained_one.name)
    return (f"round {rnd}: {strained_one.name} explained the log no better than {named.name} on the held-out "
            f"blocks, with {edges} (larger than the effect can be, or standing in for another): {named.name} "
            f"is named, the two reported as equally good")


def enter_together(ex: Explorer, d: Decision, judged: list[Judged]) -> tuple[Judged, Judged, PairedGain] | None:
    """Two effects that hide each other, when no effect alone passes the test: the unexplained one leaves
    slow, structured error that weakens the evidence for the other. Each of the first round's
    ``together_leads`` candidates (``DiagnoseOptions``) of largest held-out gain leads in turn, and it and a
    second effect enter together when the pair passes the test against the nominal, the second passes it
    against the first alone (as in round 2), and the first passes it against the second alone (as in the backward pass).
    Returns (first, second, the first's gain given the second) or None."""
    # led by the held-out gain, not the penalised one: with nothing significant alone, the penalty for a
    # candidate's parameters says little about which of two hidden effects it is, and the gain says how
    # much of the log it explains
    leads = sorted((j for j in judged if j.gain.gain > 0), key=lambda j: -j.gain.gain)
    for lead in leads[:ex.opt.together_leads]:
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
