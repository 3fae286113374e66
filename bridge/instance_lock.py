"""One bridge per parameter store: ``run``, ``run --check`` and ``calibrate`` hold an exclusive lock beside it.

Two processes on one configuration fight over everything it names: the servo board's port, the FC link's
port, the parameter store and the cycle log (which a second start truncates). The lock is an advisory
``flock`` on ``<params file>.lock`` holding the owner's pid; the kernel releases it when the process ends,
however it ends, so a crash leaves nothing to clean up.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

from warpbridge.bridge.errors import UserError
from warpbridge.hw.base import lock_exclusive

log = logging.getLogger(__name__)


class InstanceLock:
    """The lock of one parameter store, held from ``acquire`` until ``release`` (or the process's end)."""

    def __init__(self, params_file: str | os.PathLike[str]) -> None:
        self.path = Path(f"{os.fspath(params_file)}.lock")
        self._fd: int | None = None

    def acquire(self, what: str) -> InstanceLock:
        """Take the lock for ``what`` (the command); raises ``UserError`` naming the holder when another process
        has it."""
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:  # a read-only folder must not keep the wings from flying
            log.warning("%s: cannot create the lock %s (%s): a second bridge on this configuration would not be "
                        "refused", what, self.path, e.strerror or e)
            return self
        try:
            lock_exclusive(fd)  # the flock the bridge's serial ports take too
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "?"
            os.close(fd)
            raise UserError(f"{what}: another warpbridge (pid {holder}) is running with this configuration's "
                            f"parameter store ({self.path.with_suffix('')}); stop it first (e.g. systemctl stop "
                            "warpbridge): two would fight over the servo board, the FC link and the store") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode("ascii"), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor drops the flock
            self._fd = None

    def __enter__(self) -> InstanceLock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
