"""The model commands end to end on real files: simulate -> identify -> predict, and clear errors on bad input."""

import contextlib
import io
import json

import numpy as np
import pytest
from helpers import two_stage_lag

from warpbridge.bridge.cli import main


def run(*args):
    return main([str(a) for a in args])


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    assert run("simulate", "-o", d / "bench.csv", "--duration", 30, "--rate", 200, "--seed", 1) == 0
    assert run("simulate", "-o", d / "check.csv", "--duration", 20, "--rate", 200, "--excitation", "multisine",
               "--seed", 2) == 0
    assert run("identify", d / "bench.csv", "-o", d / "model.json", "--plot", d / "id.png", "--quiet",
               "--maxiter", 60) == 0
    return d


def test_identify_writes_a_versioned_model_with_its_fit_quality(workdir):
    m = json.loads((workdir / "model.json").read_text())
    assert m["format"] == "warpbridge-model/1"
    for k in ("train_rms_deg", "heldout_rms_deg", "noise_deg"):
        assert m["fit"][k] > 0
    assert m["fit"]["heldout_rms_deg"] < 1.3 * m["fit"]["noise_deg"]
    assert (workdir / "id.png").stat().st_size > 10_000


def test_identify_writes_an_interval_for_every_parameter_and_what_the_log_excites(workdir):
    fit = json.loads((workdir / "model.json").read_text())["fit"]
    unc = fit["uncertainty"]
    assert unc["level"] == 0.95 and 1 <= unc["effective_samples"] <= unc["samples"]
    assert set(unc["params"]) == {"a1", "a2", "a3", "az", "A", "n", "b1", "b2", "b3", "b4", "b5", "b6"}
    for iv in unc["params"].values():
        assert iv["lo"] <= iv["value"] <= iv["hi"] and isinstance(iv["determined"], bool)
    assert set(unc["undetermined"]) <= set(unc["params"]) | set(unc["search"])
    assert fit["excitation"]["turning_points"] >= 4 and isinstance(fit["excitation"]["notes"], list)
    assert fit["train_rms_deg"] <= fit["linear_train_rms_deg"] and fit["line_restart"] is False
    assert fit["design_seed"] == 0 and fit["design_size"] >= 512


def test_predict_writes_t_and_warp_pred_matching_the_log(workdir):
    assert run("predict", workdir / "check.csv", "--model", workdir / "model.json", "-o", workdir / "pred.csv") == 0
    lines = (workdir / "pred.csv").read_text().splitlines()
    assert lines[0] == "t,warp_pred"
    pred = np.loadtxt(workdir / "pred.csv", delimiter=",", skiprows=1)
    log = np.loadtxt(workdir / "check.csv", delimiter=",", skiprows=1)
    assert pred.shape[0] == log.shape[0]
    assert np.sqrt(np.mean((pred[:, 1] - log[:, 2]) ** 2)) < 0.07


def test_model_file_round_trips_through_predict(workdir):
    # a model with effects: predict applies them (delay shifts the prediction); a log without warp
    # starts both from the model file's z0, so the shift is exact
    log = np.loadtxt(workdir / "check.csv", delimiter=",", skiprows=1)
    np.savetxt(workdir / "inputs.csv", log[:, :2], delimiter=",", header="t,u", comments="", fmt="%.9g")
    m = json.loads((workdir / "model.json").read_text())
    m["effects"] = {"delay": {"delay_s": 0.2}}
    (workdir / "delayed.json").write_text(json.dumps(m))
    assert run("predict", workdir / "inputs.csv", "--model", workdir / "model.json", "-o", workdir / "p1.csv") == 0
    assert run("predict", workdir / "inputs.csv", "--model", workdir / "delayed.json", "-o", workdir / "p2.csv") == 0
    a = np.loadtxt(workdir / "p1.csv", delimiter=",", skiprows=1)[:, 1]
    b = np.loadtxt(workdir / "p2.csv", delimiter=",", skiprows=1)[:, 1]
    assert np.allclose(b[40:], a[:-40], atol=1e-6)  # 0.2 s at 200 Hz


