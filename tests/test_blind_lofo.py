"""The blind benchmark's fold choice: a decision is chosen by the per-family targets, then by the pooled rates."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import blind_lofo  # noqa: E402

A, B = '{"alpha": 0.05}', '{"alpha": 0.001}'


def case(family: str, truth: list[str], right: dict[str, bool]) -> dict:
    wrong = ["drift"] if truth != ["drift"] else ["delay"]
    return {"family": family, "truth": truth, "check_rms_nominal": 0.0, "check_rms_nominal_without_effects": 0.0,
            "by_decision": {dk: {"verdict": truth if ok else wrong} for dk, ok in right.items()}}


def results() -> list[dict]:
    """Family x: every single right under both. Family y: A names its pairs but misses 2 of 20 singles (90 %,
    under the 95 % target); B misses one single and 2 of 10 pairs (95 % and 80 %: both on target)."""
    out = [case("x", ["friction"], {A: True, B: True}) for _ in range(20)]
    out += [case("y", ["friction"], {A: k >= 2, B: k >= 1}) for k in range(20)]
    out += [case("y", ["backlash", "friction"], {A: True, B: k >= 2}) for k in range(10)]
    return out


def test_the_pooled_mean_alone_would_pick_the_decision_that_leaves_a_family_below_target():
    rs = results()
    assert blind_lofo.score(blind_lofo.rates(rs, A)) > blind_lofo.score(blind_lofo.rates(rs, B))
    assert blind_lofo.merit(rs, A)[0] == -0.05  # family y's singles 5 points under 95 %
    assert blind_lofo.merit(rs, B)[0] == 0.0  # every family on its targets
    assert blind_lofo.choose(rs, [A, B], default=A) == B


def test_equal_merit_keeps_the_default():
    rs = [case("x", ["friction"], {A: True, B: True}) for _ in range(5)]
    assert blind_lofo.choose(rs, [A, B], default=B) == B
    assert blind_lofo.choose(rs, [B, A], default=A) == A


def test_shortfall_sums_each_rate_below_its_target():
    rt = {"single_rate": 0.90, "pair_rate": 0.70, "fa_rate": 0.10}
    assert abs(blind_lofo.shortfall(rt) - (0.05 + 0.10 + 0.05)) < 1e-12
    assert blind_lofo.shortfall({"single_rate": 1.0, "pair_rate": float("nan"), "fa_rate": 0.0}) == 0.0


# full decisions, as the benchmark stores them (the comparison describes them)
C = '{"alpha": 0.05, "min_gain": 0.5, "min_share": 0.1}'
D = '{"alpha": 0.001, "min_gain": 0.5, "min_share": 0.1}'


def run_case(family: str, k: int, truth: list[str], right: dict[str, bool]) -> dict:
    r = case(family, truth, right)
    return r | {"seed": 0, "plant_index": 0, "case": k, "plant": f"{family}-s0-0"}


def test_comparison_counts_the_grid_and_lists_what_moved():
    before = [run_case("x", k, ["friction"], {C: True, D: True}) for k in range(4)]
    before += [run_case("y", 10, ["backlash"], {C: False, D: False})]
    after = [run_case("x", k, ["friction"], {C: True, D: k != 3}) for k in range(4)]  # case 3 loses under D
    after += [run_case("y", 10, ["backlash"], {C: True, D: False})]  # gains under C, the default
    after += [run_case("y", 11, ["backlash"], {C: True, D: True})]  # only in the new run
    assert [blind_lofo.correct_decisions(r) for r in after] == [2, 2, 2, 1, 1, 2]
    assert len(blind_lofo.matched(before, after)) == 5
    text = blind_lofo.comparison_table(before, after, C, "old", "new")
    assert "5 cases in both (0 only old, 1 only new)" in text
    grid = next(line for line in text.splitlines() if line.startswith("correct decisions over the grid"))
    assert grid.split()[-2:] == ["8/10", "8/10"]  # one gained, one lost; the case only in the new run not counted
    changed = text.split("verdicts changed")[1].split("correct decisions moved")[0]
    assert "y-s0-0" in changed and "default drift -> backlash" in changed
    assert "x-s0-0" not in changed  # its default verdict did not move
    moved = text.split("correct decisions moved")[1]
    assert "(2 cases; gained 1, lost 1)" in moved
    assert "1 -> 2 of 2" not in moved and "2 -> 1 of 2" in moved and "0 -> 1 of 2" in moved


def test_comparison_pairs_the_times_of_the_cases_both_runs_timed():
    before = [run_case("x", k, ["friction"], {C: True}) | {"seconds": s} for k, s in enumerate((10.0, 20.0, 40.0))]
    after = [run_case("x", k, ["friction"], {C: True}) | {"seconds": s} for k, s in enumerate((11.0, None, 36.0))]
    line = blind_lofo.comparison_table(before, after, C, "old", "new").splitlines()[-1]
    assert line.startswith("plain diagnose time, the 2 cases timed in both runs")
    assert "median 1.00" in line  # the ratios 1.1 and 0.9; the case the new run did not time is left out
    assert "over 30 s 1 -> 1" in line and "x-s0-0 c2, 40.0 -> 36.0 s" in line
    untimed = [run_case("x", 0, ["friction"], {C: True})]
    assert blind_lofo.comparison_table(untimed, untimed, C).endswith("no case timed in both runs")


def test_comparison_of_runs_without_shared_cases_says_so():
    a = [run_case("x", 0, ["friction"], {C: True})]
    b = [run_case("x", 1, ["friction"], {C: True})]
    assert blind_lofo.comparison_table(a, b, C) == "no case in both runs"


def missed(truth: list[str], drawn: dict[str, float], effect_rms: float) -> dict:
    r = run_case("x", 0, truth, {C: False})
    return r | {"magnitude_x_noise": drawn, "noise": 0.05, "effect_rms_deg": effect_rms, "bench_misfit_deg": 0.1}


def test_a_single_effect_short_of_its_drawn_size_is_marked_in_the_misses():
    capped = missed(["rate_limit"], {"rate_limit": 20.0}, 0.05 * 8.0)
    full = missed(["friction"], {"friction": 6.0}, 0.05 * 6.0)
    pair = missed(["backlash", "friction"], {"backlash": 5.0, "friction": 5.0}, 0.05 * 2.0)
    assert abs(blind_lofo.reached_x_noise(capped) - 8.0) < 1e-9
    assert blind_lofo.reached_x_noise(full) is None and blind_lofo.reached_x_noise(pair) is None
    lines = blind_lofo.misses([capped, full, pair], default=C).splitlines()
    assert len(lines) == 3
    assert "rate_limit 20.0x noise drawn, 8.0x reached: its size search ended at its cap" in lines[0]
    assert "reached" not in lines[1] and "reached" not in lines[2]
