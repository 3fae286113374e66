"""Physical re-readings of a selection: what a tendon sheath makes of an effect that the generic vocabulary
names otherwise (a stall that is a play, a delay that is the friction's drag, a band that follows the
tension, a band or compliance the aero load changes), and what an edge of a search means."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from warpbridge.model.diagnosis.options import Decision, DiagnoseOptions
from warpbridge.model.diagnosis.problem import BoundHit, Fit, effect_of
from warpbridge.model.diagnosis.records import Record
from warpbridge.model.diagnosis.search import Explorer, Judged
from warpbridge.model.effect_registry import BAND_EFFECTS, BOUND_HINTS, LOAD_EFFECT, TENSION_CHANGES
from warpbridge.model.effects import (
    CAPSTAN_FIELDS,
    Effects,
)
from warpbridge.model.initial_state import reachable_band


@dataclass(frozen=True)
class StallAsPlay:
    """``stall_as_play``'s reading: the backlash to name instead of the round's capstan stall, and why."""

    judged: Judged
    reason: str


@dataclass(frozen=True)
class ViscousLag(Record):
    """``viscous_lag``'s reading: a shorter delay kept in the model as the weaker friction's drag."""

    friction_scale: float
    bench_delay_s: float
    delay_s: float
    reason: str


@dataclass(frozen=True)
class TensionBand(Record):
    """``tension_band``'s reading: a friction change kept in the model as the pre-tension's, its band and
    compliance factors and the tendon's share of the travel they imply."""

    band_factor: float
    compliance_factor: float
    stretch_share: float
    reason: str


def stall_as_play(ex: Explorer, d: Decision, best: Judged, acc: list[Judged]) -> StallAsPlay | None:
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
    if not growth < ex.opt.stall_as_play_growth:
        return None
    play = next((j for j in acc if j.name == "backlash"), None)
    if play is None or not ex.ties(ex.gain(play.fit, best.fit), d):
        return None
    return StallAsPlay(
        play,
        f"friction's capstan stall (a play growing with the tension, x{eff.capstan_pull_ratio:.3g} "
        f"pulling and x{eff.capstan_release_ratio:.3g} releasing per mm above "
        f"{eff.capstan_zero_mm:.3g} mm, x{growth:.2f} across the log's travel) explains the log no "
        f"better than a fixed play on the held-out blocks: the play is the stall's limit and "
        f"nothing shows it growing with the tension, so backlash is named (to tell them apart: "
        f"minor loops at several mean tendon positions; a stall's play grows with the tension, a "
        f"backlash's does not)")


def viscous_lag(selected: tuple[str, ...], eff: Effects, base: Effects) -> ViscousLag | None:
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
    return ViscousLag(
        s, d0, d1,
        f"the delay shortened with the friction ({1e3 * d0:.1f} -> {1e3 * d1:.1f} ms while the "
        f"band narrowed to x{s:.2f}): a sheath's drag lags the pull in proportion to its speed and "
        f"weakens with the friction, and the bench's delay held that lag with the link's and the "
        f"servo's latency; the shorter delay is read as the friction's rate-dependent part, kept in "
        f"the model but not named (if the field's link or logger is faster than the bench's, it "
        f"may be that instead: compare their latencies)")


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
                 base: Effects, prob=None) -> TensionBand | None:
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
    return TensionBand(
        math.exp(band), math.exp(compliance), sigma,
        f"the friction band {way} (x{math.exp(band):.2f}) with the rig's compliance (x"
        f"{math.exp(compliance):.2f} travel per degree) after the pre-tension changed: in a tendon "
        f"sheath the band follows the tension (capstan law) and the tendon's stretch, {sigma:.0%} "
        f"of the travel here, follows it too; the friction change is read as the pre-tension's, "
        f"kept in the model but not named (if the sheath itself changed, its bend, wear or "
        f"lubricant, measure the tendon's tension at rest against the bench's: a band that "
        f"changed more than the tension is the sheath's own)")


def tension_band_notes(selected: list[str], airspeed_checked: bool = False) -> list[str]:
    """Notes for a band effect named together with a change of the tendon's tension: in a tendon sheath the
    second may be the first's consequence, not a change of its own. With ``airspeed_checked`` the aero load's
    is left to ``airspeed_note`` (the log itself was checked)."""
    band = [b for b in BAND_EFFECTS if b in selected]
    notes = []
    for cause, (what, check) in TENSION_CHANGES.items():
        if cause == LOAD_EFFECT and airspeed_checked:
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


