"""The report: the rounds along the chosen path with confidences and ambiguities, the candidate table and
the readings of the known error's sources."""

from __future__ import annotations

import logging
import math
from dataclasses import replace

from warpbridge.model.diagnosis.check import known_error_on_check
from warpbridge.model.diagnosis.options import DiagnoseOptions
from warpbridge.model.diagnosis.problem import Fit
from warpbridge.model.diagnosis.readings import bound_meaning
from warpbridge.model.diagnosis.search import Explorer, Judged
from warpbridge.model.diagnosis.selection import Path
from warpbridge.model.diagnosis.start import bench_known_error
from warpbridge.model.diagnosis.transfer import Carried, Carry
from warpbridge.model.effect_registry import EFFECT_FIELDS, SEPARATE
from warpbridge.model.model_error import ErrorModel
from warpbridge.model.modelfile import ModelFile

log = logging.getLogger(__name__)


REPORT_FORMAT = "warpbridge-diagnosis/1"

# what separates two effects that explain a log about equally well when the registry names nothing closer
DEFAULT_SEPARATE = ("a richer excitation: a random input with sharper reversals at several amplitudes and speeds, "
                    "holds, and (for airspeed effects) a varying airspeed")


def em_summary(em: ErrorModel | None, used: bool) -> dict:
    if em is None:
        return {"present": False, "used": False}
    return {"present": True, "used": used, "feature_sets": list(em.sets),
            "bench_rms_before_deg": em.rms_before_deg, "bench_rms_after_deg": em.rms_after_deg,
            "known_error_deg": em.known_error_deg}


def rounds_along(ex: Explorer, path: Path, opt: DiagnoseOptions) -> tuple[list[list[Judged]], list[dict], dict]:
    """The rounds along the chosen path as ``ex``'s floor judges them (copies of the explored ones), with
    ambiguities and the chosen effects' confidences."""
    d = opt.decision
    rounds: list[list[Judged]] = []
    ambiguities: list[dict] = []
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


def _ambiguity(best: Judged, alts: list[Judged], rnd: int) -> dict:
    names = [best.name] + [a.name for a in alts]
    how = []
    for a in alts:
        how.append({"effects": [best.name, a.name],
                    "excitation": SEPARATE.get(frozenset({best.name, a.name}), DEFAULT_SEPARATE)})
    return {"round": rnd, "chosen": best.name, "equally_good": names,
            "heldout_rms_deg": {j.name: math.sqrt(j.fit.score_mse) for j in [best, *alts]},
            "to_separate": how}


def candidate_table(names, skipped, rounds: list[list[Judged]], path: Path, chosen_conf: dict[str, float],
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
                h["meaning"] = bound_meaning(h)
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


def carry_note(carry: Carry | None, carried: Carried | None, e_known: float) -> dict | None:
    """The report's reading of the transfer check, with the known error it leaves (None without a correction
    to check)."""
    if carry is None:
        return None
    out = {"nominal": carry.nominal.to_dict(), "short": carry.nominal.short, "raised_by_ms": 0.0,
           "known_error_deg": e_known}
    if carry.measured_ms > 0:
        out["already_measured_ms"] = carry.measured_ms
    if carried is not None:
        out |= {"verdict": carried.verdict.to_dict(), "raised_by_ms": carried.raised_by_ms,
                "settled": carried.settled}
    return out


def check_note(model: ModelFile, noise: float, use_model_error: bool) -> dict | None:
    """The check log's part in the known error: its value and whether it set it, i.e. exceeds the bench's
    (None without a check)."""
    check = known_error_on_check(model.fit.extra, use_model_error and model.model_error is not None)
    if not math.isfinite(check):
        return None
    chk = model.fit.extra.get("check", {})
    return {"known_error_deg": check, "set_it": check > bench_known_error(model, noise, use_model_error),
            "log": chk.get("log")}
