"""What a user installs: the wheel and the sdist hold every module of the source folders, and only under
the one import name ``warpbridge``; installed into a fresh environment, the wheel alone runs.

The wheel and the sdist are built once per module from a copy of the source tree (the checkout is left
untouched), as ``pip wheel --no-deps -w dist .`` builds them for CI and for a companion computer."""

from __future__ import annotations

import json
import os
import shutil
import site
import subprocess
import sys
import tarfile
import tomllib
import venv
import zipfile
from pathlib import Path

import pytest

from warpbridge.bridge import cli

REPO = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())
MAPPING: dict[str, str] = PYPROJECT["tool"]["setuptools"]["package-dir"]  # warpbridge.bridge -> bridge
VERSION = PYPROJECT["project"]["version"]
SHIPPED = ("*.py", "*.json")  # modules and package data (the report schemas)
BUILD_FILES = ("pyproject.toml", "setup.py", "README.md")
IGNORE = shutil.ignore_patterns("__pycache__", "*.pyc", "*.nbi", "*.nbc")


def source_files() -> set[str]:
    """Every module and data file of the mapped source folders, as its path inside the installed package."""
    out = set()
    for package, folder in MAPPING.items():
        root = REPO / folder
        for pattern in SHIPPED:
            for f in root.rglob(pattern):
                if "__pycache__" not in f.relative_to(root).parts:
                    out.add(package.replace(".", "/") + "/" + f.relative_to(root).as_posix())
    return out


@pytest.fixture(scope="module")
def source_copy(tmp_path_factory) -> Path:
    src = tmp_path_factory.mktemp("src")
    for name in BUILD_FILES:
        shutil.copy(REPO / name, src / name)
    for folder in MAPPING.values():
        shutil.copytree(REPO / folder, src / folder, ignore=IGNORE)
    return src


@pytest.fixture(scope="module")
def wheel(source_copy, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("dist")
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(out),
                        str(source_copy)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-3000:]
    (whl,) = out.glob("warpbridge-*.whl")
    return whl


@pytest.fixture(scope="module")
def sdist(source_copy, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sdist")
    code = "import sys; from setuptools import build_meta; print(build_meta.build_sdist(sys.argv[1]))"
    r = subprocess.run([sys.executable, "-c", code, str(out)], cwd=source_copy, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-3000:]
    return out / r.stdout.split()[-1]


@pytest.fixture(scope="module")
def fresh_env(wheel, tmp_path_factory) -> Path:
    """A new virtual environment with the wheel installed (not editable) and nothing else of warpbridge.

    The dependencies (numpy, numba, ...) are not downloaded again: a directory of links to this
    environment's installed distributions, all but warpbridge's own, is put on its path."""
    env = tmp_path_factory.mktemp("venv")
    venv.EnvBuilder(with_pip=False, symlinks=True).create(env)
    python = env / "bin" / "python"
    purelib = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                             capture_output=True, text=True, check=True).stdout.strip()
    deps = env / "deps"
    deps.mkdir()
    for directory in site.getsitepackages():
        for entry in Path(directory).iterdir():
            if not entry.name.lower().startswith(("warpbridge", "__editable__")) and not (deps / entry.name).exists():
                (deps / entry.name).symlink_to(entry)
    (Path(purelib) / "dependencies.pth").write_text(f"{deps}\n")
    r = subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-index",
                        "-q", str(wheel)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-3000:]
    return env


def run_in(env: Path, *argv: str, cwd: Path) -> subprocess.CompletedProcess:
    """``argv`` with ``env``'s bin first, from ``cwd``, with no PYTHONPATH that could reach the checkout."""
    environ = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    environ["PATH"] = f"{env / 'bin'}{os.pathsep}{environ.get('PATH', '')}"
    return subprocess.run(list(argv), cwd=cwd, env=environ, capture_output=True, text=True, timeout=600)


# ---------------------------------------------------------------------- contents


