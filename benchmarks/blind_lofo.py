"""Leave-one-family-out scoring of the blind diagnosis benchmark's results (pure functions on result dicts).

Each case result holds the truth, the verdict under every decision of the grid
(``alternatives``) and the check-log gap each of them closes. For a held-out
family, the decision is the one that scores best on the other families (all
seeds); the held-out family is then scored with it. The pooled figures add up
the held-out scores of every fold, so no case is scored with a decision made
on its own family. "Best" follows the targets, which hold for each family: the
least total shortfall of the training families below them (``merit``), then the
mean of the pooled rates.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable

import numpy as np

EFFECTS = ("delay", "rate_limit", "backlash", "friction", "pretension", "sensor_lag", "drift", "aero_load")
TARGETS = {"single": 0.95, "pairs": 0.80, "false_alarm": 0.05, "min_closed": 0.50, "median_closed": 0.95,
           "seconds": 30.0}


CLEAR_FACTOR = 2.0  # an effect "well above the bench misfit": its RMS on the field log at least this x the misfit
SHORT_OF_DRAWN = 0.9  # a single effect that reached under this share of its drawn size: its size search hit its cap


def well_above_misfit(r: dict) -> bool:
    """The effect's RMS change of the warp is at least ``CLEAR_FACTOR`` x the nominal model's bench misfit."""
    return r["effect_rms_deg"] >= CLEAR_FACTOR * r["bench_misfit_deg"]


def key(d: dict) -> str:
    return json.dumps(d, sort_keys=True)


def verdict_at(r: dict, dk: str) -> list[str]:
    return sorted(r["by_decision"][dk]["verdict"])


# a check-log gap smaller than this share of the check log's own floor (the nominal's MSE on it without the
# effects) is not scored: the effect hardly acts on that excitation (a slew limit the check input never reaches),
# and the share closed is then a ratio of two differences within rounding of each other
MIN_GAP = 0.01


def check_gap(r: dict, bare: bool = False) -> float:
    """What the effects add to the nominal's MSE on the check log, as a share of its MSE there without them."""
    m0 = r["check_rms_bare" if bare else "check_rms_nominal"] ** 2
    m00 = r["check_rms_bare_without_effects" if bare else "check_rms_nominal_without_effects"] ** 2
    return (m0 - m00) / m00 if m00 > 0 else math.inf


def closed_at(r: dict, dk: str, bare: bool = False) -> float | None:
    """Check-log gap closed under decision ``dk`` (the nominal with its model-error correction, or ``bare``);
    None when the gap is not measurable (under ``MIN_GAP`` of the check log's floor, or none)."""
    if not check_gap(r, bare) >= MIN_GAP:
        return None
    return r["by_decision"][dk].get("gap_closed_bare" if bare else "gap_closed")


def rates(results: Iterable[dict], dk: str) -> dict:
    """Exact-naming rates of single effects and pairs, false alarms, gap closed, for decision ``dk``."""
    results = list(results)
    singles = [r for r in results if len(r["truth"]) == 1]
    pairs = [r for r in results if len(r["truth"]) == 2]
    nones = [r for r in results if not r["truth"]]
    s_ok = sum(verdict_at(r, dk) == r["truth"] for r in singles)
    p_ok = sum(verdict_at(r, dk) == r["truth"] for r in pairs)
    fa = sum(bool(verdict_at(r, dk)) for r in nones)
    closed = [c for r in singles if (c := closed_at(r, dk)) is not None]
    return {"singles": len(singles), "single_ok": s_ok, "pairs": len(pairs), "pair_ok": p_ok,
            "nones": len(nones), "false_alarms": fa,
            "single_rate": s_ok / len(singles) if singles else math.nan,
            "pair_rate": p_ok / len(pairs) if pairs else math.nan,
            "fa_rate": fa / len(nones) if nones else math.nan,
            "min_closed": float(np.min(closed)) if closed else math.nan,
            "median_closed": float(np.median(closed)) if closed else math.nan}


def score(rt: dict) -> float:
    """The mean of the three rates (singles, pairs, no false alarm): ``merit``'s tie-break."""
    parts = [rt["single_rate"], rt["pair_rate"], 1.0 - rt["fa_rate"]]
    parts = [p for p in parts if math.isfinite(p)]
    return float(np.mean(parts)) if parts else -math.inf


def shortfall(rt: dict) -> float:
    """How far the naming rates fall short of their targets (singles, pairs, false alarms), summed."""
    parts = [TARGETS["single"] - rt["single_rate"], TARGETS["pairs"] - rt["pair_rate"],
             rt["fa_rate"] - TARGETS["false_alarm"]]
    return float(sum(max(p, 0.0) for p in parts if math.isfinite(p)))


