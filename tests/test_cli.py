"""The command line lists every command, says in one line which one cannot be loaded and why, and
prints its version.

A broken install is simulated in-process by pointing a ``COMMANDS`` entry at a module that does not
exist or that imports a missing dependency; the real console script runs in a subprocess."""

from __future__ import annotations

import subprocess
import sys
import sysconfig
import textwrap
import tomllib
from pathlib import Path

import pytest

from warpbridge.bridge import cli

REPO = Path(__file__).resolve().parents[1]
SEVEN = {"sitl", "run", "simulate", "identify", "predict", "diagnose", "calibrate"}
MISSING_DEP = "wb_no_such_dependency"


@pytest.fixture
def fake_modules(tmp_path, monkeypatch):
    """Write command modules into a directory on ``sys.path``; forget them afterwards."""
    monkeypatch.syspath_prepend(str(tmp_path))
    written: list[str] = []

    def write(name: str, source: str) -> str:
        (tmp_path / f"{name}.py").write_text(textwrap.dedent(source))
        written.append(name)
        return name

    yield write
    for name in written:
        sys.modules.pop(name, None)


def help_commands(text: str) -> set[str]:
    """The command names of the COMMAND list in ``warpbridge --help``."""
    lines = text.split("positional arguments:", 1)[1].split("options:", 1)[0].splitlines()
    return {line.split()[0] for line in lines if line.startswith("    ") and not line.startswith("     ")}


def one_line(err: str) -> str:
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


def test_help_lists_every_command_even_one_whose_module_is_missing(monkeypatch, capsys):
    monkeypatch.setitem(cli.COMMANDS, "identify", ("warpbridge.bridge.commands.no_such_module", "identify"))
    with pytest.raises(SystemExit) as e:
        cli.main(["--help"])
    assert e.value.code == 0
    assert help_commands(capsys.readouterr().out) == set(cli.COMMANDS) >= SEVEN


def test_help_before_a_broken_command_still_prints_the_help(monkeypatch, capsys):
    monkeypatch.setitem(cli.COMMANDS, "identify", ("warpbridge.bridge.commands.no_such_module", "identify"))
    with pytest.raises(SystemExit) as e:
        cli.main(["--help", "identify"])
    assert e.value.code == 0
    assert "identify" in help_commands(capsys.readouterr().out)


@pytest.mark.parametrize("argv", [["identify", "log.csv", "-o", "model.json"], ["identify", "--help"],
                                  ["-v", "identify", "log.csv"]])
def test_a_command_whose_module_is_missing_fails_with_one_line_naming_it(monkeypatch, capsys, argv):
    monkeypatch.setitem(cli.COMMANDS, "identify", ("warpbridge.bridge.commands.no_such_module", "identify"))
    assert cli.main(argv) == cli.EXIT_UNAVAILABLE != 0
    assert one_line(capsys.readouterr().err) == (
        "warpbridge identify: cannot load warpbridge.bridge.commands.no_such_module: "
        "No module named 'warpbridge.bridge.commands.no_such_module'")


def test_a_missing_dependency_of_a_command_is_named(monkeypatch, capsys, fake_modules):
    module = fake_modules("wb_cmd_needing_a_dependency", f"import {MISSING_DEP}\n")
    monkeypatch.setitem(cli.COMMANDS, "predict", (module, "predict"))
    assert cli.main(["predict", "log.csv"]) == cli.EXIT_UNAVAILABLE
    assert one_line(capsys.readouterr().err) == (
        f"warpbridge predict: cannot load {module}: No module named '{MISSING_DEP}'")


def test_a_dependency_imported_only_when_the_command_runs_is_named(monkeypatch, capsys, fake_modules):
    module = fake_modules("wb_cmd_importing_late", f"""
        def add_arguments(parser):
            pass

        def main(args):
            import {MISSING_DEP}
            return 0
        """)
    monkeypatch.setitem(cli.COMMANDS, "diagnose", (module, "diagnose"))
    assert cli.main(["diagnose"]) == cli.EXIT_UNAVAILABLE
    line = one_line(capsys.readouterr().err)
    assert line.startswith("warpbridge diagnose: ") and f"No module named '{MISSING_DEP}'" in line


def test_other_errors_of_a_command_are_not_taken_for_a_missing_module(monkeypatch, fake_modules):
    module = fake_modules("wb_cmd_with_a_bug", """
        def add_arguments(parser):
            pass

        def main(args):
            raise ZeroDivisionError("a bug")
        """)
    monkeypatch.setitem(cli.COMMANDS, "diagnose", (module, "diagnose"))
    with pytest.raises(ZeroDivisionError):
        cli.main(["diagnose"])


