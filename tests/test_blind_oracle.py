"""The blind benchmark's miss classes: search (the test would name the true set), test, log (no better fit)."""

import sys
from pathlib import Path
from types import SimpleNamespace

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import blind_oracle  # noqa: E402

from warpbridge.model.diagnosis.options import Decision  # noqa: E402

D = Decision()  # level 0.05 over the effects tried, material gain half the floor


def fit(names: tuple[str, ...], score: float, train: float | None = None) -> SimpleNamespace:
    return SimpleNamespace(names=names, score_mse=score, train_mse=score if train is None else train)


class Explorer:
    """The part of ``diagnose.Explorer`` the classification asks: fits by order of entry, the paired gain
    (a given p-value, the gain from the scored MSEs) and the admission test (which effects pass)."""

    def __init__(self, fits: dict, p: float, fails: tuple[str, ...] = ()) -> None:
        self.names = ["delay", "backlash", "friction", "drift"]
        self.floor2 = 0.01
        self.nominal = fit((), 0.1)
        self.fits, self.p, self.fails = fits, p, fails
        self.finals: list[tuple[str, ...]] = []

    def fit_of(self, order):
        return self.fits[order]

    def final(self, selected, cur):
        self.finals.append(selected)
        return cur

    def gain(self, old, new):
        return SimpleNamespace(gain=old.score_mse - new.score_mse, p_value=self.p)

    def admits(self, d, old, new):
        # the effect that ``new`` adds over ``old`` passes unless it is one of ``fails``
        added = set(new.names) - set(old.names)
        return not (added & set(self.fails))


def pair_explorer(p: float, truth_mse: float, fails: tuple[str, ...] = ()) -> Explorer:
    return Explorer({("backlash", "friction"): fit(("backlash", "friction"), truth_mse, 0.02),
                     ("friction", "backlash"): fit(("friction", "backlash"), truth_mse + 1e-3, 0.03),
                     ("backlash",): fit(("backlash",), 0.04), ("friction",): fit(("friction",), 0.05)}, p, fails)


def classify(ex: Explorer, verdict_mse: float) -> dict:
    truth = ("backlash", "friction")
    return blind_oracle.classify(ex, D, fit(("backlash",), verdict_mse), blind_oracle.true_fit(ex, truth), truth)


def test_the_true_set_is_its_best_order_of_entry_refitted_jointly():
    ex = pair_explorer(1e-9, 0.02)
    f = blind_oracle.true_fit(ex, ("backlash", "friction"))
    assert f.names == ("backlash", "friction")  # the order with the lower training MSE
    assert ex.finals == [("backlash", "friction")]
    assert blind_oracle.true_fit(ex, ()) is ex.nominal


def test_a_true_set_the_test_would_name_is_the_searchs_miss():
    out = classify(pair_explorer(1e-9, 0.02), verdict_mse=0.04)  # gain 0.02: twice the floor
    assert out["class"] == "search"
    assert out["each_passes"] == {"backlash": True, "friction": True}


def test_a_gain_under_half_the_floor_is_the_tests_miss():
    out = classify(pair_explorer(1e-9, 0.02), verdict_mse=0.024)  # gain 0.004 < 0.005
    assert out["class"] == "test" and not out["material"]


def test_an_effect_of_the_true_set_failing_the_test_is_the_tests_miss():
    out = classify(pair_explorer(1e-9, 0.02, fails=("friction",)), verdict_mse=0.04)
    assert out["class"] == "test"
    assert out["each_passes"] == {"backlash": True, "friction": False}


def test_a_true_set_no_better_on_the_scored_blocks_is_the_logs():
    # significant at 0.05 alone, not at 0.05 over the four effects tried
    assert classify(pair_explorer(0.02, 0.02), verdict_mse=0.04)["class"] == "log"
    # the verdict fits better
    assert classify(pair_explorer(1e-9, 0.05), verdict_mse=0.04)["class"] == "log"
