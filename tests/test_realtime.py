"""Real-time settings of the bridge process (``bridge.realtime``): what is asked of the kernel, what a
refusal looks like, the config keys, and the real kernel's state after ``apply`` in a fresh process."""

from __future__ import annotations

import errno
import json
import logging
import os
import re
import resource
import subprocess
import sys
import textwrap

import pytest
from helpers import LOOP_SERVO_WINGS

from warpbridge.bridge import realtime
from warpbridge.bridge.config import LoopConfig, parse_config
from warpbridge.bridge.errors import UserError

INF = resource.RLIM_INFINITY


class FakeSystem(realtime.System):
    """Records every call; ``refuse`` maps a call name to the errno it fails with."""

    def __init__(self, *, cpus=frozenset({0, 1}), memlock=(INF, INF), ipc_lock=False, nice=0, refuse=None,
                 policy=(os.SCHED_OTHER, 0)):
        super().__init__()
        self._policy = policy
        self.calls: list[tuple] = []
        self._cpus, self._memlock, self._ipc_lock, self._nice = set(cpus), memlock, ipc_lock, nice
        self.refuse = refuse or {}

    def _call(self, name, *args):
        self.calls.append((name, *args))
        if name in self.refuse:
            e = self.refuse[name]
            raise OSError(e, os.strerror(e))

    def cpus(self):
        return set(self._cpus)

    def threads(self):
        return [101, 102]

    def set_affinity(self, tid, cpus):
        self._call("set_affinity", tid, frozenset(cpus))

    def current(self):
        return self._policy

    def set_fifo(self, priority):
        if self.refuse.get("set_fifo") and self._policy[0] == os.SCHED_FIFO and priority <= self._policy[1]:
            self.calls.append(("set_fifo", priority))  # the kernel lets a thread keep or lower its own
            return
        self._call("set_fifo", priority)

    def set_other(self):
        self._call("set_other")

    def set_nice(self, nice):
        self._call("set_nice", nice)

    def get_nice(self):
        return self._nice

    def memlock_limit(self):
        return self._memlock

    def raise_memlock_limit(self, soft, hard):
        self._call("raise_memlock_limit", soft, hard)
        self._memlock = (soft, hard)

    def has_ipc_lock(self):
        return self._ipc_lock

    def mlockall(self, flags):
        self._call("mlockall", flags)

    def gc_freeze(self):
        self._call("gc_freeze")
        return 1234


def names(fake: FakeSystem) -> list[str]:
    return [c[0] for c in fake.calls]


def test_everything_permitted_pins_raises_locks_and_freezes():
    fake = FakeSystem()
    rep = realtime.apply(LoopConfig(cpu=1, priority=30), fake)
    assert ("set_affinity", 101, frozenset({1})) in fake.calls and ("set_affinity", 102, frozenset({1})) in fake.calls
    assert ("set_fifo", 30) in fake.calls
    assert "set_nice" not in names(fake) and "set_other" not in names(fake)
    assert ("mlockall", 1 | 2 | 4) in fake.calls  # MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT
    assert names(fake)[-1] == "gc_freeze"
    assert rep.refused == []
    assert any("CPU 1" in a for a in rep.applied) and any("SCHED_FIFO priority 30" in a for a in rep.applied)
    assert any("1234" in a for a in rep.applied)


def test_refusals_are_reported_with_the_reason_and_the_rest_still_applies(caplog):
    fake = FakeSystem(memlock=(8 << 20, 8 << 20), refuse={"set_fifo": errno.EPERM, "set_nice": errno.EACCES})
    with caplog.at_level(logging.INFO, logger="warpbridge.bridge.realtime"):
        rep = realtime.apply(LoopConfig(priority=20, nice=-5), fake)
    refused = dict(rep.refused)
    assert "EPERM" in refused["SCHED_FIFO priority 20"] and "CAP_SYS_NICE" in refused["SCHED_FIFO priority 20"]
    assert "EACCES" in refused["nice -5"]
    assert "8 MiB" in refused["locked memory"] and "LimitMEMLOCK=infinity" in refused["locked memory"]
    assert "mlockall" not in names(fake)  # never lock under a finite limit: allocations would fail later
    assert ("set_nice", -5) in fake.calls  # the fallback was tried after SCHED_FIFO was refused
    assert "set_affinity" not in names(fake)  # no cpu given: left to the scheduler
    assert "gc_freeze" in names(fake)
    text = caplog.text
    assert "refused: SCHED_FIFO priority 20 (EPERM" in text and "refused: nice -5" in text
    assert all(r.levelno == logging.INFO for r in caplog.records)


def test_a_real_time_policy_set_from_outside_is_kept_when_raising_it_is_refused():
    """systemd's CPUSchedulingPolicy=fifo at 10 and [loop] priority 30 without the right to raise it."""
    fake = FakeSystem(policy=(os.SCHED_FIFO, 10), refuse={"set_fifo": errno.EPERM})
    rep = realtime.apply(LoopConfig(priority=30), fake)
    assert "SCHED_FIFO priority 30" in dict(rep.refused)
    assert ("set_fifo", 10) in fake.calls  # the same priority again, now with SCHED_RESET_ON_FORK
    assert "set_other" not in names(fake) and "set_nice" not in names(fake)  # never demoted to ordinary
    assert any("SCHED_FIFO priority 10 as started" in a for a in rep.applied)


