"""Diagnosis of the gap between a model and a log: where it is, which effect explains it, how far.

1. **Where.** The model (with the effects it already carries) is free-run on
   the logged tendon input; the residual is split by hysteresis phase, warp
   level, frequency band, time and airspeed (``model.diag_where``) against the
   floor it should reach: the noise estimated from the log's second differences
   plus the model's own known error from its fit quality (held-out RMS beyond
   the noise it was identified with), so a model that never fitted perfectly is
   not blamed on a new effect.
2. **Which.** Every effect of the vocabulary is fitted as an augmentation
   (``model.diag_fit``) on alternating training blocks of the log and scored
   on the blocks in between. Greedy forward selection: a round fits every
   remaining effect jointly with those already chosen and takes the best by a
   penalised held-out criterion (effective samples x log MSE + 2 per extra
   parameter), provided its held-out gain is significant in a
   forecast-encompassing test (``diag_stats.paired_gain``, Bonferroni over the
   effects tried) and material: larger than a tenth of the noise variance and
   than the model's known error variance.
   A backward pass drops chosen effects that stop paying once the others are
   in, and a final joint refit polishes the chosen parameters. Candidates whose
   held-out error is statistically indistinguishable from the chosen one are
   reported as ambiguous, with the excitation that would separate them.
3. **How far.** Held-out RMS before and after, and the share of the gap closed
   ``(MSE_nominal - MSE_augmented) / (MSE_nominal - noise^2)``, overall and in
   every cell of step 1.

No I/O: ``diagnose`` returns a ``Diagnosis`` with the report (a JSON-ready
dict), the augmented ``ModelFile`` and the residual series for plotting.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from warpbridge.model.diag_fit import Fit, Problem, Split
from warpbridge.model.diag_stats import effective_n, input_independence, ljung_box, paired_gain, prewhiten
from warpbridge.model.diag_where import Cells, cells, gap_closed, split
from warpbridge.model.effects import EFFECT_FIELDS, EFFECT_NAMES, Effects
from warpbridge.model.identify import noise_floor
from warpbridge.model.modelfile import FitQuality, ModelFile

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
    frozenset({"friction", "backlash"}): "minor loops of several sizes: backlash is a fixed dead band at every "
                                         "reversal, friction scales the loop width with the excursion",
    frozenset({"friction", "pretension"}): "several amplitudes around several mean tendon positions: pre-tension "
                                           "shifts and scales the whole curve, friction only widens the loop",
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


@dataclass
class DiagnoseOptions:
    """Decision settings; the defaults are statistical conventions, not tuned to particular logs."""

    max_effects: int = 3
    alpha: float = 0.01  # family-wise level of the held-out gain tests (Bonferroni over the effects tried)
    min_gain_noise: float = 0.1  # a named effect gains at least this x noise^2 of held-out MSE (RMS >= noise / 3)
    model_error_factor: float = 1.0  # ... and at least this x the model's known error^2
    ambiguity_alpha: float = 0.05  # a runner-up not worse than the winner at this level is an equal explanation
    max_evals: int = 150  # Nelder-Mead evaluations per joint fit
    joint_refits: int = 3  # candidates per round refitted jointly with the effects already chosen
    effects: tuple[str, ...] = EFFECT_NAMES  # the candidates


@dataclass
class Judged:
    """One candidate in one round: its fit and how it compares with the current model."""

    name: str
    fit: Fit
    gain: object
    penalised: float
    significant: bool
    material: bool
    accepted: bool = False
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


def _new_params(name: str) -> int:
    return len(EFFECT_FIELDS[name][0])


def _neutral(eff: Effects, name: str, base: Effects) -> Effects:
    """``eff`` with effect ``name`` back at the nominal model's own value."""
    return replace(eff, **{f: getattr(base, f) for f in EFFECT_FIELDS[name][0]})