def test_the_wheel_holds_every_module_of_the_source_folders_and_nothing_else(wheel):
    names = [n for n in zipfile.ZipFile(wheel).namelist() if not n.endswith("/")]
    dist_info = f"warpbridge-{VERSION}.dist-info"
    assert {n.split("/")[0] for n in names} == {"warpbridge", dist_info}
    package = {n for n in names if n.startswith("warpbridge/")}
    expected = source_files()
    assert sorted(expected - package) == [], "left out of the wheel"
    assert sorted(package - expected) == [], "in the wheel but not a module of the source folders"
    assert "warpbridge/bridge/commands/identify.py" in package  # once left out: listed by hand


def test_the_sdist_holds_every_module_and_what_builds_it(sdist):
    with tarfile.open(sdist) as t:
        names = [m.name for m in t.getmembers() if m.isfile()]
    top = f"warpbridge-{VERSION}/"
    assert all(n.startswith(top) for n in names)
    names = {n[len(top):] for n in names}
    folders = {folder: package for package, folder in MAPPING.items()}
    in_folders = {folders[n.split("/")[0]].replace(".", "/") + "/" + n.split("/", 1)[1]
                  for n in names if n.split("/")[0] in folders}
    assert sorted(source_files() - in_folders) == [], "left out of the sdist"
    assert sorted(in_folders - source_files()) == []
    assert {*BUILD_FILES, "PKG-INFO"} <= names


def test_the_console_script_points_into_the_package(wheel):
    with zipfile.ZipFile(wheel) as z:
        (ep,) = [n for n in z.namelist() if n.endswith("entry_points.txt")]
        text = z.read(ep).decode()
    assert "warpbridge = warpbridge.bridge.cli:main" in text


# ---------------------------------------------------------------------- installed from the wheel alone


def test_installed_from_the_wheel_the_command_line_lists_every_command(fresh_env, tmp_path):
    version = run_in(fresh_env, "warpbridge", "--version", cwd=tmp_path)
    assert (version.returncode, version.stdout) == (0, f"warpbridge {VERSION}\n"), version.stderr
    helped = run_in(fresh_env, "warpbridge", "--help", cwd=tmp_path)
    assert helped.returncode == 0, helped.stderr
    for name in cli.COMMANDS:
        assert f"\n    {name} " in helped.stdout, name
    sitl = run_in(fresh_env, "warpbridge", "sitl", "--help", cwd=tmp_path)  # a command's module loads
    assert sitl.returncode == 0 and "--duration" in sitl.stdout, sitl.stderr[-3000:]


def test_installed_from_the_wheel_every_module_imports_from_the_fresh_environment(fresh_env, wheel, tmp_path):
    modules = sorted(n[:-3].replace("/", ".").removesuffix(".__init__")
                     for n in zipfile.ZipFile(wheel).namelist() if n.endswith(".py"))
    assert {m for m, _help in cli.COMMANDS.values()} <= set(modules)
    code = ("import importlib, importlib.util, json, sys\n"
            "files = {m: importlib.import_module(m).__file__ for m in sys.argv[1:]}\n"
            "bare = [n for n in ('bridge', 'model', 'hw', 'sitl') if importlib.util.find_spec(n) is not None]\n"
            "print(json.dumps({'files': files, 'bare': bare}))\n")
    r = run_in(fresh_env, "python", "-c", code, *modules, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout.splitlines()[-1])
    outside = {m: f for m, f in out["files"].items() if not Path(f).resolve().is_relative_to(fresh_env.resolve())}
    assert outside == {}, "imported from elsewhere than the installed wheel"
    assert out["bare"] == []


def test_the_installed_environment_has_no_bare_folder_names(tmp_path):
    """In the environment running the tests too, only ``warpbridge.*`` imports outside the checkout."""
    code = ("import importlib.util as u, warpbridge.bridge.cli, warpbridge.model.boucwen;"
            f"print([n for n in {sorted(MAPPING.values())!r} if u.find_spec(n) is not None])")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