def test_priority_zero_uses_nice_without_trying_fifo():
    fake = FakeSystem()
    rep = realtime.apply(LoopConfig(priority=0, nice=-7), fake)
    assert "set_fifo" not in names(fake)
    assert names(fake)[:2] == ["set_other", "set_nice"] and ("set_nice", -7) in fake.calls
    assert any("nice -7" in a for a in rep.applied)


def test_a_finite_soft_memlock_limit_is_raised_to_an_unlimited_hard_one():
    fake = FakeSystem(memlock=(64 << 10, INF))
    rep = realtime.apply(LoopConfig(), fake)
    assert ("raise_memlock_limit", INF, INF) in fake.calls
    assert ("mlockall", 7) in fake.calls and not rep.refused


def test_cap_ipc_lock_locks_whatever_the_limit():
    fake = FakeSystem(memlock=(64 << 10, 64 << 10), ipc_lock=True)
    realtime.apply(LoopConfig(), fake)
    assert ("mlockall", 7) in fake.calls


def test_a_cpu_the_process_may_not_use_is_refused_not_forced():
    fake = FakeSystem(cpus={0, 1})
    rep = realtime.apply(LoopConfig(cpu=3), fake)
    assert "set_affinity" not in names(fake)
    assert "[0, 1]" in dict(rep.refused)["CPU 3"]


def test_off_changes_nothing():
    fake = FakeSystem()
    rep = realtime.apply(LoopConfig(realtime="off", cpu=1), fake)
    assert fake.calls == [] and rep.applied == [] and rep.refused == []


# ---------------------------------------------------------------------- config keys


def config(loop: str) -> dict:
    import tomllib

    return tomllib.loads(f"""
[link]
connection = "udpin:127.0.0.1:14550"
[loop]
{loop}
{LOOP_SERVO_WINGS}""")


def test_loop_keys_parse_with_defaults(tmp_path):
    cfg = parse_config(config(""), tmp_path)
    assert (cfg.loop.realtime, cfg.loop.cpu, cfg.loop.priority, cfg.loop.nice) == ("auto", None, 20, -10)
    cfg = parse_config(config('realtime = "off"\ncpu = 3\npriority = 0\nnice = 5'), tmp_path)
    assert (cfg.loop.realtime, cfg.loop.cpu, cfg.loop.priority, cfg.loop.nice) == ("off", 3, 0, 5)


@pytest.mark.parametrize("line, key", [('realtime = "on"', "realtime"), ("priority = 100", "priority"),
                                       ("priority = 2.5", "priority"), ("nice = -21", "nice"),
                                       ("nice = 20", "nice"), ("cpu = -1", "cpu"), ('cpu = "3"', "cpu")])
def test_bad_loop_keys_are_refused_naming_the_key(tmp_path, line, key):
    with pytest.raises(UserError, match=rf"\[loop\] {key}"):
        parse_config(config(line), tmp_path)


# ---------------------------------------------------------------------- the real kernel

PROBE = textwrap.dedent("""
    import gc, json, os, sys, threading
    from warpbridge.bridge import realtime
    from warpbridge.bridge.config import LoopConfig
    cpu = max(os.sched_getaffinity(0))
    rep = realtime.apply(LoopConfig(cpu=cpu, priority=7, nice=3))
    seen = {}
    def probe():
        seen["policy"] = os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK
        seen["nice"] = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    t = threading.Thread(target=probe)
    t.start(); t.join()
    status = dict(l.split(":", 1) for l in open("/proc/self/status").read().splitlines() if ":" in l)
    print(json.dumps({
        "applied": rep.applied, "refused": [w for w, _ in rep.refused], "cpu": cpu,
        "policy": os.sched_getscheduler(0) & ~os.SCHED_RESET_ON_FORK, "priority": os.sched_getparam(0).sched_priority,
        "nice": os.getpriority(os.PRIO_PROCESS, threading.get_native_id()),
        "affinity": sorted(os.sched_getaffinity(0)), "thread": seen, "frozen": gc.get_freeze_count(),
        "vmlck_kb": int(status["VmLck"].split()[0]),
    }))
""")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux scheduling and memory locking")
def test_what_apply_reports_is_what_the_kernel_then_shows():
    """In a fresh process: every setting reported applied is in force, every one refused is not."""
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    applied = " ".join(got["applied"])
    assert got["affinity"] == [got["cpu"]] and f"CPU {got['cpu']}" in applied
    if "SCHED_FIFO priority 7" in got["refused"]:  # unprivileged: ordinary scheduling, nice as permitted
        assert got["policy"] == os.SCHED_OTHER
        assert got["nice"] == 3 and "nice 3" in applied  # raising one's nice is always allowed
    else:
        assert "SCHED_FIFO priority 7" in applied
        assert (got["policy"], got["priority"]) == (os.SCHED_FIFO, 7)
    # a thread started after apply (the calibration fit, the parameter writer) is an ordinary one
    # (SCHED_RESET_ON_FORK: no real-time policy, no negative nice; from a real-time thread the kernel resets
    # the nice to 0, whatever nice the process was started with)
    thread_nice = 0 if got["policy"] == os.SCHED_FIFO else max(0, got["nice"])
    assert got["thread"]["policy"] == os.SCHED_OTHER and got["thread"]["nice"] == thread_nice
    if "locked memory" in got["refused"]:
        assert got["vmlck_kb"] == 0
    else:
        assert got["vmlck_kb"] > 1000  # the pages in use (imports, interpreter) are locked
    reported = int(re.search(r"(\d+) start-up objects frozen", applied).group(1))
    assert 1000 < got["frozen"] <= reported  # still frozen (less any freed since)