def test_the_other_commands_still_run_when_one_is_broken(monkeypatch, capsys):
    monkeypatch.setitem(cli.COMMANDS, "identify", ("warpbridge.bridge.commands.no_such_module", "identify"))
    with pytest.raises(SystemExit) as e:
        cli.main(["predict", "--help"])
    assert e.value.code == 0
    assert "--model" in capsys.readouterr().out


def test_version_without_an_installed_distribution(monkeypatch):
    def not_installed(name):
        raise cli.importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(cli.importlib.metadata, "version", not_installed)
    assert cli.version() == "unknown (not installed)"


# ---------------------------------------------------------------------- the console script


def console_script(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    script = Path(sysconfig.get_path("scripts")) / "warpbridge"
    return subprocess.run([str(script), *args], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_the_console_script_prints_the_version_of_pyproject(tmp_path):
    expected = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["version"]
    r = console_script("--version", cwd=tmp_path)
    assert (r.returncode, r.stdout, r.stderr) == (0, f"warpbridge {expected}\n", "")


def test_the_console_script_lists_every_command(tmp_path):
    r = console_script("--help", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert help_commands(r.stdout) == set(cli.COMMANDS) >= SEVEN


@pytest.fixture
def recording_command(monkeypatch, fake_modules):
    """``diagnose`` replaced by a command with its own ``--quiet`` that records what it was given, and the log
    level's counts recorded."""
    module = fake_modules("wb_cmd_recording", """
        seen = {}

        def add_arguments(parser):
            parser.add_argument("--quiet", action="store_true", help="less on the terminal")

        def main(args):
            seen["quiet"] = args.quiet
            return 0
        """)
    monkeypatch.setitem(cli.COMMANDS, "diagnose", (module, "diagnose"))
    levels: list[tuple[int, int]] = []
    real = cli.log_level
    monkeypatch.setattr(cli, "log_level", lambda v, q: levels.append((v, q)) or real(v, q))
    return sys.modules.get(module) or __import__(module), levels


@pytest.mark.parametrize(("argv", "counts", "own_quiet"), [
    (["-v", "diagnose"], (1, 0), False),
    (["diagnose", "-v", "--verbose"], (2, 0), False),
    (["-v", "diagnose", "-v"], (2, 0), False),
    (["-q", "diagnose"], (0, 1), False),  # less log output; the command's own terminal output stays
    (["diagnose", "-q"], (0, 1), False),  # the same after the command
    (["-q", "diagnose", "--quiet"], (0, 2), True),  # the command's own --quiet lowers the log level as well
    (["diagnose", "--quiet", "-q"], (0, 2), True),
    (["diagnose", "-q", "--quiet"], (0, 2), True),
])
def test_the_common_options_count_before_and_after_the_command(recording_command, argv, counts, own_quiet):
    module, levels = recording_command
    assert cli.main(argv) == 0
    assert levels == [counts]
    assert bool(module.seen["quiet"]) is own_quiet


def test_verbose_leaves_the_plotting_and_compiler_libraries_at_info(recording_command, monkeypatch):
    """-v is the run's debug output, not matplotlib's font search or numba's passes (hundreds of lines)."""
    import logging

    for name in cli.NOISY_LIBRARIES:
        monkeypatch.setattr(logging.getLogger(name), "level", logging.NOTSET)
    assert cli.main(["-v", "diagnose"]) == 0
    assert all(logging.getLogger(name).level == logging.INFO for name in ("matplotlib", "numba"))
    assert cli.main(["-qq", "diagnose"]) == 0
    assert logging.getLogger("matplotlib").level == logging.ERROR


@pytest.mark.parametrize(("argv", "usage", "unknown"), [
    (["diagnose", "--max-dealy", "0.1"], "usage: warpbridge diagnose", "--max-dealy 0.1"),  # the command's usage
    (["--bogus", "diagnose"], "usage: warpbridge [", "--bogus"),  # before the command: the top level's
])
def test_an_unknown_option_shows_the_usage_of_where_it_was_given(recording_command, capsys, argv, usage, unknown):
    with pytest.raises(SystemExit) as e:
        cli.main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(usage) and f"unrecognized arguments: {unknown}" in err


def test_the_version_after_a_command(recording_command, capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["diagnose", "--version"])
    assert e.value.code == 0 and capsys.readouterr().out.startswith("warpbridge ")