@dataclass(frozen=True)
class LoadSplit(Record):
    """What an effect gains (drop of the squared error, deg^2 per sample) on the slowest and the fastest third
    of the flown samples, and their mean dynamic pressures (kPa)."""

    q_slow_kpa: float
    q_fast_kpa: float
    gain_slow_ms: float
    gain_fast_ms: float

    @property
    def fast_over_slow(self) -> float | None:
        """The fast third's gain over the slow third's; None when the slow third gains nothing (or loses)."""
        return self.gain_fast_ms / self.gain_slow_ms if self.gain_slow_ms > 0 else None

    def to_dict(self) -> dict:
        return super().to_dict() | {"fast_over_slow": self.fast_over_slow}


def gain_by_airspeed(w: np.ndarray, w_without: np.ndarray, w_with: np.ndarray, q: np.ndarray,
                     mask: np.ndarray, min_samples: int = DiagnoseOptions.load_min_samples,
                     spread: float = DiagnoseOptions.load_spread) -> LoadSplit | None:
    """What an effect gains (drop of the squared error, deg^2 per sample) on the slowest and the fastest
    third of the ``mask`` samples flown (q > 0) by dynamic pressure ``q`` (kPa). None when fewer than
    ``min_samples`` such samples, or when the two thirds hardly differ in airspeed (the fast third's mean q
    under ``spread`` x the slow third's)."""
    flying = mask & (q > 0)
    qm = q[flying]
    if qm.size < min_samples:
        return None
    g = ((w - w_without) ** 2 - (w - w_with) ** 2)[flying]
    order = np.argsort(qm, kind="stable")
    third = qm.size // 3
    slow, fast = order[:third], order[-third:]
    q_slow, q_fast = float(np.mean(qm[slow])), float(np.mean(qm[fast]))
    if not q_fast > spread * q_slow:
        return None
    return LoadSplit(q_slow, q_fast, float(np.mean(g[slow])), float(np.mean(g[fast])))


def grows_with_load(r: LoadSplit) -> bool:
    """An effect's gain grows faster than the dynamic pressure between the slow and the fast third.

    A heuristic from two readings: a change of the sheath's own friction or rig gains about alike at any
    airspeed (ratio ~1); a band or a compliance the load changes (in proportion to it: capstan law) gains
    roughly as the square of the change, ~(q_fast / q_slow)^2 (roughly: the fitted constant takes up part of
    it, and the slow third's gain can even turn negative). The line is drawn halfway between the two on a
    log scale, g_fast / g_slow > q_fast / q_slow (compared multiplied out, so no division by a zero gain)."""
    return r.gain_fast_ms * r.q_slow_kpa > max(r.gain_slow_ms, 0.0) * r.q_fast_kpa


def load_ratio_text(r: LoadSplit) -> str:
    q = f"{r.q_fast_kpa / r.q_slow_kpa:.1f}x the dynamic pressure ({r.q_slow_kpa:.2f} -> {r.q_fast_kpa:.2f} kPa)"
    if r.fast_over_slow is None:
        return f"nothing (or a loss) on the slowest third of the log, {r.gain_fast_ms:.2g} deg^2 on the fastest, at {q}"
    return f"{r.fast_over_slow:.1f}x as much on the fastest third of the log as on the slowest, at {q}"


def airspeed_note(effect: str, r: LoadSplit) -> str:
    """The report's reading of ``gain_by_airspeed`` for an effect kept beside an aero load."""
    return (f"{effect} beside aero_load: on the held-out blocks it gains {load_ratio_text(r)}; what the load's "
            f"tension changes (the band, capstan law, or the compliance) would gain faster than the pressure "
            f"grows, so this is a change of its own")


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


def bound_meaning(h: BoundHit) -> str:
    hint = BOUND_HINTS.get((h.parameter, h.bound),
                           "the effect is larger than the model allows, or another effect is at work")
    return (f"{h.effect}: {h.parameter} sits at the {h.bound} bound of its search ({h.limit:.4g}): "
            f"{hint}; confidence halved")


def read_bounds(hits: list[BoundHit]) -> list[BoundHit]:
    """The hits with what each edge means."""
    return [replace(h, meaning=bound_meaning(h)) for h in hits]