def test_repeated_rows_and_uneven_sampling_are_handled(workdir, tmp_path):
    log = np.loadtxt(workdir / "bench.csv", delimiter=",", skiprows=1)
    rng = np.random.default_rng(0)
    keep = np.sort(rng.choice(log.shape[0], int(0.7 * log.shape[0]), replace=False))  # uneven
    rows = log[keep]
    rows = np.repeat(rows, rng.integers(1, 4, rows.shape[0]), axis=0)  # repeated rows
    rows[5, 2] = np.nan  # a missing cell
    path = tmp_path / "messy.csv"
    np.savetxt(path, rows, delimiter=",", header="t,u,warp,airspeed", comments="", fmt="%.9g")
    assert run("predict", path, "--model", workdir / "model.json", "-o", tmp_path / "p.csv") == 0


BAD_LOGS = {
    "missing_column": ("t,u\n0,1\n", "missing column"),
    "not_a_number": ("t,u,warp\n" + "".join(f"{i * 0.01},{i},{i}\n" for i in range(60)) + "0.6,abc,1\n",
                     "not a number"),
    "time_backwards": ("t,u,warp\n" + "".join(f"{(i if i != 30 else 5) * 0.01},{i},{i}\n" for i in range(60)),
                       "backwards"),
    "too_short": ("t,u,warp\n0,1,1\n0.1,2,2\n", "too short"),
    "empty": ("", "empty"),
    "mostly_nan": ("t,u,warp\n" + "".join(f"{i * 0.01},nan,{i}\n" for i in range(60)), "non-finite"),
    "never_reverses": ("t,u,warp\n" + "".join(f"{i * 0.01},{i},{i * 0.5}\n" for i in range(200)), "never reverses"),
}


@pytest.mark.parametrize("name", sorted(BAD_LOGS))
def test_bad_logs_get_a_one_line_error_and_nonzero_exit(name, tmp_path, capsys):
    text, needle = BAD_LOGS[name]
    path = tmp_path / f"{name}.csv"
    path.write_text(text)
    out = tmp_path / "m.json"
    out.write_text("precious")
    rc = run("identify", path, "-o", out, "--quiet")
    err = capsys.readouterr().err.strip().splitlines()
    assert rc != 0
    assert len(err) == 1 and needle in err[0] and "Traceback" not in err[0]
    assert out.read_text() == "precious"  # never overwritten on failure


@pytest.mark.parametrize("content, needle", [
    ("{not json", "not valid JSON"),
    ('{"format": "warpbridge-model/2", "params": {}}', "unsupported model format version"),
    ('{"params": {}}', "no \\\"format\\\""),
    ('{"format": "something-else/1"}', "not a warpbridge model file"),
    ('{"format": "warpbridge-model/1", "params": {"a1": 1}}', "lack"),
])
def test_bad_models_get_a_one_line_error(content, needle, workdir, tmp_path, capsys):
    path = tmp_path / "bad.json"
    path.write_text(content)
    rc = run("predict", workdir / "check.csv", "--model", path, "-o", tmp_path / "p.csv")
    err = capsys.readouterr().err.strip().splitlines()
    assert rc != 0 and len(err) == 1
    assert needle.replace("\\", "") in err[0]
    assert not (tmp_path / "p.csv").exists()


def test_missing_files_are_reported_not_raised(tmp_path, capsys):
    assert run("identify", tmp_path / "nope.csv", "-o", tmp_path / "m.json") != 0
    assert "no such file" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [
    ["identify", "{log}", "-o", "{missing}/m.json", "--quiet"],
    ["identify", "{log}", "-o", "{tmp}/m.json", "--plot", "{missing}/fit.png", "--quiet"],
    ["identify", "{log}", "-o", "{tmp}/m.json", "--plot", "{tmp}/fit.txt", "--quiet"],
    ["identify", "{log}", "-o", "{tmp}", "--quiet"],
    ["predict", "{log}", "--model", "{model}", "-o", "{missing}/p.csv"],
    ["predict", "{log}", "--model", "{model}", "-o", "{tmp}/p.csv", "--plot", "{missing}/p.png"],
])
def test_outputs_that_cannot_be_written_are_refused_before_any_work(argv, workdir, tmp_path, capsys, monkeypatch):
    import warpbridge.bridge.commands.identify as command

    def no_fit(*_a, **_k):
        raise AssertionError("the fit started before the output paths were checked")

    monkeypatch.setattr(command, "identify", no_fit)
    args = [a.format(log=workdir / "bench.csv", model=workdir / "model.json", missing=tmp_path / "nope",
                     tmp=tmp_path) for a in argv]
    rc = run(*args)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc != 0
    assert len(err) == 1 and err[0].startswith(f"warpbridge {argv[0]}: error:") and "Traceback" not in err[0]
    assert not (tmp_path / "nope").exists() and not list(tmp_path.glob("*.*"))  # nothing written


