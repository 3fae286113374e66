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
