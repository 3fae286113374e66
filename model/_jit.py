"""numba's ``njit``/``prange`` for the model's kernels, or the same functions run by the interpreter.

The kernels are plain Python on floats and arrays, compiled with numba for
identification and simulation, where they run millions of samples. The
running bridge steps the model one sample per wing per cycle, where the
interpreter is fast enough (tens of microseconds) and numba would cost its
import (LLVM alone is ~70 MB resident and ~1 s) and a compile cache. So the
mode is chosen once per process, before the first kernel module is imported:

- ``WARPBRIDGE_JIT=1`` in the environment: compiled; ``WARPBRIDGE_JIT=0``: interpreted;
- otherwise compiled, unless the program calls ``interpret()`` first (``warpbridge run`` does).

Interpreted kernels are the very same function objects, undecorated, with
``prange`` = ``range``: results agree with the compiled ones to rounding.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

_ENV = os.environ.get("WARPBRIDGE_JIT", "").strip().lower()
_FORCED: str | None = {"0": "interpreted", "off": "interpreted", "no": "interpreted",
                       "1": "compiled", "on": "compiled", "yes": "compiled"}.get(_ENV)
_mode = _FORCED or "compiled"
_decorated = False  # a kernel has been defined: the mode is fixed


def mode() -> str:
    """``"compiled"`` or ``"interpreted"``: how the kernels of this process run."""
    return _mode


def interpret() -> bool:
    """Run the kernels interpreted (no numba import). Only before the first kernel module is imported,
    and not when ``WARPBRIDGE_JIT`` forces a mode; returns whether the kernels will be interpreted."""
    global _mode
    if not _decorated and _FORCED is None:
        _mode = "interpreted"
    return _mode == "interpreted"


def compile_kernels() -> bool:
    """Undo ``interpret()`` (e.g. in a worker process that fits); same conditions; True if compiled."""
    global _mode
    if not _decorated and _FORCED is None:
        _mode = "compiled"
    return _mode == "compiled"


def vector(p: Any) -> Any:
    """A parameter vector for one-sample kernel calls: the array itself when compiled; a list of floats
    when interpreted (element access and arithmetic on numpy scalars are ~3x slower than on floats)."""
    return p if _mode == "compiled" else [float(x) for x in p]


KERNEL_DIRS = ("model", "sitl")  # package folders whose sources the compiled kernels are made of
CACHE_PREFIX = "kernels-"
_cache_set = False


def kernel_fingerprint(root: Path | None = None) -> str:
    """A hash of every source file the compiled kernels may be made of (``KERNEL_DIRS`` of the package)."""
    root = root or Path(__file__).resolve().parent.parent
    h = hashlib.sha256()
    for d in KERNEL_DIRS:
        for f in sorted((root / d).glob("*.py")):
            h.update(f"{d}/{f.name}\0".encode())
            h.update(f.read_bytes())
    return h.hexdigest()[:16]


def versioned_cache_dir(base: Path, fingerprint: str) -> Path:
    """The folder for kernels compiled from sources with ``fingerprint``, under ``base``; the folders of
    other sources there are removed (best effort)."""
    target = base / f"{CACHE_PREFIX}{fingerprint}"
    if base.is_dir():
        for old in base.glob(f"{CACHE_PREFIX}*"):
            if old != target and old.is_dir():
                shutil.rmtree(old, ignore_errors=True)
    return target


def _use_versioned_cache(numba: Any) -> None:
    """Point numba's compile cache at a folder named after the kernels' sources.

    numba checks a cached kernel against its own file only: a kernel that calls (and inlines) one from
    another file keeps the old callee after that file changes, as after an upgrade. A folder per
    fingerprint of all kernel sources never serves such a stale kernel. Under ``NUMBA_CACHE_DIR`` when set,
    else beside the sources (numba's own default place)."""
    global _cache_set
    if _cache_set:
        return
    _cache_set = True
    base = Path(numba.config.CACHE_DIR) if numba.config.CACHE_DIR else Path(__file__).resolve().parent / "__pycache__"
    try:
        numba.config.CACHE_DIR = str(versioned_cache_dir(base, kernel_fingerprint()))
    except OSError:  # unreadable sources: leave numba's own choice
        pass


def njit(*args: Any, **options: Any) -> Any:
    """``numba.njit`` (bare or with options; ``nogil`` unless told otherwise, so that threads can run kernels
    side by side) in compiled mode; the undecorated function otherwise."""
    global _decorated
    _decorated = True
    if _mode == "compiled":
        import numba

        _use_versioned_cache(numba)
        options.setdefault("nogil", True)  # callers may run kernels from several threads (diagnose's rounds)
        if len(args) == 1 and callable(args[0]):
            return numba.njit(**options)(args[0])
        return numba.njit(*args, **options)
    if len(args) == 1 and callable(args[0]) and not options:
        return args[0]

    def keep(fn: Callable[..., Any]) -> Callable[..., Any]:
        return fn
    return keep


def __getattr__(name: str) -> Any:
    """``prange``: ``numba.prange`` in compiled mode (numba must see its own object), ``range`` otherwise."""
    global _decorated
    if name != "prange":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    _decorated = True
    if _mode == "compiled":
        import numba

        _use_versioned_cache(numba)
        return numba.prange
    return range
