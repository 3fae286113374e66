"""Writing a file so that a crash or power cut at any moment leaves either the old file or the whole new one.

Temporary file in the same folder, flush, fsync, ``os.replace``, then fsync of
the folder so the rename itself is durable.
"""

from __future__ import annotations

import os
import tempfile
import threading
from pathlib import Path


def write_text_atomic(path: str | os.PathLike, text: str, *, temp_prefix: str | None = None,
                      make_dirs: bool = False) -> None:
    """Replace ``path`` with ``text`` atomically. ``temp_prefix`` names the temporary file (so stale
    ones can be found and removed after a crash); by default a unique hidden name is used."""
    path = Path(path)
    folder = path.parent
    if make_dirs:
        folder.mkdir(parents=True, exist_ok=True)
    if temp_prefix is None:
        fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
        tmp = Path(name)
        f = os.fdopen(fd, "w", encoding="utf-8", newline="")
    else:
        tmp = folder / f"{temp_prefix}{os.getpid()}-{threading.get_ident()}"
        f = open(tmp, "w", encoding="utf-8", newline="")  # noqa: SIM115 - closed below
    try:
        with f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            tmp.unlink()
        except OSError:
            pass
        raise
    try:
        dfd = os.open(folder, os.O_RDONLY)
    except OSError:
        return  # platforms without directory file descriptors
    try:
        os.fsync(dfd)
    except OSError:
        pass
    finally:
        os.close(dfd)