def diagnose(t, u, w, airspeed, model: ModelFile, options: DiagnoseOptions | None = None,
             progress: Callable[[str, int, int], None] | None = None) -> Diagnosis:
    """Diagnose the gap between ``model`` and a cleaned log (t s increasing, u mm, w deg, airspeed m/s or None)."""
    opt = options or DiagnoseOptions()
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
    prob = Problem(t, u, w, airspeed, model.params, model.effects, model.z0)
    sp = prob.split
    if sp.score.sum() < 20 or sp.train.sum() < 20:
        raise ValueError("log too short after the warm-up to split into training and scoring blocks")
    base = model.effects
    w_nom = prob.predict(base)
    r0 = w - w_nom
    noise = noise_floor(w)
    e_m = model_error(model.fit, noise)
    floor_gain = max(opt.min_gain_noise * noise ** 2, opt.model_error_factor * e_m ** 2)
    analysed = sp.train | sp.score
    cl = cells(t, u, w_nom, airspeed)
    where = split(t, u, r0, cl, analysed, noise, e_m)
    ra = r0[analysed]
    white = ljung_box(ra)
    indep = input_independence(prewhiten(u[analysed]), ra[1:])

    names = [n for n in opt.effects if n != "aero_load" or prob.has_airspeed]
    why = "the log has no airspeed" if airspeed is None else "the airspeed is zero throughout the log"
    skipped = {n: why for n in opt.effects if n not in names}
    level = opt.alpha / max(len(names), 1)
    nominal = Fit((), base, w_nom, prob.mse(w_nom, sp.train), prob.mse(w_nom, sp.score), 0)
    cur = nominal
    selected: list[str] = []
    rounds: list[list[Judged]] = []
    start_mse: list[float] = []  # held-out MSE of the model each round starts from
    ambiguities: list[dict] = []
    chosen_conf: dict[str, float] = {}
    chosen_round: dict[str, int] = {}
    total_rounds = min(opt.max_effects, len(names))
    runner_up: Judged | None = None
    notes: list[str] = []
    for rnd in range(total_rounds):
        if len(selected) >= len(names):
            break
        judged = _round(prob, selected, cur, names, w, sp, level, floor_gain, opt, progress, rnd + 1)
        start_mse.append(cur.score_mse)
        acc = [j for j in judged if j.accepted]
        if rnd == 1 and runner_up is not None:
            # a beam of two in the second round: the first round's winner may imitate two effects at once,
            # and then only its runner-up leads to the right pair
            alt = _round(prob, [runner_up.name], runner_up.fit, names, w, sp, level, floor_gain, opt, progress, 2)
            alt_acc = [j for j in alt if j.accepted]
            a_best = max(alt_acc, key=lambda j: j.penalised) if alt_acc else None
            m_best = max(acc, key=lambda j: j.penalised) if acc else None
            if a_best is not None and (m_best is None or a_best.fit.score_mse < m_best.fit.score_mse):
                g = paired_gain(w - cur.w_pred, w - a_best.fit.w_pred, sp.chunks)
                if g.p_value < level and g.gain > floor_gain:
                    notes.append(f"round 2 went on from the first round's runner-up {runner_up.name} instead of "
                                 f"{selected[0]}: together with a second effect it explains the log better")
                    chosen_conf.pop(selected[0], None)
                    chosen_round.pop(selected[0], None)
                    selected = [runner_up.name]
                    chosen_conf[runner_up.name] = runner_up.confidence
                    chosen_round[runner_up.name] = 1
                    cur = runner_up.fit
                    start_mse[-1] = cur.score_mse
                    judged, acc = alt, alt_acc
        rounds.append(judged)
        if not acc:
            break
        best = max(acc, key=lambda j: j.penalised)
        if rnd == 0:
            others = sorted((j for j in acc if j is not best), key=lambda j: -j.penalised)
            runner_up = others[0] if others else None
        selected.append(best.name)
        chosen_conf[best.name] = best.confidence
        chosen_round[best.name] = rnd + 1
        cur = best.fit
        alts = [j for j in acc if j is not best and j.ambiguous_with_best]
        if alts:
            ambiguities.append(_ambiguity(best, alts, rnd + 1))
        log.info("round %d: %s (held-out RMS %.4f -> %.4f deg)", rnd + 1, best.name,
                 math.sqrt(max(nominal.score_mse, 0)), math.sqrt(max(cur.score_mse, 0)))

    dropped: list[dict] = []
    if len(selected) >= 2:
        cur, selected = _backward(prob, cur, selected, base, w, sp, level, floor_gain, opt, dropped)
    if selected:
        if progress:
            progress("joint refit", 0, 1)
        final = prob.fit(tuple(selected), start=cur.effects, grid_for="", max_evals=3 * opt.max_evals)
        if final.train_mse <= cur.train_mse:
            cur = final
    w_aug = cur.w_pred if selected else w_nom
    r1 = w - w_aug

    shrink = split(t, u, r0, cl, sp.score, noise, e_m, r_after=r1)
    mse0, mse1 = prob.mse(w_nom, sp.score), prob.mse(w_aug, sp.score)
    shrinkage = {
        "heldout_rms_before_deg": math.sqrt(mse0), "heldout_rms_after_deg": math.sqrt(mse1),
        "gap_closed": gap_closed(mse0, mse1, noise ** 2),
        "gap_closed_beyond_model_error": gap_closed(mse0, mse1, noise ** 2 + e_m ** 2),
        "where": {k: v for k, v in shrink.items() if k not in ("scores", "dominant", "dominant_cell")},
    }
    cand = _candidate_table(names, skipped, rounds, start_mse, selected, chosen_conf, chosen_round, cur, nominal)
    residual_is_noise = white.passed and indep.passed
    if not selected and not residual_is_noise:
        notes.append("the residual is structured but no effect explains a significant, material share of it: "
                     "it is the model's own error (re-identify on a richer log, or diagnose a longer one)")
    eff_out = cur.effects if selected else base
    fitq = FitQuality(train_rms_deg=math.sqrt(prob.mse(w_aug, sp.train)), heldout_rms_deg=math.sqrt(mse1),
                      noise_deg=noise, extra={"method": "warpbridge diagnose", "verdict": list(selected),
                                              "nominal_heldout_rms_deg": math.sqrt(mse0)})
    meta = dict(model.meta)
    meta["augmented_by"] = "warpbridge diagnose"
    meta["verdict"] = list(selected)
    augmented = ModelFile(params=model.params, effects=eff_out, z0=model.z0, fit=fitq, meta=meta)
    report = {
        "format": REPORT_FORMAT,
        "verdict": list(selected),
        "effects": {n: cur.values([n])[n] for n in selected},
        "samples": int(t.size), "duration_s": float(t[-1] - t[0]),
        "noise_deg": noise, "model_error_deg": e_m, "min_material_gain_ms": floor_gain,
        "residual_is_noise": residual_is_noise,
        "tests": {"whiteness": white.to_dict(), "input_independence": indep.to_dict()},
        "where": where,
        "candidates": cand,
        "ambiguities": ambiguities,
        "dropped": dropped,
        "shrinkage": shrinkage,
        "split": {"scheme": "10 alternating blocks, blocks 2, 5, 7, 10 scored", "warmup_samples": sp.start,
                  "train_samples": int(sp.train.sum()), "score_samples": int(sp.score.sum()),
                  "score_chunks": int(sp.chunks.max() + 1)},
        "nominal_effects": base.to_dict(),
        "notes": notes,
        "model_evaluations": prob.evaluations,
    }
    report["summary"] = summary_lines(report)
    return Diagnosis(list(selected), report, augmented, t, u, w, w_nom, w_aug, sp, cl)