def merit(results: list[dict], dk: str) -> tuple[float, float]:
    """What a decision is chosen by (larger is better): first the shortfall below the targets summed over
    the families of ``results``, each scored alone (the targets hold for each family, so a decision that
    keeps every training family above them is preferred to one that buys a higher pooled rate with one
    family below), then the mean of the pooled rates (``score``)."""
    fams = sorted({r["family"] for r in results})
    miss = sum(shortfall(rates([r for r in results if r["family"] == f], dk)) for f in fams)
    return -round(miss, 12), round(score(rates(results, dk)), 12)  # rounded: sums of rates compare exactly


def choose(results: list[dict], decisions: list[str], default: str) -> str:
    """The decision of the largest ``merit`` on ``results``; ties go to the default, then to the first listed."""
    best, best_m = default, merit(results, default)
    for dk in decisions:
        if (m := merit(results, dk)) > best_m:
            best, best_m = dk, m
    return best


def lofo(results: list[dict], default: str, pool: list[dict] | None = None) -> dict:
    """{family: (decision chosen without it, its results)} for every family in the results. The decision is
    chosen on the other families of ``pool`` (default: the results themselves); a pool of other seeds holds
    each family out and the scored seeds out as well."""
    pool = results if pool is None else pool
    families = sorted({r["family"] for r in results})
    decisions = sorted({dk for r in pool for dk in r["by_decision"]})
    out = {}
    for fam in families:
        train = [r for r in pool if r["family"] != fam]
        dk = choose(train, decisions, default) if train else default
        out[fam] = (dk, [r for r in results if r["family"] == fam])
    return out


def _pct(a: int, b: int) -> str:
    return f"{a}/{b} ({a / b:.0%})" if b else "-"


def _ok(val: float, target: float, higher: bool) -> str:
    if not math.isfinite(val):
        return ""
    return "ok" if (val >= target if higher else val <= target) else "MISSED"


def describe_decision(dk: str) -> str:
    d = json.loads(dk)
    return f"alpha {d['alpha']:g}, share {d['min_share']:g}, gain {d['min_gain']:g}" + (
        ", parsimony" if d.get("parsimony") else "") + (f", total {d['min_total']:g}" if d.get("min_total") else "")


def fold_table(folds: dict, seeds: list[int]) -> str:
    """Per held-out family and seed: the decision chosen without that family and the figures it gives."""
    lines = [f"{'held-out family':<20} {'seed':>4}  {'decision chosen on the others':<44} {'singles exact':>14} "
             f"{'pairs exact':>13} {'false alarms':>12} {'gap closed min / median':>24}"]
    for fam, (dk, rs) in folds.items():
        dtxt = describe_decision(dk)
        for seed in [*seeds, None]:
            sub = [r for r in rs if seed is None or r["seed"] == seed]
            if not sub:
                continue
            rt = rates(sub, dk)
            gc = (f"{rt['min_closed']:.0%} / {rt['median_closed']:.0%}" if math.isfinite(rt["median_closed"])
                  else "-")
            lines.append(f"{fam if seed in (seeds[0], None) else '':<20} {seed if seed is not None else 'all':>4}  "
                         f"{dtxt if seed == seeds[0] else '':<44} {_pct(rt['single_ok'], rt['singles']):>14} "
                         f"{_pct(rt['pair_ok'], rt['pairs']):>13} {_pct(rt['false_alarms'], rt['nones']):>12} "
                         f"{gc:>24}")
    return "\n".join(lines)


def default_table(results: list[dict], default: str) -> str:
    """Per family: what the shipped default decision (the one users run) gives, against the targets. The
    default was set on the benchmark's folds in an earlier round, so unlike the fold table this is not a
    held-out figure."""
    lines = [f"{'family':<20} {'singles exact':>14} {'pairs exact':>13} {'false alarms':>12} "
             f"{'gap closed min / median':>24}   targets"]
    fams = sorted({r["family"] for r in results})
    for fam in [*fams, None]:
        rt = rates([r for r in results if fam is None or r["family"] == fam], default)
        gc = f"{rt['min_closed']:.0%} / {rt['median_closed']:.0%}" if math.isfinite(rt["median_closed"]) else "-"
        ok = [_ok(rt["single_rate"], TARGETS["single"], True), _ok(rt["pair_rate"], TARGETS["pairs"], True),
              _ok(rt["fa_rate"], TARGETS["false_alarm"], False), _ok(rt["min_closed"], TARGETS["min_closed"], True)]
        lines.append(f"{fam or 'all':<20} {_pct(rt['single_ok'], rt['singles']):>14} "
                     f"{_pct(rt['pair_ok'], rt['pairs']):>13} {_pct(rt['false_alarms'], rt['nones']):>12} "
                     f"{gc:>24}   {' '.join(o for o in ok if o) or '-'}")
    return "\n".join(lines)


