"""Bad input on every command is one line and a non-zero exit, never a traceback: files that are
binary, empty, directories, unreadable or not TOML; output paths that are directories or files;
option values out of range. Through ``bridge.cli.main`` as a user would run the commands."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from warpbridge.bridge.cli import main
from warpbridge.model.boucwen import BoucWenParams
from warpbridge.model.modelfile import ModelFile


def fails_cleanly(capsys, argv: list[str], fragment: str) -> str:
    """``warpbridge argv`` exits 2 with one line on stderr containing ``fragment``."""
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert "Traceback" not in err
    last = err.splitlines()[-1]
    assert last.startswith(f"warpbridge {argv[0]}: error:") and fragment in last, err
    return last


def bad_configs(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    """name -> (path, what the error line must say)."""
    binary = tmp_path / "binary.toml"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    empty = tmp_path / "empty.toml"
    empty.write_text("")
    folder = tmp_path / "folder.toml"
    folder.mkdir()
    bad = tmp_path / "bad.toml"
    bad.write_text("[link\nconnection = 'udpin:0.0.0.0:14550'\n")
    csv = tmp_path / "log.csv"
    csv.write_text("t,u,warp\n0,0,0\n")
    return {"binary": (binary, "not a TOML text file"), "empty": (empty, "[link] connection: missing"),
            "directory": (folder, "Is a directory"), "bad TOML": (bad, "not valid TOML"),
            "a CSV": (csv, "not valid TOML"), "missing": (tmp_path / "nope.toml", "No such file")}


@pytest.mark.parametrize("case", ["binary", "empty", "directory", "bad TOML", "a CSV", "missing"])
@pytest.mark.parametrize("command", [["run", "--check"], ["calibrate", "--no-fc"]])
def test_bad_config_file(tmp_path, capsys, command, case):
    path, says = bad_configs(tmp_path)[case]
    fails_cleanly(capsys, [command[0], "--config", str(path), *command[1:]], says)


def test_unreadable_config(tmp_path, capsys, monkeypatch):
    path = tmp_path / "wb.toml"
    path.write_text("[link]\n")
    real = Path.read_text

    def denied(self, *a, **kw):
        if self == path:
            raise PermissionError(13, "Permission denied", str(self))
        return real(self, *a, **kw)

    monkeypatch.setattr(Path, "read_text", denied)  # root reads any file: make it unreadable another way
    fails_cleanly(capsys, ["run", "--config", str(path), "--check"], "Permission denied")


@pytest.mark.parametrize("argv, says", [
    (["calibrate", "--seconds", "5"], "--seconds"),
    (["calibrate", "--timeout", "nan"], "--timeout"),
    (["calibrate", "--timeout", "-1"], "--timeout"),
])
def test_calibrate_options_are_checked_before_anything_opens(tmp_path, capsys, argv, says):
    fails_cleanly(capsys, [*argv, "--config", str(tmp_path / "not-read.toml")], says)


@pytest.mark.parametrize("argv, says", [
    (["--duration", "inf"], "--duration"),
    (["--duration", "nan"], "--duration"),
    (["--duration", "1e9", "--lockstep"], "--duration"),
    (["--seed", "-1", "--lockstep"], "--seed"),
    (["--kp", "-2"], "--kp"),
    (["--ki", "nan"], "--ki"),
    (["--gcs", "14550:udp"], "--gcs"),
    (["--effects", "delay"], "--effects"),
    (["--bridge-model", "no-such-model.json"], "--bridge-model: no-such-model.json: no such model file"),
])
def test_sitl_options_out_of_range(capsys, argv, says):
    fails_cleanly(capsys, ["sitl", *argv], says)


def test_sitl_output_folder_that_is_a_file(tmp_path, capsys):
    f = tmp_path / "run"
    f.write_text("a file, not a folder\n")
    fails_cleanly(capsys, ["sitl", "--out", str(f), "--no-gcs"], "cannot make the folder")
    assert f.read_text() == "a file, not a folder\n"


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    d = tmp_path_factory.mktemp("good")
    log = d / "log.csv"
    assert main(["simulate", "-o", str(log), "--duration", "4", "--rate", "100"]) == 0
    model = d / "model.json"
    model.write_text(json.dumps(ModelFile(BoucWenParams.paper()).to_dict()))
    return log, model


def test_outputs_that_are_directories(good, tmp_path, capsys):
    log, model = good
    out = tmp_path / "out"
    out.mkdir()
    fails_cleanly(capsys, ["simulate", "-o", str(out), "--duration", "2"], "is a directory")
    fails_cleanly(capsys, ["predict", str(log), "--model", str(model), "-o", str(out)], "is a directory")
    fails_cleanly(capsys, ["diagnose", str(log), "--model", str(model), "--report", str(out)], "is a directory")
    assert out.is_dir() and list(out.iterdir()) == []


@pytest.mark.parametrize("argv, says", [
    (["--duration", "1e12"], "samples"),
    (["--seed", "-1"], "--seed"),
    (["--noise", "-1"], "--noise"),
])
def test_simulate_options_out_of_range(tmp_path, capsys, argv, says):
    fails_cleanly(capsys, ["simulate", "-o", str(tmp_path / "x.csv"), *argv], says)
    assert not (tmp_path / "x.csv").exists()