def _round(prob: Problem, selected: list[str], cur: Fit, names: list[str], w: np.ndarray, sp: Split, level: float,
           floor_gain: float, opt: DiagnoseOptions, progress, rnd: int) -> list[Judged]:
    """Fit every effect not yet chosen on top of ``cur`` (jointly with the chosen ones) and judge it."""
    remaining = [n for n in names if n not in selected]
    fits = {}
    for i, c in enumerate(remaining):
        if progress:
            progress(f"round {rnd}", i, len(remaining))
        # screen with a short joint fit (the chosen effects may move: effects interact), then refit the
        # most promising ones fully
        fits[c] = prob.fit(tuple(selected) + (c,), start=cur.effects, grid_for=c,
                           max_evals=opt.max_evals if not selected else opt.max_evals // 3)
    if selected:
        for c in sorted(fits, key=lambda k: fits[k].train_mse)[:opt.joint_refits]:
            f = prob.fit(tuple(selected) + (c,), start=fits[c].effects, grid_for="", max_evals=opt.max_evals)
            if f.train_mse <= fits[c].train_mse:
                fits[c] = f
    judged = [_judge(c, fits[c], cur, w, sp, level, floor_gain) for c in remaining]
    _rank(judged, w, sp, cur, opt.ambiguity_alpha, floor_gain)
    return judged


def _judge(name: str, f: Fit, cur: Fit, w: np.ndarray, sp: Split, level: float, floor_gain: float) -> Judged:
    g = paired_gain(w - cur.w_pred, w - f.w_pred, sp.chunks)
    return Judged(name, f, g, -math.inf, g.p_value < level, g.gain > floor_gain)


def _rank(judged: list[Judged], w: np.ndarray, sp: Split, cur: Fit, amb_alpha: float, floor_gain: float) -> None:
    """Penalised criterion, acceptance, ambiguity with the winner and a confidence for each candidate."""
    best_mse = min(j.fit.score_mse for j in judged)
    best_fit = next(j.fit for j in judged if j.fit.score_mse == best_mse)
    neff = effective_n((w - best_fit.w_pred)[sp.score])
    for j in judged:
        ok = j.fit.score_mse > 0 and cur.score_mse > 0 and math.isfinite(j.fit.score_mse)
        j.penalised = neff * math.log(cur.score_mse / j.fit.score_mse) - 2 * _new_params(j.name) if ok else -math.inf
        j.accepted = j.significant and j.material and j.penalised > 0
    acc = [j for j in judged if j.accepted]
    support = {j.name: 1.0 - j.gain.p_value for j in judged}
    if not acc:
        for j in judged:
            j.confidence = 0.0
        return
    best = max(acc, key=lambda j: j.penalised)
    best_conf = support[best.name]
    for j in acc:
        if j is best:
            continue
        g = paired_gain(w - j.fit.w_pred, w - best.fit.w_pred, sp.chunks)  # is best better than j?
        p = g.p_value
        # about equal: not significantly worse, or worse by less than a material gain
        j.ambiguous_with_best = p > amb_alpha or g.gain < floor_gain
        if j.ambiguous_with_best:
            p = max(p, 0.5 * (1.0 - g.gain / floor_gain)) if g.gain < floor_gain else p
        j.confidence = support[j.name] * min(1.0, 2.0 * p)
        best_conf = min(best_conf, support[best.name] * min(1.0, 2.0 * (1.0 - p)))
    best.confidence = best_conf
    for j in judged:
        if not j.accepted:
            j.confidence = 0.0


def _backward(prob: Problem, cur: Fit, selected: list[str], base: Effects, w, sp: Split, level: float,
              floor_gain: float, opt: DiagnoseOptions, dropped: list[dict]) -> tuple[Fit, list[str]]:
    """Drop chosen effects that no longer pay once the others are in (refitting the rest)."""
    changed = True
    while changed and len(selected) >= 2:
        changed = False
        for s in list(selected):
            rest = [x for x in selected if x != s]
            f = prob.fit(tuple(rest), start=_neutral(cur.effects, s, base), grid_for="", max_evals=opt.max_evals)
            g = paired_gain(w - f.w_pred, w - cur.w_pred, sp.chunks)
            if not (g.p_value < level and g.gain > floor_gain):
                dropped.append({"effect": s, "gain_ms_when_kept": g.gain, "p_value": g.p_value,
                                "reason": "no significant, material held-out gain once the others are fitted"})
                selected = rest
                cur = f
                changed = True
                break
    return cur, selected


def _ambiguity(best: Judged, alts: list[Judged], rnd: int) -> dict:
    names = [best.name] + [a.name for a in alts]
    how = []
    for a in alts:
        how.append({"effects": [best.name, a.name],
                    "excitation": SEPARATE.get(frozenset({best.name, a.name}), DEFAULT_SEPARATE)})
    return {"round": rnd, "chosen": best.name, "equally_good": names,
            "heldout_rms_deg": {j.name: math.sqrt(j.fit.score_mse) for j in [best, *alts]},
            "to_separate": how}


def _candidate_table(names, skipped, rounds, start_mse, selected, chosen_conf, chosen_round, final: Fit,
                     nominal: Fit) -> list[dict]:
    out = []
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
            row["alone"] = {"fitted": j1.fit.values([n])[n],
                            "heldout_rms_before_deg": math.sqrt(nominal.score_mse),
                            "heldout_rms_after_deg": math.sqrt(j1.fit.score_mse),
                            "heldout_gain_ms": j1.gain.gain, "p_value": j1.gain.p_value,
                            "significant": j1.significant, "material": j1.material}
        per_round = []
        for k, judged in enumerate(rounds):
            for j in judged:
                if j.name == n:
                    per_round.append({"round": k + 1, "with": [x for x in j.fit.names if x != n],
                                      "fitted": j.fit.values(), "heldout_rms_after_deg": math.sqrt(j.fit.score_mse),
                                      "heldout_gain_ms": j.gain.gain, "p_value": j.gain.p_value,
                                      "accepted": j.accepted, "confidence": j.confidence})
        row["rounds"] = per_round
        if n in selected:
            row["fitted"] = final.values([n])[n]
            row["confidence"] = chosen_conf.get(n, 0.0)
            chosen = [r for r in per_round if r["round"] == chosen_round.get(n)]
            if chosen:
                prev = math.sqrt(start_mse[chosen[0]["round"] - 1])
                row["chosen"] = {"round": chosen[0]["round"], "heldout_rms_before_deg": prev,
                                 "heldout_rms_after_deg": chosen[0]["heldout_rms_after_deg"],
                                 "p_value": chosen[0]["p_value"]}
        else:
            row["fitted"] = j1.fit.values([n])[n] if j1 is not None else None
            row["confidence"] = max((r["confidence"] for r in per_round), default=0.0)
        out.append(row)
    return out


def _fmt_params(d: dict) -> str:
    return ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in d.items())


def summary_lines(rep: dict) -> list[str]:
    """A readable summary of a report, one line each."""
    lines = []
    where = rep["where"]
    sh = rep["shrinkage"]
    lines.append(f"residual RMS {where['rms_deg']:.4f} deg against a floor of {where['floor_deg']:.4f} deg "
                 f"(noise {rep['noise_deg']:.4f}, model's known error {rep['model_error_deg']:.4f})")
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
                f"{a.get('heldout_rms_after_deg', math.nan):.4f} deg, p={a.get('p_value', 1.0):.2g}")
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
    verdict = rep["verdict"]
    if verdict:
        gc = sh["gap_closed"]
        lines.append(f"verdict: {', '.join(verdict)}; held-out RMS {sh['heldout_rms_before_deg']:.4f} -> "
                     f"{sh['heldout_rms_after_deg']:.4f} deg, gap closed "
                     + (f"{gc:.0%}" if gc is not None else "n/a"))
        for n, p in rep["effects"].items():
            lines.append(f"  {n}: {_fmt_params(p)}")
    else:
        lines.append("verdict: [] (no effect explains the gap beyond noise and the model's known error)")
    lines.extend(f"note: {n}" for n in rep["notes"])
    return lines