COUNTS = ("singles", "single_ok", "pairs", "pair_ok", "nones", "false_alarms")


def summed_rates(scored: Iterable[tuple[str, list[dict]]]) -> dict:
    """The counts of ``rates`` added up over (decision, results) pairs: each fold's cases with its decision."""
    tot = dict.fromkeys(COUNTS, 0)
    for dk, rs in scored:
        rt = rates(rs, dk)
        for k in COUNTS:
            tot[k] += rt[k]
    return tot


def pooled_table(folds: dict, seeds: list[int]) -> str:
    """Pooled held-out figures (each case scored with the decision of its own fold), per seed, with targets."""
    lines = [f"{'pooled (each family held out)':<34} " + " ".join(f"{f'seed {s}':>16}" for s in seeds)
             + f" {'all':>16}   target"]

    def pooled(seed):
        subs = [(dk, [r for r in rs if seed is None or r["seed"] == seed]) for dk, rs in folds.values()]
        tot = summed_rates(subs)
        clear = {"clear": 0, "clear_ok": 0}
        closed = []
        for dk, sub in subs:
            closed += [(c, closed_at(r, dk, bare=True)) for r in sub
                       if len(r["truth"]) == 1 and (c := closed_at(r, dk)) is not None]
            # the clear cases: an effect well above what the nominal model got wrong on the bench
            well = [r for r in sub if len(r["truth"]) == 1 and well_above_misfit(r)]
            clear["clear"] += len(well)
            clear["clear_ok"] += sum(verdict_at(r, dk) == r["truth"] for r in well)
        return tot | clear, closed

    cols = [pooled(s) for s in [*seeds, None]]
    rows = [
        ("single effects named exactly", lambda t, c: _pct(t["single_ok"], t["singles"]),
         f">= {TARGETS['single']:.0%}"),
        (f"  of them effect >= {CLEAR_FACTOR:g}x bench misfit", lambda t, c: _pct(t["clear_ok"], t["clear"]), ""),
        ("pairs named exactly", lambda t, c: _pct(t["pair_ok"], t["pairs"]), f">= {TARGETS['pairs']:.0%}"),
        ("false alarms (no effect)", lambda t, c: _pct(t["false_alarms"], t["nones"]),
         f"<= {TARGETS['false_alarm']:.0%}"),
        ("check-log gap closed, min", lambda t, c: f"{min(x for x, _ in c):.0%}" if c else "-",
         f">= {TARGETS['min_closed']:.0%}"),
        ("check-log gap closed, median", lambda t, c: f"{np.median([x for x, _ in c]):.0%}" if c else "-",
         f">= {TARGETS['median_closed']:.0%}"),
        ("  bare model: min / median", lambda t, c: _bare_closed(c), ""),
    ]
    for name, fn, target in rows:
        lines.append(f"{name:<34} " + " ".join(f"{fn(t, c):>16}" for t, c in cols) + f"   {target}")
    return "\n".join(lines)


def _bare_closed(c: list[tuple[float, float | None]]) -> str:
    b = [y for _, y in c if y is not None]
    return f"{min(b):.0%} / {np.median(b):.0%}" if b else "-"


def effect_table(results: list[dict], folds: dict) -> str:
    """Per effect (single-effect cases, each with its fold's decision): named exactly, contained, gap closed."""
    lines = [f"{'effect':<12} {'named exactly':>14} {'contained':>10} {'gap closed min / median':>24}   "
             "named instead"]
    dk_of = {fam: dk for fam, (dk, _) in folds.items()}
    for n in EFFECTS:
        rs = [r for r in results if r["truth"] == [n]]
        if not rs:
            continue
        ex = sum(verdict_at(r, dk_of[r["family"]]) == [n] for r in rs)
        inc = sum(n in verdict_at(r, dk_of[r["family"]]) for r in rs)
        gc = [c for r in rs if (c := closed_at(r, dk_of[r["family"]])) is not None]
        wrong: dict[str, int] = {}
        for r in rs:
            v = verdict_at(r, dk_of[r["family"]])
            if v != [n]:
                k = "+".join(v) or "[]"
                wrong[k] = wrong.get(k, 0) + 1
        gct = f"{min(gc):.0%} / {np.median(gc):.0%}" if gc else "-"
        lines.append(f"{n:<12} {ex:>8}/{len(rs):<5} {inc:>6}/{len(rs):<3} {gct:>24}   "
                     + ", ".join(f"{k} x{v}" for k, v in sorted(wrong.items(), key=lambda kv: -kv[1])))
    return "\n".join(lines)


