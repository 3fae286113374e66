"""The diagnosis's fits on worker processes: the same fits as in this process, whatever happens to the pool."""

from __future__ import annotations

import contextlib
import logging
import os
import signal

import numpy as np
import pytest

from warpbridge.model.boucwen import BoucWenParams, inverse
from warpbridge.model.diagnosis import pool as diag_pool
from warpbridge.model.diagnosis.pool import FitPool
from warpbridge.model.diagnosis.problem import Problem
from warpbridge.model.effects import Effects
from warpbridge.model.excitation import filtered_random
from warpbridge.model.plant import Plant

P = BoucWenParams.paper()
FS = 200.0

pytestmark = pytest.mark.skipif(not diag_pool.can_fork(), reason="worker processes are forked")


def _problem(seed: int = 4) -> Problem:
    t = np.arange(int(8.0 * FS)) / FS
    u, _ = inverse(P, filtered_random(t, 1.0, 4.5, 7.0, seed=seed))
    _, w = Plant(P, Effects(friction_scale=1.3, friction_pivot=0.5)).simulate(t, u, None)
    w = w + 0.03 * np.random.default_rng(seed).standard_normal(t.size)
    return Problem(t, u, w, None, P, Effects())


def _same(a, b) -> bool:
    return (a.effects == b.effects and np.array_equal(a.w_pred, b.w_pred) and a.train_mse == b.train_mse
            and a.score_mse == b.score_mse and a.coords == b.coords)


def test_fits_on_worker_processes_are_those_of_this_process_and_their_runs_are_counted():
    here = _problem()
    jobs_here = here.fit_jobs(("friction",))
    local = [job() for job in jobs_here]
    prob = _problem()
    before = prob.evaluations  # the nominal's run
    jobs = prob.fit_jobs(("friction",))
    assert len(jobs) >= 2  # the forms of friction, each a job
    with FitPool(prob, 2) as pool:
        assert pool.processes
        futures = [pool.submit(job) for job in jobs]
        remote = [pool.result(f, job) for f, job in zip(futures, jobs, strict=True)]
    assert all(_same(a, b) for a, b in zip(local, remote, strict=True))
    # no core ran here (a fit on a thread of this process keeps its grid's runs in this problem): every run
    # counted is a worker's, as each fit says
    assert here._grid_cache and not prob._grid_cache
    assert prob.evaluations - before == sum(f.evaluations for f in remote) > 0
    # and the searches they ran are known here: the same fit in this process takes their ends
    again = prob.fit(("friction",))
    assert _same(again, Problem.best_of(remote)) and again.evaluations < sum(f.evaluations for f in remote)


def test_a_pool_whose_workers_die_fits_on_in_this_process(caplog):
    prob = _problem(seed=6)
    jobs = prob.fit_jobs(("friction",))
    expected = [job() for job in _problem(seed=6).fit_jobs(("friction",))]
    with FitPool(prob, 2) as pool:
        for p in list(pool._executor._processes.values()):
            # once one worker dies the executor's manager thread may end and reap the others first
            with contextlib.suppress(ProcessLookupError):
                os.kill(p.pid, signal.SIGKILL)
            p.join()
        with caplog.at_level(logging.WARNING, logger="warpbridge.model.diagnosis.pool"):
            futures = [pool.submit(job) for job in jobs]
            got = [pool.result(f, job) for f, job in zip(futures, jobs, strict=True)]
    assert all(_same(a, b) for a, b in zip(expected, got, strict=True))
    assert not pool.processes and "threads in this process" in caplog.text


def test_without_fork_the_pool_is_threads_of_this_process(monkeypatch):
    monkeypatch.setattr(diag_pool, "can_fork", lambda: False)
    prob = _problem()
    before = prob.evaluations
    jobs = prob.fit_jobs(("delay",))
    with FitPool(prob, 2) as pool:
        assert not pool.processes
        got = [pool.result(pool.submit(job), job) for job in jobs]
    assert prob.evaluations - before == sum(f.evaluations for f in got) > 0
    assert all(_same(a, b) for a, b in zip(got, [job() for job in _problem().fit_jobs(("delay",))], strict=True))


def test_a_pool_that_cannot_start_its_workers_fits_on_threads(monkeypatch, caplog):
    def refused(*args, **kwargs):
        raise OSError("Resource temporarily unavailable")

    monkeypatch.setattr(diag_pool, "ProcessPoolExecutor", refused)
    prob = _problem()
    jobs = prob.fit_jobs(("delay",))
    with caplog.at_level(logging.WARNING, logger="warpbridge.model.diagnosis.pool"):
        with FitPool(prob, 2) as pool:
            got = [pool.result(pool.submit(job), job) for job in jobs]
    assert not pool.processes and "Resource temporarily unavailable" in caplog.text
    assert all(_same(a, b) for a, b in zip(got, [job() for job in _problem().fit_jobs(("delay",))], strict=True))
