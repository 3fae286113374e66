"""identify --check: the model scored on a second bench log of another input, and diagnose's known error from it.

The rig is the capstan sheath of ``sitl.sheath`` with a heavy wrap (380 deg at mu 0.30: a tension ratio of
about 7): its friction holds a memory of many reversals, and a model identified on a random input misses a
sweep several times worse than its own bench log.
"""

import contextlib
import io
import json
import math

import numpy as np
import pytest

from warpbridge.bridge.cli import main
from warpbridge.model import excitation
from warpbridge.model.diagnosis.check import known_error_on_check
from warpbridge.sitl.sheath import SheathParams, SheathPlant

RATE = 200.0
HEAVY = SheathParams(bend_deg=380.0, mu=0.30, n_segments=20, k_tendon=3.8, k_wing=1.0, pretension_n=0.37,
                     mm_per_deg=0.5, hardening=0.45, slack_mm=1.5, slack_n=0.5)


def run(*args):
    return main([str(a) for a in args])


def write(path, t, u, w):
    np.savetxt(path, np.c_[t, u, w], delimiter=",", header="t,u,warp", comments="", fmt="%.9g")


@pytest.fixture(scope="module")
def heavy(tmp_path_factory):
    d = tmp_path_factory.mktemp("heavy")
    lo, hi = SheathPlant(HEAVY).travel_range(2.0)[1], SheathPlant(HEAVY).travel_range(12.0)[1]
    off, amp = 0.5 * (lo + hi), 0.5 * (hi - lo)
    rng = np.random.default_rng(1)
    for name, dur, kind in (("bench", 40, "random"), ("check", 30, "sweep"), ("field", 20, "multisine")):
        t = np.arange(int(dur * RATE)) / RATE
        if kind == "random":
            u = excitation.filtered_random(t, 1.2, amp, off, seed=3)
        elif kind == "sweep":
            u = excitation.sweep(t, 0.2, 2.0, amp, off)
        else:
            u = excitation.multisine_reversals(t, (0.6 * amp, 0.28 * amp, 0.12 * amp), (0.3, 1.1, 2.7), off)
        write(d / f"{name}.csv", t, u, SheathPlant(HEAVY, u0=0.0).simulate(u, 0.0) + 0.03 * rng.standard_normal(t.size))
    return d