def reached_x_noise(r: dict) -> float | None:
    """A single-effect case's effect RMS over the noise when it fell short of the drawn size (the benchmark's
    size search for it ended at its cap: a servo too slow to move, a lag of seconds, a friction gone), else None."""
    if len(r["truth"]) != 1 or not r.get("noise"):
        return None
    reached = r["effect_rms_deg"] / r["noise"]
    return reached if reached < SHORT_OF_DRAWN * r["magnitude_x_noise"][r["truth"][0]] else None


def misses(results: list[dict], folds: dict | None = None, default: str = "") -> str:
    """Cases whose verdict is not the truth, each with its fold's decision (or with ``default`` for all)."""
    dk_of = {fam: dk for fam, (dk, _) in folds.items()} if folds is not None else {}
    lines = []
    for r in results:
        v = verdict_at(r, dk_of.get(r["family"], default))
        if v != r["truth"]:
            mags = ", ".join(f"{k} {m:.1f}x noise" for k, m in r["magnitude_x_noise"].items())
            if (reached := reached_x_noise(r)) is not None:
                mags += f" drawn, {reached:.1f}x reached: its size search ended at its cap"
            lines.append(f"  {r['plant']:<28} truth {r['truth'] or '[]'} ({mags or 'none'}; bench misfit "
                         f"{r['bench_misfit_deg']:.3f} deg, effect RMS {r['effect_rms_deg']:.3f} deg; check log "
                         f"without the effect {r['check_rms_nominal_without_effects']:.2f} deg) -> {v or '[]'}")
    return "\n".join(lines) if lines else "  none"


def short_closures(results: list[dict], folds: dict) -> str:
    """Single-effect cases that close less than ``TARGETS['min_closed']`` of their check-log gap, with what
    their fold's decision named."""
    lines = []
    for _, (dk, rs) in sorted(folds.items()):
        for r in rs:
            c = closed_at(r, dk)
            if len(r["truth"]) == 1 and c is not None and c < TARGETS["min_closed"]:
                v = verdict_at(r, dk)
                what = "named nothing" if not v else "named right" if v == r["truth"] else f"named {v}"
                chk = (f"  (the model misses the check log by {r['check_rms_nominal']:.2f} deg with the effect, "
                       f"{r['check_rms_nominal_without_effects']:.2f} without it")
                if (b := closed_at(r, dk, bare=True)) is not None:
                    chk += (f"; the bare model {r['check_rms_bare']:.2f} and "
                            f"{r['check_rms_bare_without_effects']:.2f}, closed {b:.0%}")
                chk += ")"
                lines.append(f"  {r['plant']:<28} {r['truth'][0]:<12} closed {c:>5.0%}  {what:<14}{chk}")
    return "\n".join(lines) if lines else "  none"


def unscored_gaps(results: list[dict]) -> str:
    """Single-effect cases whose check-log gap is not measurable (``check_gap`` under ``MIN_GAP``)."""
    lines = []
    for r in results:
        if len(r["truth"]) == 1 and not check_gap(r) >= MIN_GAP:
            lines.append(f"  {r['plant']:<28} {r['truth'][0]:<12} the effect adds {check_gap(r):+.2%} to the "
                         f"nominal's check-log MSE ({r['check_rms_nominal_without_effects']:.4f} -> "
                         f"{r['check_rms_nominal']:.4f} deg RMS)")
    return "\n".join(lines) if lines else "  none"


def bench_error_table(results: list[dict]) -> str:
    """Per family: what the nominal model gets wrong on the bench (identification's held-out RMS) and what the
    model-error model still leaves beyond noise (its cross-validated known error), over the family's plants."""
    per: dict[str, dict[str, tuple[float, float]]] = {}
    for r in results:
        per.setdefault(r["family"], {})[r["plant"]] = (r["bench_misfit_deg"], r["model_error_deg"])

    def span(v: list[float]) -> str:
        return f"{np.median(v):.3f} ({min(v):.3f}-{max(v):.3f})"

    lines = [f"{'family':<20} {'plants':>6} {'bench misfit, deg: median (range)':>36} "
             f"{'known error after the correction':>36}"]
    for fam in sorted(per):
        vals = list(per[fam].values())
        lines.append(f"{fam:<20} {len(vals):>6} {span([v[0] for v in vals]):>36} {span([v[1] for v in vals]):>36}")
    return "\n".join(lines)


