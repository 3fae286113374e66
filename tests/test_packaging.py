"""Installed, warpbridge adds one top-level import name: ``warpbridge``."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
FOLDERS = ("bridge", "model", "hw", "sitl")


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """A wheel built from a copy of the source tree (the checkout is left untouched)."""
    src = tmp_path_factory.mktemp("src")
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, src / name)
    for folder in FOLDERS:
        shutil.copytree(REPO / folder, src / folder, ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
    out = tmp_path_factory.mktemp("dist")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(out),
                    str(src)], check=True, capture_output=True, text=True)
    (whl,) = out.glob("warpbridge-*.whl")
    return whl


def test_the_wheel_installs_only_the_warpbridge_import_name(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    top = {n.split("/")[0] for n in names}
    dist_info = {t for t in top if t.endswith(".dist-info")}
    assert top - dist_info == {"warpbridge"}
    for folder in FOLDERS:
        assert f"warpbridge/{folder}/__init__.py" in names
    assert "warpbridge/bridge/cli.py" in names


def test_the_console_script_points_into_the_package(wheel):
    with zipfile.ZipFile(wheel) as z:
        (ep,) = [n for n in z.namelist() if n.endswith("entry_points.txt")]
        text = z.read(ep).decode()
    assert "warpbridge = warpbridge.bridge.cli:main" in text


def test_the_installed_environment_has_no_bare_folder_names(tmp_path):
    """Outside the checkout, only ``warpbridge.*`` imports; ``bridge`` and friends are not found."""
    code = ("import importlib.util as u, warpbridge.bridge.cli, warpbridge.model.boucwen;"
            f"print([n for n in {list(FOLDERS)!r} if u.find_spec(n) is not None])")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