def test_predict_plot_draws_the_prediction_against_the_log(workdir, tmp_path, saved_figures, recwarn):
    figures = saved_figures
    assert run("predict", workdir / "check.csv", "--model", workdir / "model.json", "-o", tmp_path / "p.csv",
               "--plot", tmp_path / "p.png") == 0
    assert (tmp_path / "p.png").stat().st_size > 10_000
    assert not [w for w in recwarn if "matplotlib" in str(w.filename) or "artists" in str(w.message)]
    (fig,) = figures
    texts = [fig.get_suptitle()] + [ax.get_title() for ax in fig.axes]
    labels = [t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()]
    assert all(ax.lines for ax in fig.axes)  # no empty panel
    assert all(ax.get_legend() is not None for ax in fig.axes)
    assert "RMS" in fig.get_suptitle()
    assert not any("training" in s for s in texts + labels)
    # a time series, a residual and a loop (tendon on the x axis)
    assert {ax.get_xlabel() for ax in fig.axes} >= {"t (s)", "tendon u (mm)"}


def test_with_a_servo_in_the_model_the_loops_are_drawn_against_the_travel_through_it(workdir, tmp_path,
                                                                                     saved_figures):
    """A closed loop's command jumps: the loops' axis is the tendon travel the model is fed, not the command."""
    from warpbridge.model.effects import Effects, servo_travel

    figures = saved_figures
    m = json.loads((workdir / "model.json").read_text())
    m["effects"] = {"servo_lag": {"servo_tau_s": 0.04, "servo_rate_mm_s": 60.0}}
    (tmp_path / "servo.json").write_text(json.dumps(m))
    t = np.arange(0.0, 8.0, 0.01)
    u = np.repeat(np.random.default_rng(3).uniform(-4.0, 4.0, 16), 50)  # a step every 0.5 s
    warp = 2.0 * servo_travel(t, u, 0.04, 60.0, float(u[0]))
    np.savetxt(tmp_path / "steps.csv", np.column_stack([t, u, warp]), delimiter=",", header="t,u,warp",
               comments="", fmt="%.9g")
    assert run("predict", tmp_path / "steps.csv", "--model", tmp_path / "servo.json", "-o", tmp_path / "p.csv",
               "--plot", tmp_path / "p.png") == 0
    assert run("identify", tmp_path / "steps.csv", "-o", tmp_path / "m.json", "--plot", tmp_path / "id.png",
               "--quiet", "--maxiter", 20) == 0
    kept = Effects(**json.loads((tmp_path / "m.json").read_text())["effects"].get("servo_lag", {}))
    assert kept.has_servo  # the steps are followed by a servo: identify keeps one
    through = [servo_travel(t, u, 0.04, 60.0, float(u[0])),  # predict's figure, then identify's
               servo_travel(t, u, kept.servo_tau_s, kept.servo_rate_mm_s, float(u[0]), kept.servo_deadband_mm)]
    for fig, x in zip(figures, through, strict=True):
        loops = [ax for ax in fig.axes if "u -> warp" in ax.get_title()]
        assert loops and all("through its servo" in ax.get_xlabel() for ax in loops)
        drawn = np.concatenate([ax.lines[0].get_xdata() for ax in loops])
        np.testing.assert_allclose(drawn, x, atol=1e-9)
        assert np.abs(np.diff(drawn)).max() < 0.5 * np.abs(np.diff(u)).max()  # no jump drawn across the loop


def test_a_log_starting_with_the_tendon_loaded_is_predicted_from_its_first_sample(workdir, tmp_path, capsys):
    """The target: a correct model's whole-log RMS within 1.1x of its RMS after the first 5 s."""
    assert run("simulate", "-o", tmp_path / "long.csv", "--duration", 40, "--rate", 200, "--seed", 6) == 0
    log = np.loadtxt(tmp_path / "long.csv", delimiter=",", skiprows=1)
    u, w = log[:, 1], log[:, 2]
    # cut where the tendon has just been pulled far up from rest: the log starts loaded
    start = 200 + int(np.argmax(u[200:4000]))
    np.savetxt(tmp_path / "loaded.csv", log[start:], delimiter=",", header="t,u,warp,airspeed", comments="",
               fmt="%.9g")
    assert w[start] > np.median(w) + 1.0
    assert run("predict", tmp_path / "loaded.csv", "--model", "paper", "-o", tmp_path / "p.csv") == 0
    assert "estimated from the log's first samples" in capsys.readouterr().out
    t = log[start:, 0]
    e = np.loadtxt(tmp_path / "p.csv", delimiter=",", skiprows=1)[:, 1] - log[start:, 2]
    whole = float(np.sqrt(np.mean(e ** 2)))
    late = float(np.sqrt(np.mean(e[t >= t[0] + 5.0] ** 2)))
    assert whole < 1.1 * late
    assert whole < 0.06  # the paper plant with 0.05 deg noise, predicted by itself