def check_log_table(results: list[dict]) -> str:
    """Per family: the nominal's check-log RMS without effects, bare and with its model-error correction, over
    the family's cases (median, and in how many the correction is better)."""
    per: dict[str, list[tuple[float, float]]] = {}
    for r in results:
        if "check_rms_bare_without_effects" in r:
            per.setdefault(r["family"], []).append((r["check_rms_bare_without_effects"],
                                                    r["check_rms_nominal_without_effects"]))
    lines = [f"{'family':<20} {'cases':>6} {'bare, deg: median':>18} {'corrected':>10} {'ratio median':>13} "
             f"{'better':>8}"]
    for fam in sorted(per):
        v = np.array(per[fam])
        lines.append(f"{fam:<20} {len(v):>6} {np.median(v[:, 0]):>18.3f} {np.median(v[:, 1]):>10.3f} "
                     f"{np.median(v[:, 1] / v[:, 0]):>13.2f} {int(np.sum(v[:, 1] < v[:, 0])):>4}/{len(v):<3}")
    return "\n".join(lines)


def plant_table(results: list[dict], folds: dict, about: dict[str, str] | None = None) -> str:
    """Per plant, worst first: the nominal's bench misfit and known error (after its correction), its median
    check-log RMS without effects (corrected: another excitation than the bench's), and the plant's cases named
    exactly under its fold's decision. ``about`` adds a word on each plant (e.g. a sheath's capstan wrap)."""
    about = about or {}
    per: dict[str, list[dict]] = {}
    dec = {fam: dk for fam, (dk, _) in folds.items()}
    for r in results:
        per.setdefault(r["plant"], []).append(r)
    rows = []
    for plant, rs in per.items():
        ok = sum(verdict_at(r, dec[r["family"]]) == r["truth"] for r in rs)
        chk = float(np.median([r["check_rms_nominal_without_effects"] for r in rs]))
        rows.append((ok / len(rs), plant, rs[0]["bench_misfit_deg"], rs[0]["model_error_deg"], chk, ok, len(rs)))
    lines = [f"{'plant':<26} {'bench misfit':>12} {'known error':>12} {'check w/o effects':>18} {'exact':>7}   about"]
    for _, plant, bm, me, chk, ok, n in sorted(rows):
        lines.append(f"{plant:<26} {bm:>12.3f} {me:>12.3f} {chk:>18.3f} {ok:>3}/{n:<3}   {about.get(plant, '')}")
    return "\n".join(lines)


def _outcomes(rs: list[dict], dk: str) -> dict:
    """``rates`` plus the effect cases named wrongly and those named nothing."""
    missed = [verdict_at(r, dk) for r in rs if r["truth"] and verdict_at(r, dk) != r["truth"]]
    return rates(rs, dk) | {"wrong": sum(bool(v) for v in missed), "nothing": sum(not v for v in missed)}


def check_comparison(with_check: list[dict], without: list[dict], dk: str, carry_factor: float = 2.0) -> str:
    """The same cases diagnosed with models scored on a check log (``identify --check``) and without, under
    decision ``dk``: per group of plants (those whose check-log known error is over ``carry_factor`` x the
    bench's and x half the noise, i.e. the model does not carry to another input, and the others), what is
    named exactly, named wrongly or not at all; then every case whose verdict changed."""
    base = {(r["plant"], r["case"]): r for r in without}
    pairs = [(r, base[(r["plant"], r["case"])]) for r in with_check if (r["plant"], r["case"]) in base]
    if not pairs:
        return "  no case of these seeds was run without the check (run the same command without --bench-check)"
    def group(r, r0):  # as identify warns: over carry_factor x the bench's error, or x half the noise
        carries = r["model_error_deg"] <= carry_factor * max(r0["model_error_deg"], 0.5 * r0["noise"])
        return "carries" if carries else "does not carry"
    lines = [f"{'models':<16} {'plants':>6} {'':<8} {'singles':>8} {'pairs':>7} {'false alarms':>13} "
             f"{'named wrongly':>14} {'nothing named':>14}"]
    for g in ("does not carry", "carries"):
        sel = [(r, r0) for r, r0 in pairs if group(r, r0) == g]
        if not sel:
            continue
        n_pl = len({r["plant"] for r, _ in sel})
        for tag, rs in (("without", [r0 for _, r0 in sel]), ("with", [r for r, _ in sel])):
            t = _outcomes(rs, dk)
            lines.append(f"{g if tag == 'without' else '':<16} {n_pl if tag == 'without' else '':>6} {tag:<8} "
                         f"{t['single_ok']:>4}/{t['singles']:<3} {t['pair_ok']:>3}/{t['pairs']:<3} "
                         f"{t['false_alarms']:>9}/{t['nones']:<3} {t['wrong']:>14} {t['nothing']:>14}")
    changed = [(r, r0) for r, r0 in pairs if verdict_at(r, dk) != verdict_at(r0, dk)]
    lines.append(f"verdicts changed: {len(changed)} of {len(pairs)}")
    for r, r0 in changed:
        lines.append(f"  {r['plant']}-c{r['case']:<4} truth {'+'.join(r['truth']) or 'none':<24} "
                     f"{'+'.join(verdict_at(r0, dk)) or '[]':<24} -> {'+'.join(verdict_at(r, dk)) or '[]':<24} "
                     f"known error {r0['model_error_deg']:.3f} -> {r['model_error_deg']:.3f} deg")
    return "\n".join(lines)


