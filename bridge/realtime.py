"""What Linux offers the bridge's loop as a real-time process; ``[loop] realtime``, ``cpu``, ``priority``, ``nice``.

``apply(loop_config)`` is called once, just before the loop starts, in the thread
that runs the loop. With ``realtime = "auto"`` (the default) it tries, in order:

- CPU affinity (``cpu = N``): every thread of the process onto core N, so the loop
  never migrates and keeps its cache; give it a core the camera or telemetry
  process does not use (or isolate it with ``isolcpus=``);
- scheduling: ``SCHED_FIFO`` at ``priority`` (1-99) for the loop's thread, which then
  preempts every ordinary process on its core; if that is refused (it needs root,
  ``CAP_SYS_NICE`` or ``RLIMIT_RTPRIO``), or with ``priority = 0``, the ordinary
  scheduler at ``nice`` (-20..19; below 0 needs the same rights). Threads started
  later (the self-calibration fit, the parameter writer) do not inherit it
  (``SCHED_RESET_ON_FORK``): they run as ordinary threads and the loop preempts them;
- locked memory: ``mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT)``, so no page
  the loop touches is ever swapped out or dropped and faulted back from the SD
  card (pages are locked as they are used, the resident size does not grow). It
  needs ``RLIMIT_MEMLOCK`` unlimited (it is raised to the hard limit when that
  allows) or ``CAP_IPC_LOCK``: with a finite limit a growing process would have
  allocations refused, so then nothing is locked;
- the garbage collector: everything allocated during start-up (about 10^5
  objects: the imports, the model, the compiled kernels) is collected once and
  frozen (``gc.freeze``), so a full collection during flight scans only what the
  loop allocated since (microseconds) instead of everything (tens to hundreds of
  ms on a small board). The cycle itself allocates only short-lived scalars and
  small dicts that reference counting frees; the compiled model steps on
  preallocated parameter arrays.

Each step is logged at INFO as applied or refused, with the reason (``EPERM``
and what would grant it); a refused step never stops the bridge. ``"off"``
changes nothing: the systemd unit's settings (``CPUSchedulingPolicy=``,
``CPUAffinity=``, ``Nice=``) or the shell's stay as they are. See
``deploy/warpbridge.service`` and docs/hardware.md, "Real-time".
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import gc
import logging
import os
import resource
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

MODES = ("auto", "off")
MCL_CURRENT, MCL_FUTURE, MCL_ONFAULT = 1, 2, 4  # <sys/mman.h> on Linux
CAP_IPC_LOCK = 14  # <linux/capability.h>


@dataclass
class RealtimeReport:
    """What ``apply`` did: one line per setting applied, one (setting, reason) per refusal."""

    applied: list[str] = field(default_factory=list)
    refused: list[tuple[str, str]] = field(default_factory=list)

    def summary(self) -> str:
        parts = ["applied: " + ("; ".join(self.applied) or "nothing")]
        if self.refused:
            parts.append("refused: " + "; ".join(f"{what} ({why})" for what, why in self.refused))
        return "real time " + ", ".join(parts)


class System:
    """The calls ``apply`` makes, in one place so tests can stand in for the kernel."""

    def __init__(self) -> None:
        self._libc: Any = None

    def cpus(self) -> set[int]:
        return os.sched_getaffinity(0)

    def threads(self) -> list[int]:
        try:
            return [int(p.name) for p in Path("/proc/self/task").iterdir()]
        except OSError:
            return [threading.get_native_id()]

    def set_affinity(self, tid: int, cpus: set[int]) -> None:
        os.sched_setaffinity(tid, cpus)

    def set_fifo(self, priority: int) -> None:
        os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(priority))

    def current(self) -> tuple[int, int]:
        """(scheduling policy without flags, real-time priority) of the calling thread."""
        return os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK, os.sched_getparam(0).sched_priority

    def set_other(self) -> None:
        os.sched_setscheduler(0, os.SCHED_OTHER | os.SCHED_RESET_ON_FORK, os.sched_param(0))

    def set_nice(self, nice: int) -> None:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), nice)  # this thread only (Linux)

    def get_nice(self) -> int:
        return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())

    def memlock_limit(self) -> tuple[int, int]:
        return resource.getrlimit(resource.RLIMIT_MEMLOCK)

    def raise_memlock_limit(self, soft: int, hard: int) -> None:
        resource.setrlimit(resource.RLIMIT_MEMLOCK, (soft, hard))

    def has_ipc_lock(self) -> bool:
        """Whether the process holds CAP_IPC_LOCK (locking is then not bound by RLIMIT_MEMLOCK)."""
        try:
            for line in Path("/proc/self/status").read_text().splitlines():
                if line.startswith("CapEff:"):
                    return bool(int(line.split()[1], 16) >> CAP_IPC_LOCK & 1)
        except (OSError, ValueError):
            pass
        return False

    def mlockall(self, flags: int) -> None:
        if self._libc is None:
            self._libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        if self._libc.mlockall(ctypes.c_int(flags)) != 0:
            e = ctypes.get_errno()
            raise OSError(e, os.strerror(e))

    def gc_freeze(self) -> int:
        gc.collect()
        gc.freeze()
        return gc.get_freeze_count()


def _why(e: OSError, needs: str) -> str:
    name = errno.errorcode.get(e.errno or 0, "error")
    return f"{name}: {needs}" if e.errno in (errno.EPERM, errno.EACCES) else f"{name}: {e.strerror or e}"


def apply(loop: Any, system: System | None = None) -> RealtimeReport:
    """Apply ``loop``'s real-time settings (``realtime``, ``cpu``, ``priority``, ``nice``) to this
    process and to the calling thread (the loop's); log and return what was applied and refused."""
    sys_ = system or System()
    rep = RealtimeReport()
    if loop.realtime == "off":
        log.info("real time: off ([loop] realtime); scheduling, affinity and memory left as they are")
        return rep
    _affinity(loop.cpu, sys_, rep)
    _scheduling(loop.priority, loop.nice, sys_, rep)
    _lock_memory(sys_, rep)
    n = sys_.gc_freeze()
    rep.applied.append(f"garbage collector: {n} start-up objects frozen")
    for line in rep.applied:
        log.info("real time: %s", line)
    for what, why in rep.refused:
        log.info("real time: refused: %s (%s)", what, why)
    return rep


def _affinity(cpu: int | None, sys_: System, rep: RealtimeReport) -> None:
    if cpu is None:
        return
    allowed = sys_.cpus()
    if cpu not in allowed:
        rep.refused.append((f"CPU {cpu}", f"not one of this process's CPUs {sorted(allowed)}"))
        return
    try:
        for tid in sys_.threads():
            try:
                sys_.set_affinity(tid, {cpu})
            except ProcessLookupError:  # a thread that ended meanwhile
                pass
    except OSError as e:
        rep.refused.append((f"CPU {cpu}", _why(e, "the cpuset does not allow it")))
        return
    rep.applied.append(f"pinned to CPU {cpu}")


def _scheduling(priority: int, nice: int, sys_: System, rep: RealtimeReport) -> None:
    if priority > 0:
        try:
            sys_.set_fifo(priority)
            rep.applied.append(f"SCHED_FIFO priority {priority} for the loop's thread")
            return
        except OSError as e:
            rep.refused.append((f"SCHED_FIFO priority {priority}",
                                _why(e, "needs root, CAP_SYS_NICE or RLIMIT_RTPRIO >= the priority; "
                                        "see CPUSchedulingPolicy= in deploy/warpbridge.service")))
        policy, current = sys_.current()
        if policy in (os.SCHED_FIFO, os.SCHED_RR):  # set from outside (the unit, chrt): keep it
            if policy == os.SCHED_FIFO:
                try:
                    sys_.set_fifo(current)  # the same priority, now with SCHED_RESET_ON_FORK
                except OSError:
                    pass
            rep.applied.append(f"{'SCHED_FIFO' if policy == os.SCHED_FIFO else 'SCHED_RR'} priority {current} "
                               "as started (kept)")
            return
    try:
        sys_.set_other()  # SCHED_RESET_ON_FORK: threads started later do not inherit a negative nice
    except OSError as e:
        rep.refused.append(("ordinary scheduling policy", _why(e, "not permitted")))
        return
    if nice == sys_.get_nice():
        rep.applied.append(f"nice {nice} (already)")
        return
    try:
        sys_.set_nice(nice)
        rep.applied.append(f"nice {nice} for the loop's thread")
    except OSError as e:
        rep.refused.append((f"nice {nice}", _why(e, "below 0 needs root, CAP_SYS_NICE or RLIMIT_NICE; "
                                                    "see Nice= in deploy/warpbridge.service")))


def _lock_memory(sys_: System, rep: RealtimeReport) -> None:
    soft, hard = sys_.memlock_limit()
    inf = resource.RLIM_INFINITY
    if soft != inf and hard == inf:
        try:
            sys_.raise_memlock_limit(inf, inf)
            soft = inf
        except (OSError, ValueError):
            pass
    if soft != inf and not sys_.has_ipc_lock():
        rep.refused.append(("locked memory", f"RLIMIT_MEMLOCK is {_size(soft)}: a process bound by a finite "
                                             "limit would have its allocations refused once past it; set "
                                             "LimitMEMLOCK=infinity (deploy/warpbridge.service)"))
        return
    try:
        sys_.mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT)
    except OSError as e:
        why = "kernel older than 4.4 (no MCL_ONFAULT)" if e.errno == errno.EINVAL else _why(e, "needs CAP_IPC_LOCK")
        rep.refused.append(("locked memory", why))
        return
    rep.applied.append("memory locked as it is used (mlockall MCL_CURRENT|MCL_FUTURE|MCL_ONFAULT)")


def _size(n: int) -> str:
    return f"{n // 1024} KiB" if n < 1 << 20 else f"{n / (1 << 20):g} MiB"

