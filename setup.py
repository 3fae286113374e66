"""The package list, found rather than written: every package under each folder that
``[tool.setuptools.package-dir]`` in pyproject.toml maps into ``warpbridge``.

pyproject.toml holds everything else. Its ``packages.find`` names packages after their
folders (``bridge.commands``) and cannot prefix them with ``warpbridge.``; listing them by
hand once left ``warpbridge.bridge.commands`` out of the wheel. setuptools resolves each
subpackage's folder from the mapping of its parent (``warpbridge.bridge.commands`` ->
``bridge/commands``). Every folder counts, with or without ``__init__.py`` (a folder of
data such as ``bridge/commands/schemas`` too), except compile caches.
"""

import tomllib
from pathlib import Path

from setuptools import find_namespace_packages, setup

HERE = Path(__file__).resolve().parent
MAPPING: dict[str, str] = tomllib.loads((HERE / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
CACHES = ["__pycache__", "__pycache__.*", "*.__pycache__", "*.__pycache__.*"]

setup(packages=[f"{name}{'.' + sub if sub else ''}"
                for name, folder in MAPPING.items()
                for sub in ["", *find_namespace_packages(where=str(HERE / folder), exclude=CACHES)]])