SWITCHES = ("min_total", "parsimony")  # the decision's switches; their values are those the results' grid holds


def switch_table(folds: dict) -> str:
    """Each fold's decision with one switch of the grid forced on (each value the results hold), scored on its
    held-out family as the pooled table is: what a switch no fold chose would have given."""
    keys = {dk for _, rs in folds.values() for r in rs for dk in r["by_decision"]}
    values = sorted({(sw, json.loads(dk)[sw]) for dk in keys for sw in SWITCHES if json.loads(dk).get(sw)})
    lines = [f"{'each fold decision':<28} {'singles exact':>16} {'pairs exact':>14} {'false alarms':>13}   "
             "per family (singles/pairs)"]
    for label, sw in [("as chosen", None), *((f"with {k} {v}", (k, v)) for k, v in values)]:
        scored = {}
        for fam, (dk, rs) in folds.items():
            d = json.loads(dk) | (dict([sw]) if sw else {})
            scored[fam] = (key(d), rs)
        if any(k not in r["by_decision"] for k, rs in scored.values() for r in rs):
            continue  # a fold's decision with this switch is not in every result's grid
        tot = summed_rates(scored.values())
        per = [f"{fam} {rates(rs, k)['single_ok']}/{rates(rs, k)['pair_ok']}" for fam, (k, rs) in scored.items()]
        lines.append(f"{label:<28} {_pct(tot['single_ok'], tot['singles']):>16} "
                     f"{_pct(tot['pair_ok'], tot['pairs']):>14} {_pct(tot['false_alarms'], tot['nones']):>13}   "
                     + ", ".join(per))
    return "\n".join(lines)


def close_calls(results: list[dict], folds: dict, pool: list[dict] | None = None) -> str:
    """Per fold: the decision chosen and the best-scoring other decision on the same training families (of
    ``pool``, as ``lofo`` was given) that scores the held-out family differently (singles / pairs / false
    alarms, training and held out): how near the choice was."""
    pool = results if pool is None else pool
    decisions = sorted({dk for r in pool for dk in r["by_decision"]})
    lines = [f"{'held-out family':<20} {'':<10} {'decision':<44} {'others: s/p/fa':>16} {'held out: s/p/fa':>17}"]

    def counts(rs: list[dict], dk: str) -> tuple[int, int, int]:
        rt = rates(rs, dk)
        return rt["single_ok"], rt["pair_ok"], rt["false_alarms"]

    for fam, (dk, rs) in folds.items():
        train = [r for r in pool if r["family"] != fam]
        chosen = counts(rs, dk)
        ranked = sorted((d for d in decisions if d != dk), key=lambda d: merit(train, d), reverse=True)
        alt = next((d for d in ranked if counts(rs, d) != chosen), None)
        for label, d in (("chosen", dk), ("next other", alt)):
            if d is None:
                continue
            lines.append(f"{fam if label == 'chosen' else '':<20} {label:<10} {describe_decision(d):<44} "
                         f"{'/'.join(map(str, counts(train, d))):>16} {'/'.join(map(str, counts(rs, d))):>17}")
    return "\n".join(lines)


def aero_split_table(results: list[dict], folds: dict) -> str:
    """Per case: each effect its fold's decision attributed to the aero load (its gain grows faster than the
    dynamic pressure), and each one the shipped default's report kept beside the load, with the ratios."""
    dk_of = {fam: dk for fam, (dk, _) in folds.items()}
    lines = [f"{'case':<30} {'truth':<24} {'verdict':<28} {'effect':<11} {'gain fast/slow':>14} "
             f"{'q fast/slow':>11}   {'':<10}"]

    def row(r: dict, verdict: list[str], x: dict, what: str) -> str:
        ratio = x["fast_over_slow"]
        rt = f"{ratio:.2f}" if ratio is not None else "(slow <= 0)"
        return (f"{r['plant'] + '-c' + str(r['case']):<30} {'+'.join(r['truth']) or '[]':<24} "
                f"{'+'.join(verdict) or '[]':<28} {x['effect']:<11} {rt:>14} "
                f"{x['q_fast_kpa'] / x['q_slow_kpa']:>11.2f}   {what}")

    for r in sorted(results, key=lambda r: (r["family"], r["seed"], r["plant_index"], r["case"])):
        fold = r["by_decision"][dk_of[r["family"]]]
        for x in fold.get("to_aero_load", []):
            lines.append(row(r, fold["verdict"], x, "to the load (fold's decision)"))
        for x in r.get("kept_beside_aero_load", []):
            lines.append(row(r, r["verdict"], x, "kept (shipped default)"))
    return "\n".join(lines) if len(lines) > 1 else "  none"