@pytest.fixture(scope="module")
def heavy_models(heavy):
    """The model identified with the check log (its output), and the same model without the check's record:
    what identify writes without --check, as the check scores the model and does not change the fit
    (``test_the_check_log_scores_the_model_and_leaves_the_fit_as_it_is``)."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert run("identify", heavy / "bench.csv", "-o", heavy / "checked.json", "--quiet", "--maxiter", 60,
                   "--check", heavy / "check.csv") == 0
    plain = json.loads((heavy / "checked.json").read_text())
    del plain["fit"]["check"]
    (heavy / "plain.json").write_text(json.dumps(plain))
    return {"checked": buf.getvalue()}


def test_the_check_log_scores_the_model_and_leaves_the_fit_as_it_is(tmp_path, capsys):
    assert run("simulate", "-o", tmp_path / "bench.csv", "--duration", 10, "--rate", 100, "--seed", 1) == 0
    assert run("simulate", "-o", tmp_path / "check.csv", "--duration", 10, "--rate", 100, "--excitation",
               "sweep", "--seed", 2) == 0
    for tag, extra in (("checked", ["--check", tmp_path / "check.csv"]), ("plain", [])):
        assert run("identify", tmp_path / "bench.csv", "-o", tmp_path / f"{tag}.json", "--quiet", *extra) == 0
    out = capsys.readouterr().out
    assert out.count("check log check.csv") == 1
    m, plain = (json.loads((tmp_path / f"{tag}.json").read_text()) for tag in ("checked", "plain"))
    assert "check" in m["fit"] and "check" not in plain["fit"]
    assert plain["params"] == m["params"] and plain["effects"] == m["effects"]


@pytest.mark.slow
def test_identify_scores_the_check_log_and_warns_when_the_model_does_not_carry(heavy, heavy_models):
    m = json.loads((heavy / "checked.json").read_text())
    chk = m["fit"]["check"]
    assert chk["log"] == "check.csv" and chk["samples"] == int(29 * RATE)
    assert chk["rms_bare_deg"] > chk["rms_corrected_deg"] > chk["known_error_corrected_deg"] > 0
    bench_known = m["model_error"]["bench_rms_after_deg"]
    assert chk["known_error_corrected_deg"] > 3 * bench_known  # the sweep is missed far worse than the bench
    assert "check log check.csv" in heavy_models["checked"]
    assert "warning: the model misses the check log" in heavy_models["checked"]


@pytest.mark.slow
def test_diagnose_takes_the_check_logs_error_as_the_known_error_when_larger(heavy, heavy_models, capsys):
    reports = {}
    for tag in ("checked", "plain"):
        assert run("diagnose", heavy / "field.csv", "--model", heavy / f"{tag}.json", "--report",
                   heavy / f"r-{tag}.json", "--quiet", "--jobs", 1) == 0
        reports[tag] = json.loads((heavy / f"r-{tag}.json").read_text())
    capsys.readouterr()
    m = json.loads((heavy / "checked.json").read_text())
    on_check = m["fit"]["check"]["known_error_corrected_deg"]
    assert reports["checked"]["model_error_deg"] == pytest.approx(on_check)
    assert reports["checked"]["model_error_from_check"]["set_it"] is True
    assert "measured on its check log of another input (check.csv)" in reports["checked"]["summary"][0]
    assert reports["plain"]["model_error_deg"] < 0.5 * on_check
    assert reports["plain"]["model_error_from_check"] is None
    assert "check log" not in reports["plain"]["summary"][0]
    assert reports["checked"]["floor_deg"] > reports["plain"]["floor_deg"]


@pytest.mark.slow
def test_a_check_log_the_model_carries_to_gives_no_warning_and_keeps_the_bench_error(tmp_path, capsys):
    # the paper's own Bouc-Wen plant: identified on a random input, it predicts a multisine as well
    assert run("simulate", "-o", tmp_path / "bench.csv", "--duration", 30, "--rate", RATE, "--seed", 1) == 0
    assert run("simulate", "-o", tmp_path / "check.csv", "--duration", 20, "--rate", RATE, "--excitation",
               "multisine", "--seed", 2) == 0
    capsys.readouterr()
    assert run("identify", tmp_path / "bench.csv", "-o", tmp_path / "m.json", "--quiet", "--maxiter", 60,
               "--check", tmp_path / "check.csv") == 0
    out = capsys.readouterr().out
    assert "check log check.csv" in out and "warning" not in out
    chk = json.loads((tmp_path / "m.json").read_text())["fit"]["check"]
    assert chk["rms_corrected_deg"] < 1.5 * chk["noise_deg"]
    # a check that misses nothing beyond its noise (as the bench, or less): diagnose keeps the bench's known
    # error and does not credit the check log with it, even when both are nothing
    m = json.loads((tmp_path / "m.json").read_text())
    m["fit"]["check"]["known_error_corrected_deg"] = 0.0
    (tmp_path / "m.json").write_text(json.dumps(m))
    assert run("simulate", "-o", tmp_path / "field.csv", "--duration", 20, "--rate", RATE, "--seed", 5) == 0
    assert run("diagnose", tmp_path / "field.csv", "--model", tmp_path / "m.json", "--report", tmp_path / "r.json",
               "--quiet", "--jobs", 1) == 0
    rep = json.loads((tmp_path / "r.json").read_text())
    assert rep["model_error_from_check"] == {"known_error_deg": 0.0, "set_it": False, "log": "check.csv"}
    assert "check log" not in rep["summary"][0]


def test_a_check_log_without_warp_is_refused_before_the_fit(tmp_path, capsys, monkeypatch):
    import warpbridge.bridge.commands.identify as ident

    assert run("simulate", "-o", tmp_path / "bench.csv", "--duration", 10, "--rate", 100) == 0
    t = np.arange(500) / 100.0
    np.savetxt(tmp_path / "nowarp.csv", np.c_[t, np.sin(t)], delimiter=",", header="t,u", comments="")
    monkeypatch.setattr(ident, "identify", lambda *a, **k: pytest.fail("the fit ran before the check log was read"))
    capsys.readouterr()
    assert run("identify", tmp_path / "bench.csv", "-o", tmp_path / "m.json", "--check", tmp_path / "nowarp.csv") != 0
    err = capsys.readouterr().err
    assert "nowarp.csv" in err and "warp" in err
    assert not (tmp_path / "m.json").exists()


def test_a_check_log_too_short_to_score_is_an_error_and_no_model_is_written(tmp_path, capsys):
    assert run("simulate", "-o", tmp_path / "bench.csv", "--duration", 10, "--rate", 100) == 0
    assert run("simulate", "-o", tmp_path / "short.csv", "--duration", 2.5, "--rate", 100) == 0
    capsys.readouterr()
    assert run("identify", tmp_path / "bench.csv", "-o", tmp_path / "m.json", "--quiet", "--maxiter", 5,
               "--check", tmp_path / "short.csv") != 0
    err = capsys.readouterr().err
    assert "--check" in err and "at least 200 are needed" in err
    assert not (tmp_path / "m.json").exists()


@pytest.mark.parametrize("extra", [{}, {"check": "x"}, {"check": {}}, {"check": {"known_error_corrected_deg": None}},
                                   {"check": {"known_error_corrected_deg": "a"}},
                                   {"check": {"known_error_corrected_deg": -1.0}},
                                   {"check": {"known_error_corrected_deg": float("nan")}}])
def test_a_model_file_without_a_usable_check_gives_no_check_error(extra):
    assert math.isnan(known_error_on_check(extra, corrected=True))


def test_the_check_error_of_the_kind_asked_is_read():
    extra = {"check": {"known_error_corrected_deg": 0.2, "known_error_bare_deg": 0.5}}
    assert known_error_on_check(extra, corrected=True) == 0.2
    assert known_error_on_check(extra, corrected=False) == 0.5


def test_the_warning_says_so_when_the_model_misses_nothing_on_its_bench(tmp_path):
    from warpbridge.bridge.commands.identify import score_check_log
    from warpbridge.bridge.commands.logfile import read_log
    from warpbridge.model.boucwen import BoucWenParams
    from warpbridge.model.modelfile import FitQuality, ModelFile

    assert run("simulate", "-o", tmp_path / "c.csv", "--duration", 10, "--rate", 100, "--noise", 0.03) == 0
    log = np.loadtxt(tmp_path / "c.csv", delimiter=",", skiprows=1)
    log[:, 2] += 0.5 * np.sin(0.7 * log[:, 0])  # the check log's warp wanders off what the model predicts
    write(tmp_path / "c.csv", log[:, 0], log[:, 1], log[:, 2])
    mf = ModelFile(BoucWenParams.paper(), fit=FitQuality(0.03, 0.03, 0.03, {"check": {"known_error_bare_deg": 9.0}}))
    rec, lines = score_check_log(mf, read_log(tmp_path / "c.csv"), "c.csv")
    assert rec["known_error_bare_deg"] > 0.2
    assert "against 0.0000 on the bench log" in lines[0]  # the file's earlier check is not the bench's error
    assert "none on the bench log" in lines[1]
