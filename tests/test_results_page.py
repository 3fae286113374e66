"""docs/results.md is what benchmarks/results_page.py makes of the archives, and the page says whose figures
they are: this code's, or (stale) the sources the newest archive was computed on."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import results_page  # noqa: E402
from blind_archive import case_file, write_rows  # noqa: E402
from blind_lofo import key  # noqa: E402
from stored import imported_sources, sources_hash, sources_match  # noqa: E402

DEFAULT = key({"alpha": 0.05, "min_gain": 0.5, "min_share": 0.1})
NOTHING = key({"alpha": 0.001, "min_gain": 2.0, "min_share": 0.5})  # a decision that names nothing
FAMILIES = ("dahl", "sheath")


def result(fam: str, seed: int, k: int, truth: list[str], verdict: list[str], sources: str) -> dict:
    """A case result as the blind benchmark stores it, reduced to what the scoring reads."""
    return {"family": fam, "seed": seed, "plant_index": 0, "case": k, "plant": f"{fam}-s{seed}-0", "truth": truth,
            "verdict": verdict, "default_decision": DEFAULT, "sources": sources, "seconds": 10.0 + k,
            "by_decision": {DEFAULT: {"verdict": verdict, "gap_closed": 0.9, "gap_closed_bare": 0.8},
                            NOTHING: {"verdict": [], "gap_closed": 0.0, "gap_closed_bare": 0.0}},
            "check_rms_nominal": 0.2, "check_rms_nominal_without_effects": 0.1, "check_rms_bare": 0.2,
            "check_rms_bare_without_effects": 0.1, "effect_rms_deg": 0.1, "bench_misfit_deg": 0.01}


def archive(folder: Path, sources: str, miss: bool = False) -> Path:
    """An archive of two families, seeds 0, 1, 2 and 9: per plant a no-effect case, two singles and a pair, all
    named right under the default (``miss``: the pair of seed 9's sheath named as one of its effects)."""
    rows = []
    for fam in FAMILIES:
        for seed in (0, 1, 2, 9):
            cases = [([], []), (["delay"], ["delay"]), (["drift"], ["drift"]), (["drift", "friction"],) * 2]
            for k, (truth, verdict) in enumerate(cases):
                if miss and (fam, seed, k) == ("sheath", 9, 3):
                    verdict = ["drift"]
                rows.append((case_file((fam, seed, 0, k)), result(fam, seed, k, truth, verdict, sources)))
    name = results_page.results_dir(Path("."), magnitude=results_page.MAGNITUDE).name
    out = folder / f"{name[:-12]}{sources}{results_page.SUFFIX}"
    write_rows(out, sorted(rows))
    return out


def realdata(folder: Path, sources: str) -> None:
    """bench_diagnose_realdata's figures as ``--json`` writes them: one bend named a pre-tension."""
    rec = {"benchmark": "bench_diagnose_realdata", "sources": sources, "data": "tsm-kaist", "base": "0",
           "identified": {"train_rms_deg": 0.76, "heldout_rms_deg": 0.95, "noise_deg": 0.06},
           "logs": [{"log": "120", "verdict": ["pretension"], "effects": {"pretension": {"pretension_gain": 0.75}},
                     "kept_unnamed": {}, "ambiguous": [], "heldout_rms_before_deg": 11.57,
                     "heldout_rms_after_deg": 1.02, "gap_closed": 0.99,
                     "other_logs": [{"log": "60", "nominal_rms_deg": 6.8, "augmented_rms_deg": 4.44}]}]}
    (folder / f"realdata-diagnose-{sources}.json").write_text(json.dumps(rec))


def sitl(folder: Path, files_hash: str | None = None) -> None:
    """bench_sitl_compare's figures as ``--json`` writes them: two seeds calm, one in gusts, the paper's beside."""
    paper = {"open": 1.727, "pi": 2.04, "ff+pi": 0.285}

    def row(scenario, mode, window, rms, label=""):
        return {"scenario": scenario, "mode": mode, "label": label, "rms_deg": rms, "window_s": window,
                "paper_deg": None if label else paper.get(mode)}

    calm = [row("random", m, w, [base * f, base * f * 1.2]) for w, f in (([1.0, 20.0], 1.1), ([15.0, 60.0], 1.0))
            for m, base in (("open", 1.0), ("pi", 0.5), ("ff", 0.3), ("ff+pi", 0.1))]
    calm.append(row("random", "pi", [15.0, 60.0], [0.8, 0.9], "paper-horn gains"))
    gusts = [row(g, m, [5.0, 30.0], [0.2]) for g in ("gust7", "gust12") for m in ("open", "pi", "ff", "ff+pi")]
    files = ["model/boucwen.py"]
    rec = {"benchmark": "bench_sitl_compare", "seeds": 2, "few_seeds": 1, "pretension_change": 1.4,
           "friction_change": 1.15, "like_for_like": calm + gusts, "upper_bound": calm[:8],
           "sources": {"files": files, "hash": files_hash or sources_hash(files)}}
    (folder / results_page.SITL).write_text(json.dumps(rec))


def margins(folder: Path) -> None:
    """bench_margins's figures as ``--json`` writes them, its table's cells as it prints them."""
    files = ["model/boucwen.py"]
    rec = {"benchmark": "bench_margins", "delay_ms": 1.0, "measured": False, "loop_hz": 100.0, "servo_tau_ms": 20.0,
           "slopes_deg_per_mm": {"paper wing": 1.9}, "header": ["gains", "gain margin"],
           "rows": [["default", "2.70 (8.6 dB)"], ["paper-horn", "1.10 (0.8 dB)"]],
           "sources": {"files": files, "hash": sources_hash(files)}}
    (folder / results_page.MARGINS).write_text(json.dumps(rec))


def field_tuning(folder: Path) -> None:
    """bench_field_tuning's figures as ``--json`` writes them (keys sorted, the methods' order kept apart)."""
    files = ["model/boucwen.py"]
    rec = {"benchmark": "bench_field_tuning", "rigged_s": 60.0, "drift_s": 300.0, "seed": 0, "drift_mm": 0.61,
           "methods": ["matched", "stale", "cal+adapt"], "ffpi_gains": [0.7, 20.0],
           "rigged": {"pretension": {"pretension_offset_mm": 0.8, "pretension_gain": 1.1}},
           "rows": [{"condition": "rigged", "mode": "ff",
                     "rms_deg": {"cal+adapt": 0.12, "matched": 0.1, "stale": 0.5}}],
           "failures": [{"failure": "sensor stuck", "rms_before_deg": 0.1, "rms_adapt_on_deg": 0.3,
                         "rms_adapt_off_deg": 0.2, "offset_moved_mm": 0.05}],
           "sources": {"files": files, "hash": sources_hash(files)}}
    (folder / results_page.FIELD_TUNING).write_text(json.dumps(rec, sort_keys=True))


def test_the_page_shows_this_codes_archive_with_the_default_and_the_code_before_beside(tmp_path):
    here = results_page.source_hash(results_page.DIAG_SOURCES)
    archive(tmp_path, here)
    archive(tmp_path, "000000000000", miss=True)  # not in git: ordered by name, so it counts as older
    realdata(tmp_path, here)
    sitl(tmp_path)
    margins(tmp_path)
    field_tuning(tmp_path)
    inp = results_page.gather(tmp_path)
    assert inp.current and inp.shown.sources == here and inp.before.sources == "000000000000"
    text = results_page.render(inp)
    assert "Stale" not in text and f"These are the figures of this code: its diagnosis sources hash to `{here}`" \
        in text
    # every single named, under the decision chosen on the other family (the default: the other names nothing)
    assert "| **pooled** | each family's own | 8/8 (100%) | 4/4 (100%) | 0/4 | 90% / 90% | 8/8, 4/4, 0/4, 90% |" \
        in text
    # the code before missed one pair of the fresh seeds
    assert "| the code before (sources 000000000000), pooled | each family's own | 8/8 (100%) | 3/4 (75%) |" in text
    assert "| bend 120 | `pretension` (pretension_gain 0.75) | 11.57 -> 1.02 (99%) | bend 60: 6.80 -> 4.44 |" in text
    # the SITL table: each mode's mean and range over seeds, the PI with the paper's gains, the paper's row
    assert ("| scenario | open loop | PI only | feed-forward | feed-forward + PI | PI only, paper-horn gains |"
            in text)
    assert "| calm, settled | 1.100 (1.000-1.200) | 0.550 (0.500-0.600) | 0.330 (0.300-0.360) |" in text
    assert "| gusts 12 m/s | 0.200 | 0.200 | 0.200 | 0.200 |  |" in text
    assert "| paper, bench (Lee et al. 2017) | 1.727 | 2.04 |  | 0.285 |  |" in text
    assert "| gains | gain margin |\n| --- | --- |\n| default | 2.70 (8.6 dB) |\n| paper-horn | 1.10 (0.8 dB) |" in text
    assert "(paper wing: 1.90 deg/mm)" in text
    assert "| rigged | ff | 0.100 | 0.500 (5.00x) | 0.120 (1.20x) |" in text
    assert "by `pretension` (pretension_gain 1.1, pretension_offset_mm 0.8), flown 60 s" in text
    assert "| sensor stuck | 0.100 | 0.300 | 0.200 | 0.050 |" in text
    assert results_page.render(results_page.gather(tmp_path)) == text  # the same inputs give the same page


def test_without_this_codes_results_every_table_says_it_is_stale(tmp_path):
    archive(tmp_path, "0123456789ab")
    realdata(tmp_path, "ba9876543210")
    sitl(tmp_path, files_hash="000000000000")
    text = results_page.render(results_page.gather(tmp_path))
    assert "**Stale: no archive holds this code's results**" in text
    tables = text.count("\n### ")
    assert tables == 5 and text.count("**Stale: of the sources `0123456789ab`, not of this code.**") == tables
    assert "**Stale: of the sources `ba9876543210`, not of this code**" in text
    assert "**Stale: of the sources `000000000000`; some of the files that run imported have changed since.**" \
        in text


def test_stored_figures_are_keyed_by_the_project_files_the_process_imported(tmp_path):
    files = imported_sources()
    assert "benchmarks/results_page.py" in files and "bridge/commands/diagnose.py" in files
    assert all((ROOT / f).is_file() for f in files)  # every one a file of this repository
    (tmp_path / "model").mkdir()
    (tmp_path / "model" / "a.py").write_text("x = 1\n")
    rec = {"sources": {"files": ["model/a.py"], "hash": sources_hash(["model/a.py"], tmp_path)}}
    assert sources_match(rec, tmp_path)
    (tmp_path / "model" / "a.py").write_text("x = 2\n")
    assert not sources_match(rec, tmp_path)


def test_check_says_whether_the_page_is_up_to_date(tmp_path, capsys):
    (tmp_path / "a").mkdir()
    archive(tmp_path / "a", "0123456789ab")
    page = tmp_path / "results.md"
    args = ["--archives", str(tmp_path / "a"), "--out", str(page)]
    assert results_page.main([*args, "--check"]) == 1 and not page.exists()
    assert results_page.main(args) == 0
    assert results_page.main([*args, "--check"]) == 0
    page.write_text(page.read_text().replace("8/8", "7/8"))
    assert results_page.main([*args, "--check"]) == 1
    assert "out of date" in capsys.readouterr().err


def test_docs_results_is_up_to_date_with_the_archives_and_this_code():
    text = (ROOT / "docs" / "results.md").read_text(encoding="utf-8")
    recorded = results_page.page_digest(text)
    assert recorded is not None, "docs/results.md does not say what it was made from"
    inputs = results_page.gather()
    if inputs.ordered_by == results_page.NO_HISTORY:
        pytest.skip("no whole git history (a shallow clone or an unpacked sdist): the archives' order is unknown")
    assert recorded == results_page.inputs_digest(inputs), (
        "docs/results.md is out of date (the archives, the diagnosis sources or the page's scripts changed): run "
        "python benchmarks/results_page.py")


@pytest.mark.parametrize("line", ["# Measured figures", "<!-- hand-written -->"])
def test_a_page_without_the_generated_first_line_records_no_digest(line):
    assert results_page.page_digest(line + "\n") is None


def test_no_stored_result_or_page_names_a_path_of_the_machine_that_made_it():
    """Results and docs are read on other machines: a temporary or home folder written into them (a benchmark's
    ``--resume`` argument stored as given) means nothing there."""
    machine = re.compile(r"(?<![\w.~-])/(?:tmp|home|root|work|Users|var/folders)/")
    files = [*ROOT.glob("*.md"), *(ROOT / "docs").rglob("*.md"), *(ROOT / "benchmarks" / "results").rglob("*.json"),
             *(ROOT / "benchmarks" / "results").rglob("*.md")]
    assert len(files) > 5
    found = [f"{f.relative_to(ROOT)}: {m.group(0)}" for f in files
             for m in [machine.search(f.read_text(encoding="utf-8"))] if m]
    assert found == []


def seed_log(name: str, train: list[float], held: list[float]) -> dict:
    """One bench log of bench_identify_seeds' output, reduced to what the page reads."""
    runs = [{"seed": i, "train_rms_deg": tr, "heldout_rms_deg": h, "seconds": 3.0} for i, (tr, h) in
            enumerate(zip(train, held, strict=True))]
    summary = {"min": min(held), "median": sorted(held)[len(held) // 2], "max": max(held),
               "spread": max(held) / min(held), "seconds_median": 3.0, "default_heldout_rms_deg": held[0]}
    return {"set": "bench", "log": name, "plant": "paper", "open_loop_bench": True, "noise_deg": 0.05,
            "line_heldout_rms_deg": 1.0, "runs": {"new": runs, "old": runs[:1]}, "new": summary,
            "old": summary | {"min": held[0], "median": held[0], "max": held[0], "spread": 1.0},
            "default_over_old_best": 1.0}


def test_the_seed_table_gives_the_training_spread_beside_the_held_out_one(tmp_path):
    """Seeds that agree on the training part but not held out are told apart from seeds whose training fits
    differ: the first log agrees within 1 % on training only, the second on neither, the third on both."""
    logs = [seed_log("flat valley", [0.0500, 0.0502, 0.0503], [0.060, 0.064, 0.062]),
            seed_log("two basins", [0.40, 0.52, 0.41], [0.70, 0.90, 0.71]),
            seed_log("one answer", [0.0500, 0.0500, 0.0501], [0.0510, 0.0511, 0.0510])]
    path = tmp_path / "identify-seeds.json"
    path.write_text(json.dumps({"seeds": 3, "baseline": "abc1234", "merged_from": None, "finished": "x",
                                "logs": logs}), encoding="utf-8")
    page = "\n".join(results_page.identify_seeds_section(SimpleNamespace(identify_seeds=path)))
    summary = next(line for line in page.splitlines() if line.startswith("| Simulated bench logs"))
    assert "| 1/3 (2/3) |" in summary
    rows = {line.split(" | ")[0].strip("| "): line.split(" | ") for line in page.splitlines()
            if line.startswith(("| flat valley", "| two basins", "| one answer"))}
    assert rows["flat valley"][5] == "1.006" and rows["flat valley"][4] == "1.067"
    assert rows["two basins"][5] == "1.300"
    assert rows["one answer"][5] == "1.002"


def test_closed_loop_logs_are_set_against_their_own_runs_true_tendon_travel(tmp_path):
    """Beside the plant's open-loop bench log, each closed-loop log gets the fit of its own run's true tendon travel:
    a log at 1.6x the bench but 1.1x its own run's travel is the excitation's, not the closed loop's."""
    bench = seed_log("sheath open-loop bench", [0.25, 0.25], [0.30, 0.30]) | {"set": "sitl", "plant": "sheath"}
    sweep = seed_log("sheath sweep s0 left", [0.24, 0.25], [0.48, 0.50]) | {
        "set": "sitl", "plant": "sheath", "open_loop_bench": False,
        "true_travel": {"heldout_rms_deg": 0.40, "train_rms_deg": 0.23, "seconds": 1.0, "samples": 4000}}
    steps = seed_log("sheath steps s0 left", [0.06, 0.06], [0.09, 0.09]) | {
        "set": "sitl", "plant": "sheath", "open_loop_bench": False,
        "true_travel": {"heldout_rms_deg": 0.10, "train_rms_deg": 0.05, "seconds": 1.0, "samples": 4000}}
    path = tmp_path / "identify-seeds.json"
    path.write_text(json.dumps({"seeds": 2, "baseline": "abc1234", "merged_from": None, "finished": "x",
                                "logs": [bench, sweep, steps]}), encoding="utf-8")
    page = "\n".join(results_page.identify_seeds_section(SimpleNamespace(identify_seeds=path)))
    rows = {line.split(" | ")[0].strip("| "): line.split(" | ") for line in page.splitlines()
            if line.startswith("| sheath")}
    assert rows["sheath sweep s0 left"][9] == "0.400 (1.20x)"
    assert rows["sheath steps s0 left"][9] == "0.100 (0.90x)"
    assert rows["sheath open-loop bench"][9] == "-"
    line = next(x for x in page.splitlines() if x.startswith("Closed-loop logs within 1.5x"))
    assert "sheath 1/2 (median 0.95x, max 1.60x)" in line
    assert ("Against the same run's true tendon travel: sheath median 1.05x, max 1.20x (the true travel's own fit "
            "0.33-1.33x the open-loop bench log)") in line