# ---- two runs of the same cases (``blind_compare.py``): another code's results against this one's ----------------

def case_id(r: dict) -> tuple:
    return r["family"], r["seed"], r["plant_index"], r["case"]


def correct_decisions(r: dict) -> int:
    """How many decisions of the grid name the case's truth exactly."""
    return sum(sorted(v["verdict"]) == r["truth"] for v in r["by_decision"].values())


def matched(before: list[dict], after: list[dict]) -> list[tuple[dict, dict]]:
    """(before, after) of every case in both runs, in the order of ``after``."""
    old = {case_id(r): r for r in before}
    return [(old[case_id(r)], r) for r in after if case_id(r) in old]


def _figures(results: list[dict], folds: dict, default: str) -> dict:
    """The held-out and shipped-default counts, gap closed and correct decisions of one run."""
    held = summed_rates(folds.values())
    closed = [c for dk, rs in folds.values() for r in rs
              if len(r["truth"]) == 1 and (c := closed_at(r, dk)) is not None]
    dflt = rates(results, default)
    return {"held": held, "closed": closed, "default": dflt,
            "decisions": sum(correct_decisions(r) for r in results),
            "grid": sum(len(r["by_decision"]) for r in results)}


def _gap_text(closed: list[float]) -> str:
    return f"{min(closed):.0%} / {np.median(closed):.0%}" if closed else "-"


def same_verdict_gap_lines(pairs: list[tuple[dict, dict]], folds: dict, shown: int = 4) -> list[str]:
    """How the check-log gap closed moved where both runs name the truth under the second run's fold decision:
    a change that sizes effects differently, not what it names, shows here and nowhere else."""
    moves = []
    for r0, r1 in pairs:
        dk = folds[r1["family"]][0]
        if not r1["truth"] or verdict_at(r0, dk) != r1["truth"] or verdict_at(r1, dk) != r1["truth"]:
            continue
        c0, c1 = closed_at(r0, dk), closed_at(r1, dk)
        if c0 is not None and c1 is not None:
            moves.append((c1 - c0, c0, c1, r1))
    head = "check-log gap closed where both runs name the truth (held out, the second run's fold decisions):"
    if not moves:
        return [head, "  no such case"]
    d = sorted(m[0] for m in moves)
    lines = [head, f"  {len(moves)} cases: median change {float(np.median(d)):+.1%}, up by over 1 point "
                   f"{sum(x > 0.01 for x in d)}, down by over 1 point {sum(x < -0.01 for x in d)}; min "
                   f"{min(m[1] for m in moves):.0%} -> {min(m[2] for m in moves):.0%}"]
    by = sorted(moves, key=lambda m: m[0])
    for m in by[:shown] + [x for x in by[-shown:] if x not in by[:shown]]:
        r = m[3]
        lines.append(f"  {r['plant']:<24} c{r['case']:<3} {'+'.join(r['truth']):<22} {m[1]:.0%} -> {m[2]:.0%}")
    return lines


