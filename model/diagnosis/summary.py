"""A readable summary of a diagnosis report, one line each."""

from __future__ import annotations

import math


def _fmt_params(d: dict) -> str:
    return ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in d.items())


def summary_lines(rep: dict) -> list[str]:
    """A readable summary of a report, one line each."""
    lines = []
    where = rep["where"]
    sh = rep["shrinkage"]
    chk = rep.get("model_error_from_check")
    on_check = (", measured on its check log of another input" + (f" ({chk['log']})" if chk.get("log") else "")
                if chk and chk.get("set_it") else "")
    lines.append(f"residual RMS {where['rms_deg']:.4f} deg against a floor of {where['floor_deg']:.4f} deg "
                 f"(noise {rep['noise_deg']:.4f}, model's known error {rep['model_error_deg']:.4f}{on_check})")
    em = rep.get("model_error_model") or {}
    if em.get("used"):
        lines.append(f"bench model error: {em['bench_rms_before_deg']:.4f} deg RMS on the bench, "
                     f"{em['bench_rms_after_deg']:.4f} with its correction ({', '.join(em['feature_sets']) or 'none'})"
                     "; the field is judged against the corrected model")
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
                f"{a.get('heldout_rms_after_deg', math.nan):.4f} deg, p={a.get('p_value', 1.0):.2g}, "
                f"{a.get('share_of_gap', 0.0):.0%} of the gap")
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
    for h in rep.get("bound_hits", []):
        lines.append(f"at a bound: {h['meaning']}")
    verdict = rep["verdict"]
    if verdict:
        gc = sh["gap_closed"]
        lines.append(f"verdict: {', '.join(verdict)}; held-out RMS {sh['heldout_rms_before_deg']:.4f} -> "
                     f"{sh['heldout_rms_after_deg']:.4f} deg, gap closed "
                     + (f"{gc:.0%}" if gc is not None else "n/a"))
        nominal = rep.get("nominal_effects") or {}
        for n, p in rep["effects"].items():  # e.g. a field delay on top of the rig's own, which identify found
            was = nominal.get(n)
            lines.append(f"  {n}: {_fmt_params(p)}" + (f" (the model had {_fmt_params(was)})" if was else ""))
        for n, k in (rep.get("kept_unnamed") or {}).items():  # in the augmented model, as the note says
            lines.append(f"  kept in the model, not named: {n}: {_fmt_params(k['fitted'])}")
    else:
        lines.append("verdict: [] (no effect explains the gap beyond noise and the model's known error)")
    lines.extend(f"note: {n}" for n in rep["notes"])
    return lines
