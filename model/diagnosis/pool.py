"""Candidate fits on worker processes, each a fork of the process that set up the diagnosis.

A fit job (``problem.FitJob``) is the arguments of one form's search on a
``Problem``. Run on threads, the searches' Python between the compiled kernel
calls (Nelder-Mead's steps, the least squares of the linear parameters, the
bookkeeping of every evaluation) takes turns on the interpreter lock: on a
Prandtl-Ishlinskii plant two threads took 20.9 s where one took 22.4 s,
while two single-threaded processes each took about as long as one alone.
So the jobs run on processes forked once per diagnosis, after the problem is
set up: each worker holds its own copy of the problem (log, nominal model,
caches) and gets only a job's arguments; the fit comes back whole, with the
ends of the searches it ran, which go out with later jobs to every worker (a
search from where another started takes that one's end, ``problem``).

The caches a fit uses are memos of pure functions (core runs, input terms, a
search's end by where it started), so a worker that lacks one computes the same
value: the fits, and the report, are those of one process. Where processes
cannot be forked (not POSIX) or started (a process limit), or the pool breaks (a
worker killed), the jobs run on threads in this process instead, with a warning.
"""

from __future__ import annotations

import logging
import multiprocessing
from collections.abc import Callable
from concurrent.futures import Executor, Future, ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool

from warpbridge.model.diagnosis.problem import Fit, FitJob, Problem

log = logging.getLogger(__name__)

_PROBLEM: Problem | None = None  # the problem a forked worker inherited (set in the parent just before the fork)


def _ready() -> bool:
    return _PROBLEM is not None


def _fit_in_worker(args: tuple, ends: list) -> tuple[Fit, list]:
    """(the job's fit, the search ends it found) on this worker's copy of the problem, which first keeps the
    search ends the others found (``ends``)."""
    if _PROBLEM is None:
        raise RuntimeError("a fit job reached a worker without its problem")
    n = _PROBLEM.keep_search_ends(ends)
    fit = _PROBLEM.fit_form_job(args)
    return fit, _PROBLEM.search_ends(n)


def can_fork() -> bool:
    return "fork" in multiprocessing.get_all_start_methods()


class FitPool:
    """``workers`` processes forked now, each with a copy of ``prob`` as it stands (threads when they cannot
    be forked). ``submit`` takes fit jobs of ``prob`` (others run in this process); use as a context manager."""

    def __init__(self, prob: Problem, workers: int) -> None:
        global _PROBLEM
        self.prob = prob
        self.workers = workers
        self.processes = can_fork()
        self._fallback: ThreadPoolExecutor | None = None
        if not self.processes:
            self._executor: Executor = self._threads()
            return
        _PROBLEM = prob
        try:
            self._executor = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork"))
            if not self._executor.submit(_ready).result():  # the first submit forks every worker
                raise RuntimeError("a worker started without the problem")
        except (OSError, RuntimeError, BrokenProcessPool) as e:  # no processes to be had (limits, memory)
            log.warning("no worker processes for the diagnosis (%s); fitting on threads in this process", e)
            self.processes = False
            self._executor = self._threads()
        finally:
            _PROBLEM = None  # the workers have their copies; this process keeps none alive

    def submit(self, job: Callable[[], Fit]) -> Future:
        if self.processes and isinstance(job, FitJob) and job.problem is self.prob:
            try:
                return self._executor.submit(_fit_in_worker, job.args, self.prob.search_ends())
            except BrokenProcessPool:
                self._broken()
        return self._threads().submit(job)

    def result(self, future: Future, job: Callable[[], Fit]) -> Fit:
        """The fit of ``future`` (submitted for ``job``); a job lost with a broken pool is run here instead."""
        try:
            fit = future.result()
        except BrokenProcessPool:
            self._broken()
            return job()
        if isinstance(fit, tuple):  # from a worker: its core runs and search ends join this process's
            fit, ends = fit
            self.prob.count_runs(fit.evaluations)
            self.prob.keep_search_ends(ends)
        return fit

    def _broken(self) -> None:
        if self.processes:
            log.warning("the diagnosis's worker processes stopped; fitting on threads in this process instead")
            self.processes = False

    def _threads(self) -> ThreadPoolExecutor:
        if self._fallback is None:
            self._fallback = ThreadPoolExecutor(self.workers)
        return self._fallback

    def __enter__(self) -> FitPool:
        return self

    def __exit__(self, *exc) -> None:
        self._executor.shutdown(wait=True, cancel_futures=True)
        if self._fallback is not None and self._fallback is not self._executor:
            self._fallback.shutdown(wait=True)
