"""Where numba keeps the compiled model kernels: a writable place, chosen before numba is imported.

numba caches each compiled kernel beside its source (``__pycache__`` in the
package directory; ``model._jit`` puts it in a folder per version of the kernel
sources there, or under ``NUMBA_CACHE_DIR``) and, when that is not writable,
under the user's cache directory. A system-wide install (read-only site-packages) started by systemd
as a user without a home has neither: the kernels are then compiled again at
every start (tens of seconds on a small board) or the first compile fails
("no locator available"). ``configure()`` sets ``NUMBA_CACHE_DIR`` when the
user has not set it and the package directory is not writable, to the first
writable of:

1. ``$CACHE_DIRECTORY`` (systemd sets it for ``CacheDirectory=warpbridge``);
2. ``$XDG_CACHE_HOME/warpbridge``, by default ``~/.cache/warpbridge``;
3. ``/var/cache/warpbridge``;
4. ``<temporary directory>/warpbridge-<uid>`` (lost at reboot: compiled again after each boot).

The flight loop itself runs interpreted kernels (``model._jit``); the cache
serves the offline commands and the pre-flight calibration's worker process.
"""

from __future__ import annotations

import logging
import os
import tempfile
from collections.abc import Callable, Mapping, MutableMapping
from pathlib import Path

log = logging.getLogger(__name__)

ENV = "NUMBA_CACHE_DIR"


def package_dir() -> Path:
    """The directory holding the model's kernels (where numba would cache them by default)."""
    return Path(__file__).resolve().parent.parent / "model"


def writable(path: Path) -> bool:
    """Whether files can be created in ``path`` (created if missing)."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path, prefix=".wb-probe-"):
            return True
    except OSError:
        return False


def candidates(environ: Mapping[str, str]) -> list[Path]:
    """The fallback cache directories in order of preference."""
    out = []
    if environ.get("CACHE_DIRECTORY"):
        out.append(Path(environ["CACHE_DIRECTORY"].split(":")[0]))
    xdg = environ.get("XDG_CACHE_HOME") or (str(Path(environ["HOME"]) / ".cache") if environ.get("HOME") else "")
    if xdg:
        out.append(Path(xdg) / "warpbridge")
    out.append(Path("/var/cache/warpbridge"))
    out.append(Path(tempfile.gettempdir()) / f"warpbridge-{os.getuid() if hasattr(os, 'getuid') else 'user'}")
    return out


def choose(environ: Mapping[str, str], kernels_dir: Path,
           can_write: Callable[[Path], bool] = writable) -> Path | None:
    """The cache directory to set, or None when numba's own choice is fine (set by the user, or the
    package directory's ``__pycache__`` is writable)."""
    if environ.get(ENV):
        return None
    if can_write(kernels_dir / "__pycache__"):
        return None
    for path in candidates(environ):
        if can_write(path):
            return path
    return None


def configure(environ: MutableMapping[str, str] = os.environ, kernels_dir: Path | None = None,
              can_write: Callable[[Path], bool] = writable) -> Path | None:
    """Set ``NUMBA_CACHE_DIR`` in ``environ`` when needed (see the module docstring); returns what was set."""
    path = choose(environ, kernels_dir or package_dir(), can_write)
    if path is not None:
        environ[ENV] = str(path)
        log.debug("numba cache: %s (the package directory is not writable)", path)
    return path