def test_identify_records_whether_the_data_support_the_model(workdir, capsys):
    m = json.loads((workdir / "model.json").read_text())
    assert m["fit"]["supported"] is True and "straight line" in m["fit"]["support"]
    assert m["fit"]["linear_heldout_rms_deg"] > m["fit"]["heldout_rms_deg"]
    assert m["z0"] == 0.0 and "z0_start_of_log" in m["fit"]  # another log's start is estimated from that log


def test_predict_adds_the_bench_correction_the_model_carries_when_asked(tmp_path, capsys):
    # the bench's sensor has dynamics the rate-independent model lacks (40 + 15 ms): identify (told to fit no
    # transport delay) learns them as model error, and predict --correction carries them to another excitation
    # (a 0.5-3 Hz sweep)
    rng = np.random.default_rng(5)
    for name, argv in (("bench", ["--duration", 40, "--seed", 3]),
                       ("check", ["--duration", 20, "--excitation", "sweep", "--seed", 4])):
        assert run("simulate", "-o", tmp_path / f"{name}-clean.csv", "--rate", 200, "--noise", 0, *argv) == 0
        log = np.loadtxt(tmp_path / f"{name}-clean.csv", delimiter=",", skiprows=1)
        log[:, 2] = two_stage_lag(log[:, 0], log[:, 2], 0.04, 0.015, substeps=10) + 0.03 * rng.standard_normal(len(log))
        np.savetxt(tmp_path / f"{name}.csv", log[:, :3], delimiter=",", header="t,u,warp", comments="", fmt="%.9g")
    # no transport delay and no servo lag in front of the model: the sensor's lag is left to the correction
    assert run("identify", tmp_path / "bench.csv", "-o", tmp_path / "model.json", "--quiet", "--maxiter", 60,
               "--max-lag", 0) == 0
    assert json.loads((tmp_path / "model.json").read_text())["model_error"]["sets"]
    capsys.readouterr()
    assert run("predict", tmp_path / "check.csv", "--model", tmp_path / "model.json", "-o", tmp_path / "c.csv",
               "--correction") == 0
    assert "model-error correction added" in capsys.readouterr().out
    assert run("predict", tmp_path / "check.csv", "--model", tmp_path / "model.json", "-o", tmp_path / "b.csv") == 0
    assert "bare model (--correction adds" in capsys.readouterr().out
    w = np.loadtxt(tmp_path / "check.csv", delimiter=",", skiprows=1)[:, 2]
    rms = {k: float(np.sqrt(np.mean((np.loadtxt(tmp_path / f"{k}.csv", delimiter=",", skiprows=1)[200:, 1]
                                     - w[200:]) ** 2))) for k in "cb"}
    assert rms["b"] > 0.1  # the bare model misses the sweep by far more than the noise
    assert rms["c"] < 0.5 * rms["b"]


def test_identify_writes_the_rigs_transport_delay_and_predict_applies_it(tmp_path, capsys):
    # the bench's servo answers 40 ms late: the model carries the delay, and a prediction of another log uses it
    for name, argv in (("bench", ["--duration", 40, "--seed", 3]), ("check", ["--duration", 20, "--seed", 4])):
        assert run("simulate", "-o", tmp_path / f"{name}.csv", "--rate", 200, "--noise", 0.03, "--effects",
                   "delay_s=0.04", *argv) == 0
    assert run("identify", tmp_path / "bench.csv", "-o", tmp_path / "model.json", "--quiet", "--maxiter", 60,
               "--max-delay", 0.16) == 0
    assert "transport delay" in capsys.readouterr().out
    m = json.loads((tmp_path / "model.json").read_text())
    assert m["effects"]["delay"]["delay_s"] == pytest.approx(0.04, abs=0.008)
    assert m["fit"]["delay_s"] == m["effects"]["delay"]["delay_s"]
    assert run("predict", tmp_path / "check.csv", "--model", tmp_path / "model.json", "-o", tmp_path / "p.csv") == 0
    w = np.loadtxt(tmp_path / "check.csv", delimiter=",", skiprows=1)[:, 2]
    e = np.loadtxt(tmp_path / "p.csv", delimiter=",", skiprows=1)[200:, 1] - w[200:]
    assert float(np.sqrt(np.mean(e ** 2))) < 2.0 * 0.03