def comparison_table(before: list[dict], after: list[dict], default: str, label_before: str = "before",
                     label_after: str = "after") -> str:
    """Two runs on the same cases: the held-out figures of each (its own folds' choices), the shipped default's,
    the grid's correct decisions, per family, then every case whose verdict changed (under the default, or under
    its fold's decision in either run) and every case whose count of correct decisions moved."""
    pairs = matched(before, after)
    b = [p[0] for p in pairs]
    a = [p[1] for p in pairs]
    if not pairs:
        return "no case in both runs"
    fb, fa = lofo(b, default), lofo(a, default)
    xb, xa = _figures(b, fb, default), _figures(a, fa, default)
    lines = [f"{len(pairs)} cases in both ({len(before) - len(pairs)} only {label_before}, "
             f"{len(after) - len(pairs)} only {label_after})", "",
             f"{'':<44} {label_before:>16} {label_after:>16}"]

    def row(name: str, fn) -> None:
        lines.append(f"{name:<44} {fn(xb):>16} {fn(xa):>16}")

    row("held out: singles named exactly", lambda x: _pct(x["held"]["single_ok"], x["held"]["singles"]))
    row("held out: pairs named exactly", lambda x: _pct(x["held"]["pair_ok"], x["held"]["pairs"]))
    row("held out: false alarms", lambda x: _pct(x["held"]["false_alarms"], x["held"]["nones"]))
    row("held out: check-log gap closed, min / median", lambda x: _gap_text(x["closed"]))
    row("shipped default: singles", lambda x: _pct(x["default"]["single_ok"], x["default"]["singles"]))
    row("shipped default: pairs", lambda x: _pct(x["default"]["pair_ok"], x["default"]["pairs"]))
    row("shipped default: false alarms", lambda x: _pct(x["default"]["false_alarms"], x["default"]["nones"]))
    row("correct decisions over the grid", lambda x: f"{x['decisions']}/{x['grid']}")
    lines += ["", f"{'per family (held out)':<22} {'singles':>15} {'pairs':>13} {'false alarms':>14}   decision "
                  f"chosen on the others ({label_before} -> {label_after})"]
    for fam in sorted(fa):
        rb, ra = rates(fb[fam][1], fb[fam][0]), rates(fa[fam][1], fa[fam][0])
        cell = [f"{rb[k]}->{ra[k]}/{ra[n]}" for k, n in (("single_ok", "singles"), ("pair_ok", "pairs"),
                                                          ("false_alarms", "nones"))]
        dec = describe_decision(fb[fam][0])
        dec += "" if fa[fam][0] == fb[fam][0] else f" -> {describe_decision(fa[fam][0])}"
        lines.append(f"{fam:<22} {cell[0]:>15} {cell[1]:>13} {cell[2]:>14}   {dec}")
    lines += ["", "verdicts changed (shipped default; held out: each run's fold decision), check-log gap closed "
                  "under the default:"]
    changed = []
    for r0, r1 in pairs:
        d0, d1 = verdict_at(r0, default), verdict_at(r1, default)
        h0, h1 = verdict_at(r0, fb[r0["family"]][0]), verdict_at(r1, fa[r1["family"]][0])
        if d0 == d1 and h0 == h1:
            continue
        c0, c1 = closed_at(r0, default), closed_at(r1, default)
        gap = "" if c0 is None or c1 is None else f"; closed {c0:.0%} -> {c1:.0%}"
        changed.append(f"  {r1['plant']:<24} c{r1['case']:<3} truth {'+'.join(r1['truth']) or '[]':<22} default "
                       f"{'+'.join(d0) or '[]'} -> {'+'.join(d1) or '[]'}; held out {'+'.join(h0) or '[]'} -> "
                       f"{'+'.join(h1) or '[]'}{gap}")
    lines += changed or ["  none"]
    lines += ["", *same_verdict_gap_lines(pairs, fa)]
    moved = [(correct_decisions(r1) - correct_decisions(r0), r0, r1) for r0, r1 in pairs]
    moved = sorted((m for m in moved if m[0]), key=lambda m: (-abs(m[0]), case_id(m[2])))
    lines += ["", f"correct decisions moved ({len(moved)} cases; gained {sum(m[0] for m in moved if m[0] > 0)}, "
                  f"lost {-sum(m[0] for m in moved if m[0] < 0)}):"]
    lines += [f"  {r1['plant']:<24} c{r1['case']:<3} truth {'+'.join(r1['truth']) or '[]':<22} "
              f"{correct_decisions(r0)} -> {correct_decisions(r1)} of {len(r1['by_decision'])}"
              for _, r0, r1 in moved] or ["  none"]
    lines += ["", *paired_time_lines(pairs, label_before, label_after)]
    return "\n".join(lines)


def paired_time_lines(pairs: list[tuple[dict, dict]], label_before: str, label_after: str) -> list[str]:
    """The plain ``diagnose`` times of the cases both runs timed, case by case: the two runs were made at other
    times, so the machine's load moves each ratio; the median over many cases is what the code changed."""
    timed = [(r0["seconds"], r1["seconds"], r1) for r0, r1 in pairs
             if r0.get("seconds") is not None and r1.get("seconds") is not None]
    if not timed:
        return ["plain diagnose time: no case timed in both runs"]
    ratios = sorted(t1 / t0 for t0, t1, _ in timed)
    slow = max(timed, key=lambda x: x[1])
    over = TARGETS["seconds"]
    return [f"plain diagnose time, the {len(timed)} cases timed in both runs (each run on its own day and load, "
            f"so one case's ratio is noisy): ratio {label_after} / {label_before} median "
            f"{float(np.median(ratios)):.2f} (middle half {ratios[len(ratios) // 4]:.2f}-"
            f"{ratios[(3 * len(ratios)) // 4]:.2f}); median {float(np.median([t[0] for t in timed])):.1f} -> "
            f"{float(np.median([t[1] for t in timed])):.1f} s; over {over:.0f} s {sum(t[0] > over for t in timed)} "
            f"-> {sum(t[1] > over for t in timed)}; slowest in {label_after}: {slow[2]['plant']} c{slow[2]['case']}, "
            f"{slow[0]:.1f} -> {slow[1]:.1f} s"]
