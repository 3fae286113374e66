"""A benchmark's figures stored as JSON, keyed by the project's sources the run imported.

    record = keyed(figures)          # after the run: {"sources": {"hash", "files"}, ...figures}
    write_json(path, record)
    sources_match(record)            # later: True while every listed file is as it was

``results_page.py`` reads such files from ``benchmarks/results/`` and says when their sources have changed
since (stale). The files listed are every module of ``warpbridge`` and of ``benchmarks/`` that the benchmark's
process had imported when it finished, as paths in the repository (``model/signals.py``): a change to any
of them may change the figures; a change anywhere else cannot, as far as that process goes (worker
processes import the same modules for the runs they are given; a command the run started as a subprocess is
named to ``keyed``, which imports it).
"""

from __future__ import annotations

import hashlib
import importlib
import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def imported_sources() -> list[str]:
    """Repository paths of the ``warpbridge`` and benchmark modules this process has imported, sorted."""
    files = set()
    for name, mod in list(sys.modules.items()):
        f = getattr(mod, "__file__", None)
        if not f or not f.endswith(".py"):
            continue
        parts = name.split(".")
        if parts[0] == "warpbridge" and len(parts) > 1:
            rel = Path(*parts[1:])
            files.add((rel / "__init__.py" if Path(f).name == "__init__.py" else rel.with_suffix(".py")).as_posix())
        elif Path(f).resolve().parent == HERE:
            files.add(f"benchmarks/{Path(f).name}")
    return sorted(files)


def sources_hash(files: list[str], root: Path = ROOT) -> str:
    """12 hex digits of a SHA-256 over each file's path and content (``absent`` for a file that is gone)."""
    h = hashlib.sha256()
    for p in files:
        f = root / p
        h.update(p.encode())
        h.update(f.read_bytes() if f.is_file() else b"absent")
    return h.hexdigest()[:12]


def keyed(figures: dict, also: tuple[str, ...] = ()) -> dict:
    """``figures`` with the sources this process imported and their hash; ``also`` names modules the run used in
    another process (a command run as a subprocess), imported here so that they and what they import count."""
    for name in also:
        importlib.import_module(name)
    files = imported_sources()
    return {"sources": {"hash": sources_hash(files), "files": files}} | figures


def sources_match(record: dict, root: Path = ROOT) -> bool:
    """The sources a stored record lists still hash to its key."""
    src = record.get("sources") or {}
    return bool(src.get("files")) and sources_hash(src["files"], root) == src.get("hash")


def write_json(path: Path, record: dict) -> None:
    """Write ``record`` as sorted, indented JSON (the same figures give the same bytes)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    tmp.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    tmp.replace(path)