def test_max_delay_is_checked_against_the_scans_grid(tmp_path, capsys):
    assert run("simulate", "-o", tmp_path / "b.csv", "--rate", 100, "--duration", 5) == 0
    capsys.readouterr()
    assert run("identify", tmp_path / "b.csv", "-o", tmp_path / "m.json", "--max-delay", 0.5) != 0
    assert "--max-delay must lie between 0 and 0.16 s" in capsys.readouterr().err
    assert not (tmp_path / "m.json").exists()


@pytest.fixture(scope="module")
def short_fit(workdir):
    """identify's output and model on the bench log with 10 refinement steps, the defaults otherwise."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert run("identify", workdir / "bench.csv", "-o", workdir / "once.json", "--maxiter", 10) == 0
    return buf.getvalue(), json.loads((workdir / "once.json").read_text())


def test_identify_says_when_it_searched_again_from_the_exponents_upper_limit(workdir, short_fit, tmp_path, capsys,
                                                                               monkeypatch):
    from warpbridge.model.identification import pipeline

    assert "searched again" not in short_fit[0]
    capsys.readouterr()
    monkeypatch.setattr(pipeline, "EDGE_FRAC", 1.0)  # every refinement counts as ending at the limit
    monkeypatch.setattr(pipeline, "EDGE_AGREE", -1.0)  # and its starts as disagreeing there
    assert run("identify", workdir / "bench.csv", "-o", tmp_path / "twice.json", "--maxiter", 10) == 0
    out = capsys.readouterr().out
    assert "the first refinement ended at the upper limit of the exponent n: searched again" in out
    assert ("was kept" in out) != ("the first still fitted" in out)


def test_identify_says_when_it_searched_again_without_a_fold_in_the_backbone(workdir, short_fit, tmp_path, capsys,
                                                                             monkeypatch):
    from warpbridge.model.identification import checks

    assert "folded" not in short_fit[0]
    assert "backbone_fold_deg" not in short_fit[1]["fit"]
    capsys.readouterr()
    # a working range so wide that the paper wing's own backbone (its vertex at 17.4 deg) folds in it: without
    # the fold it fits far worse, so the data show the fold and the first model is kept
    monkeypatch.setattr(checks, "FOLD_MARGIN", 1e3)
    assert run("identify", workdir / "bench.csv", "-o", tmp_path / "shown.json", "--maxiter", 10) == 0
    out = capsys.readouterr().out
    assert "the first search's backbone folded at" in out and "the data show the fold, the first model kept" in out
    fit = json.loads((tmp_path / "shown.json").read_text())["fit"]
    lo, hi = fit["working_range_deg"]
    first, unfolded = fit["fold_train_rms_deg"]
    assert lo < fit["backbone_fold_deg"] < hi and fit["fold_search_kept"] is False and unfolded > 1.05 * first
    # kept whatever it costs: the model without the fold, and the message says so
    monkeypatch.setattr(checks, "FOLD_KEEP", 1e9)
    assert run("identify", workdir / "bench.csv", "-o", tmp_path / "again.json", "--maxiter", 10) == 0
    assert "searched again with the fold kept outside it, and that model was kept" in capsys.readouterr().out
    m = json.loads((tmp_path / "again.json").read_text())
    assert m["fit"]["fold_search_kept"] is True
    assert not lo < -m["params"]["a2"] / (2.0 * m["params"]["a1"]) < hi


def test_predict_and_diagnose_say_when_a_log_leaves_the_identified_travel(workdir, tmp_path, capsys):
    m = json.loads((workdir / "model.json").read_text())
    bench = np.loadtxt(workdir / "bench.csv", delimiter=",", skiprows=1)
    lo, hi = m["fit"]["travel_mm"]
    assert (lo, hi) == pytest.approx(tuple(np.percentile(bench[:, 1], [0.5, 99.5])))
    capsys.readouterr()
    assert run("predict", workdir / "check.csv", "--model", workdir / "model.json", "-o", tmp_path / "p.csv") == 0
    assert "beyond the travel" not in capsys.readouterr().err  # the check log stays inside it
    log = np.loadtxt(workdir / "check.csv", delimiter=",", skiprows=1)
    log[:, 1] = lo + (log[:, 1] - lo) * 1.5  # stretched: the top third of its travel beyond the bench's
    out = np.mean(log[:, 1] > hi + 0.02 * (hi - lo))
    assert 0.05 < out < 0.5
    np.savetxt(tmp_path / "wide.csv", log[:, :3], delimiter=",", header="t,u,warp", comments="", fmt="%.9g")
    assert run("predict", tmp_path / "wide.csv", "--model", workdir / "model.json", "-o", tmp_path / "p.csv") == 0
    err = capsys.readouterr().err
    assert f"{out:.0%} of the log drives the tendon beyond the travel of the log the model was identified on" in err
    assert f"({lo:.2f}..{hi:.2f} mm; 0% below it, {out:.0%} above)" in err
    assert run("diagnose", tmp_path / "wide.csv", "--model", workdir / "model.json", "--report", tmp_path / "r.json",
               "--effects", "delay", "--out-model", tmp_path / "aug.json", "--quiet") == 0
    notes = json.loads((tmp_path / "r.json").read_text())["log"]["notes"]
    assert any("beyond the travel of the log the model was identified on" in n for n in notes)
    # the augmented model keeps the travel its nominal part was identified on, and predict still says it
    assert json.loads((tmp_path / "aug.json").read_text())["fit"]["travel_mm"] == [lo, hi]
    capsys.readouterr()
    assert run("predict", tmp_path / "wide.csv", "--model", tmp_path / "aug.json", "-o", tmp_path / "p.csv") == 0
    assert f"{out:.0%} of the log drives the tendon beyond the travel" in capsys.readouterr().err
    del m["fit"]["travel_mm"]  # a model identified before the travel was recorded: nothing to say
    (tmp_path / "old.json").write_text(json.dumps(m))
    capsys.readouterr()
    assert run("predict", tmp_path / "wide.csv", "--model", tmp_path / "old.json", "-o", tmp_path / "p.csv") == 0
    assert "beyond the travel" not in capsys.readouterr().err


def test_a_log_opening_with_the_play_released_is_predicted_from_its_first_sample(tmp_path, capsys):
    """A model with a wide backlash, the log cut where the tendon had just been released: predict starts the
    play on its releasing edge (and says so), and the whole-log RMS is within 1.1x of the RMS after 5 s."""
    from warpbridge.bridge.commands.modelio import save_model
    from warpbridge.model.boucwen import BoucWenParams
    from warpbridge.model.effects import Effects
    from warpbridge.model.excitation import filtered_random
    from warpbridge.model.modelfile import ModelFile
    from warpbridge.model.plant import Plant

    p, eff = BoucWenParams.paper(), Effects(backlash_mm=0.8)
    save_model(tmp_path / "m.json", ModelFile(params=p, effects=eff))
    t = np.arange(0, 34, 0.005)
    u = 4.5 + 2.0 * np.sin(2 * np.pi * 0.08 * t) + filtered_random(t, 1.5, 0.6, 0.0, seed=4)
    w = Plant(p, eff).simulate(t, u)[1] + np.random.default_rng(5).normal(0, 0.03, t.size)
    k = int(np.argmin(u[:2400]))
    np.savetxt(tmp_path / "log.csv", np.column_stack([t[k:] - t[k], u[k:], w[k:]]), delimiter=",",
               header="t,u,warp", comments="", fmt="%.9g")
    assert run("predict", tmp_path / "log.csv", "--model", tmp_path / "m.json", "-o", tmp_path / "p.csv") == 0
    assert "the play's slack taken up by a release" in capsys.readouterr().out
    e = np.loadtxt(tmp_path / "p.csv", delimiter=",", skiprows=1)[:, 1] - w[k:]
    tt = t[k:] - t[k]
    whole, late = float(np.sqrt(np.mean(e ** 2))), float(np.sqrt(np.mean(e[tt >= 5.0] ** 2)))
    assert whole < 1.1 * late
