"""What ``warpbridge diagnose`` costs on 60 s at 500 Hz, two ways of running it side by side in the same run.

    python benchmarks/bench_diagnose_time.py [--compare threads|input-terms|band-travel|time-terms|opening-cap|
                                                        trial-reach|blow-up|passes|kept-runs|processes|schedule|
                                                        reverse-refits|code-before --against REV]
                                             [--threads 2] [--seed 2] [--plant 0] [--cases 10,12] [--families ...]
                                             [--case FAMILY/SEED/PLANT/CASE ...] [--repeats 1] [--cache DIR]

``--compare code-before --against REV``: this checkout against the code of git revision REV, each run in a
process of its own (REV's folders extracted with ``git archive`` and imported as ``warpbridge`` in place of this
one's), both on one thread; a reshaping must leave the reports identical.
``--compare threads`` (the default): one thread (``--jobs 1``, the code before the candidates were fitted side
by side) against ``--threads`` workers (``--jobs N``: worker processes since 18543fc, threads before; the
command's default is the cores free at its start).
``--compare schedule``: on ``--threads`` workers, each stage's fits handed out longest first
(``diagnose.hand_out_order``, by ``FitJob.expected_runs``) and the beam's two second rounds fitted side by side
(``Explorer.rounds``) (as shipped) against in the order they were asked for and one round at a time (the code
before); the reports must be identical.
``--compare reverse-refits``: on ``--threads`` workers, round 2's refit from the new effect's own fit run for the
two candidates of best screen and for every one that alone closed ``DiagnoseOptions.alone_share`` of the nominal's
training gap (as shipped) against for the two of best screen only (the code before); the verdicts are compared,
the reports differ by design (more refits, other alternatives).
``--compare input-terms``: the model-error correction's input terms reused (as shipped) against recomputed at
every evaluation (the code before they were cached), both on one thread. ``--compare band-travel``: the
correction's loop-shape terms stretched in travel with a friction band (as shipped: their input terms computed
again for every band a fit tries) against kept on the bench's travel scale (the code before; their height
still scales), both on one thread; the verdicts are compared, the reports differ by design.
``--compare time-terms``: the correction's rate and lag terms from what is kept per log (``model_error.TimeTerms``:
each lag's step factors, the rate's smoothing width) and its play states in one compiled pass (as shipped) against
the code before (a lag recomputing exp(-dt / tau) at every sample, a median of the steps at every evaluation, one
play after another), both on one thread; the reports must be identical.
``--compare opening-cap``: a play's start side judged on the log's opening with the forward map that gives up once
more of the opening than a candidate may leaves the model's monotone range (as shipped: that start costs inf)
against the uncapped map (the code before: every such sample searched for the range's edge), both on one thread;
the reports must be identical. The slow cases are on other plants than the default's: name them with ``--case``.
``--compare trial-reach``: the forward solve's trial warps kept within ``kernels.TRIAL_REACH`` of the last point
short of the sample's target before a bracket is found (as shipped) against unbounded (the code before: from a
near-flat slope a Newton guess went millions of degrees out, and every march there ran out of sub-steps).
``--compare blow-up``: a march bound to pass a blow-up of the hysteretic state ends as diverged at once (as
shipped, ``kernels.BLOWUP_SPARE``) against marched until |z| passes its cap (the code before: thousands of ever
shorter sub-steps per march). Both on one thread; these are compiled-in constants, so each variant runs in its
own process with its own numba cache (under ``--cache``), timed after an untimed warm-up on the log's first
10 s; the reports are compared.
``--compare passes``: what every evaluation of a candidate computes besides its core run, in compiled passes row
by row (as shipped: the play and lag states stepped together per sample, ``np.gradient``'s weights kept per log,
``initial_state.algebraic_z0`` in one pass; the correction's input terms at a band other than 1 kept for the last
two paths, for fits that hold a band while they move the rest) against the code before (one column after another,
``np.gradient`` and numpy calls at every evaluation, those input terms computed afresh), both on one thread; the
same arithmetic, so the reports must be identical.
``--compare kept-runs``: the core runs of the fits' starting grids kept for every thread, up to
``diag_fit.GRID_CACHE_BYTES``, and each search's end kept by where it started (as shipped: a later fit walking the
same grid through the same cores reuses them, and a search from the same effects over the same boxes takes the
first one's end) against only each thread's last few runs kept (the code before), both on ``--threads`` threads
(the command's default on two cores); the reports must be identical.
``--compare processes``: the candidate fits on ``--threads`` worker processes forked per diagnosis (as shipped,
``model.diag_pool``: each with its own interpreter lock; the search ends they find shared through the jobs)
against on as many threads of one process (the code before: every kept run shared, but the fits' Python taking
turns on one lock); the reports must be identical.

Cases are the blind benchmark's (``bench_diagnose_blind.py``: plant ``--plant`` (0) of each family at ``--seed``,
the case numbers given, or each ``--case`` family/seed/plant/case; 10-12 are its pairs, usually the slowest; all
six families unless ``--families``), the bench models from its cache (identified there when missing). Each case
runs plain ``diagnose`` through ``bridge.cli.main`` once per variant and repeat, the variants alternating in order,
one process at a time. The report must be the same either way (checked: the verdict, every fitted parameter and
every candidate's figures; only the count of core runs may differ, with the thread count or what is kept); the
table gives each case's times, their ratio and each variant's count of core runs (the report's
``model_evaluations``: a kept run is not counted again), then the median ratios and the slowest time per variant.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_diagnose_blind as blind  # noqa: E402
from plants import draw_plants  # noqa: E402

from warpbridge.bridge.commands import diagnose as diagnose_cmd  # noqa: E402
from warpbridge.model import initial_state, kernels, model_error  # noqa: E402
from warpbridge.model._jit import njit  # noqa: E402
from warpbridge.model.boucwen import forward  # noqa: E402
from warpbridge.model.diagnosis import pool as diag_pool  # noqa: E402
from warpbridge.model.diagnosis import problem as diag_fit  # noqa: E402
from warpbridge.model.diagnosis import search as diagnose  # noqa: E402
from warpbridge.model.diagnosis.options import DiagnoseOptions  # noqa: E402
from warpbridge.model.diagnosis.problem import Problem  # noqa: E402
from warpbridge.model.effects import lagged, play  # noqa: E402
from warpbridge.model.initial_state import squared_error  # noqa: E402

FAMILIES = ("bouc-wen", "bouc-wen-phys", "dahl", "prandtl-ishlinskii", "sheath", "lugre-sheath")


def _recomputed(self, x: np.ndarray, band: float = 1.0) -> tuple:
    """The baseline: the input terms computed afresh at every call."""
    return model_error.input_terms(x, self.x_span * band, plays=len(self.sets) >= 6)


_SHIPPED_INPUT_TERMS = model_error.ErrorModel._input_terms


def _bench_travel(self, x: np.ndarray, band: float = 1.0) -> tuple:
    """The baseline of ``--compare band-travel``: the input terms on the bench's travel scale at any band,
    kept per path (the code before the loop-shape terms were stretched with the band)."""
    return _SHIPPED_INPUT_TERMS(self, x, 1.0)


def _old_lag_states(t, w, rate_scale, terms=None):
    """The baseline of ``--compare time-terms``: each lag run on its own, exp(-dt / tau) at every sample."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    w = np.ascontiguousarray(w, dtype=np.float64)
    out = np.empty((w.size, len(model_error.LAG_TIMES_S)))
    for j, tau in enumerate(model_error.LAG_TIMES_S):
        out[:, j] = (lagged(t, w, tau, float(w[0])) - w) / (rate_scale * tau)
    return out


def _old_smooth_rate(t, w, terms=None):
    """The baseline of ``--compare time-terms``: ``np.gradient`` and the median step at every call."""
    r = np.gradient(w, t) if t.size > 2 else np.zeros_like(w)
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    k = max(1, int(round(model_error.RATE_SMOOTH_S / max(dt, 1e-9))))
    if k > 1:
        r = np.convolve(r, np.ones(k) / k, mode="same")
    return r


def _old_play_states(x, thresholds):
    """The baseline of ``--compare time-terms``: one ``model.effects.play`` after another."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    out = np.empty((x.size, len(thresholds)))
    for j, r in enumerate(thresholds):
        out[:, j] = (x - play(x, 2.0 * float(r), float(x[0]))) / r
    return out


def _uncapped_opening(self, p, x: np.ndarray) -> float:
    """The baseline of ``--compare opening-cap``: the opening's squared error from the uncapped forward map."""
    m = self._opening
    return squared_error(forward(p, np.ascontiguousarray(x[:m]), z0=self.z0_for(p, x))[0], self.w[:m])


_SHIPPED_OPENING = Problem._opening_cost
_SHIPPED_SEARCH = Problem._search


def _unkept_search(self, boxes, s0, build, cost, lin, max_evals):
    """The baseline of ``--compare kept-runs``: every search run afresh."""
    return self._brent(cost, s0) if len(boxes) == 1 else self._nelder_mead(cost, s0, max_evals)


_SHIPPED_CAN_FORK = diag_pool.can_fork


def _no_fork() -> bool:
    """The baseline of ``--compare processes``: the fits on threads of this process."""
    return False


_SHIPPED_ROUNDS = diagnose.Explorer.rounds
_SHIPPED_ORDER = diagnose.hand_out_order


def _one_by_one(self, selections):
    """The baseline of ``--compare schedule``: each round's fits handed out on their own."""
    return [_SHIPPED_ROUNDS(self, [s])[0] for s in selections]


def _as_asked(jobs) -> list[int]:
    """The baseline of ``--compare schedule``: the jobs handed out in the order they were asked for."""
    return list(range(len(jobs)))


_TIME_TERMS_BASELINE = {"lag_states": _old_lag_states, "_smooth_rate": _old_smooth_rate,
                        "play_states": _old_play_states}


@njit(cache=True)
def _column_play_states(x, thresholds):
    """The baseline of ``--compare passes``: one compiled pass per play, column by column."""
    out = np.empty((x.shape[0], thresholds.shape[0]))
    for j in range(thresholds.shape[0]):
        r = thresholds[j]
        out[:, j] = (x - play(x, 2.0 * r, x[0])) / r
    return out


@njit(cache=True)
def _column_lags(w, factors, denom):
    """The baseline of ``--compare passes``: one lag after another, column by column."""
    out = np.empty((w.shape[0], factors.shape[0]))
    for j in range(factors.shape[0]):
        y = w[0] if w.shape[0] else 0.0
        for k in range(w.shape[0]):
            a = factors[j, k]
            y = a * y + (1.0 - a) * w[k]
            out[k, j] = (y - w[k]) / denom[j]
    return out


def _numpy_smooth_rate(t, w, terms=None):
    """The baseline of ``--compare passes``: ``np.gradient`` at every call, the smoothing width kept."""
    r = np.gradient(w, t) if t.size > 2 else np.zeros_like(w)
    k = (terms if terms is not None else model_error.time_terms(t)).smooth
    if k > 1:
        r = np.convolve(r, np.ones(k) / k, mode="same")
    return r


def _numpy_algebraic_z0(params, u, w) -> float:
    """The baseline of ``--compare passes``: ``initial_state.algebraic_z0`` in numpy calls (the code before)."""
    u = np.asarray(u, dtype=np.float64)
    w = np.asarray(w, dtype=np.float64)
    span = float(np.nanmax(u) - np.nanmin(u)) if u.size else 0.0
    if span <= 0:
        k = min(u.size, initial_state.FIRST_MAX)
    else:
        moved = np.abs(u[: initial_state.FIRST_MAX] - u[0]) > 0.02 * span
        k = max(1, int(np.argmax(moved)) if moved.any() else min(u.size, initial_state.FIRST_MAX))
    z = initial_state.algebraic_z(params, u[:k], w[:k])
    z = z[np.isfinite(z)]
    if z.size == 0:
        return 0.0
    lo, hi = initial_state.reachable_band(params, float(np.nanmedian(w[:k])) if np.isfinite(w[:k]).any() else 0.0)
    return float(np.clip(np.median(z), lo, hi))


def _uncached_band_terms(self, x: np.ndarray, band: float = 1.0) -> tuple:
    """The baseline of ``--compare passes``: the input terms at a band other than 1 computed afresh at every
    call (those at band 1 kept as shipped)."""
    if band != 1.0:
        return model_error.input_terms(x, self.x_span * band, plays=len(self.sets) >= 6)
    return _SHIPPED_INPUT_TERMS(self, x, band)


_PASSES_BASELINE = {(model_error.ErrorModel, "_input_terms"): _uncached_band_terms,
                    (model_error, "_play_states"): _column_play_states, (model_error, "_lag_columns"): _column_lags,
                    (model_error, "_smooth_rate"): _numpy_smooth_rate,
                    (diag_fit, "algebraic_z0"): _numpy_algebraic_z0}


_KERNEL_VARIANT_RUN = """
import sys, time
from warpbridge.model import kernels
for item in sys.argv[1].split(","):  # before the first compile: numba freezes module constants into the kernels
    if item:
        name, value = item.split("=")
        setattr(kernels, name, float(value))
from warpbridge.bridge.cli import main
if main(sys.argv[2:3] + [sys.argv[3], "--quiet", "--jobs", "1"] + sys.argv[5:]) != 0:
    sys.exit("warm-up failed")
t0 = time.perf_counter()
code = main(sys.argv[2:3] + [sys.argv[4], "--quiet", "--jobs", "1"] + sys.argv[5:])
print(time.perf_counter() - t0)
sys.exit(code)
"""

KERNEL_BASELINES = {"trial-reach": "TRIAL_REACH=inf", "blow-up": "BLOWUP_SPARE=inf"}  # the compiled-in constants

_REVISION_RUN = """
import sys, time
# the code of the revision in sys.argv[1] as the package warpbridge: this checkout's (an editable install's
# finder, or an installed wheel) out of the way
sys.meta_path = [f for f in sys.meta_path if "editable" not in repr(f).lower()]
sys.path.insert(0, sys.argv[1])
import warpbridge.model
assert warpbridge.model.__file__.startswith(sys.argv[1]), warpbridge.model.__file__
from warpbridge.bridge.cli import main
if main(["diagnose", sys.argv[2], "--quiet", "--jobs", "1"] + sys.argv[4:]) != 0:
    sys.exit("warm-up failed")
t0 = time.perf_counter()
code = main(["diagnose", sys.argv[3], "--quiet", "--jobs", "1"] + sys.argv[4:])
print(time.perf_counter() - t0)
sys.exit(code)
"""


def revision_tree(rev: str, where: Path) -> Path:
    """A folder holding the package ``warpbridge`` of git revision ``rev`` (its four folders from ``git
    archive``), to put first on ``sys.path``."""
    src = where / "src"
    src.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(["git", "-C", str(blind.ROOT), "archive", rev, "bridge", "model", "hw", "sitl"],
                             capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(src)], input=archive, check=True)
    pkg = where / "pkg" / "warpbridge"
    pkg.mkdir(parents=True, exist_ok=True)
    for name in ("bridge", "model", "hw", "sitl"):
        link = pkg / name
        if not link.exists():
            link.symlink_to(src / name, target_is_directory=True)
    return where / "pkg"


def process_diagnose(field_csv: Path, model: Path, out: Path, cache: Path, overrides: str = "",
                     tree: Path | None = None) -> float:
    """Seconds of one plain ``diagnose`` on one thread in a process of its own, after an untimed warm-up on the
    log's first 10 s (which compiles the kernels into the variant's own numba cache the first time): of the code
    in ``tree`` (``revision_tree``), or of this checkout with its kernels compiled with the ``overrides`` of
    ``kernels``' constants ("NAME=value,..."; empty: as shipped)."""
    lines = field_csv.read_text().splitlines(keepends=True)
    t0 = float(lines[1].split(",")[0])
    head = field_csv.with_name(field_csv.stem + "-head.csv")
    head.write_text("".join([lines[0]] + [ln for ln in lines[1:] if float(ln.split(",")[0]) - t0 < 10.0]))
    rest = ["--model", str(model), "--report", str(out)]
    if tree is None:
        argv = [sys.executable, "-c", _KERNEL_VARIANT_RUN, overrides, "diagnose", str(head), str(field_csv), *rest]
        numba = cache / "numba" / ("kernels-" + (overrides or "shipped"))
    else:
        argv = [sys.executable, "-c", _REVISION_RUN, str(tree), str(head), str(field_csv), *rest]
        numba = tree.parent / "numba"
    proc = subprocess.run(argv, env=dict(os.environ, NUMBA_CACHE_DIR=str(numba)), capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"diagnose failed: {proc.stderr[-2000:]}")
    return float(proc.stdout.strip().splitlines()[-1])


def _strip(report: dict) -> dict:
    return {k: v for k, v in report.items() if k not in ("seconds", "created", "model_evaluations")}


def timed_diagnose(field_csv: Path, model: Path, out: Path, new: bool, compare: str, threads: int, cache: Path,
                   tree: Path | None = None) -> tuple[float, dict]:
    """(seconds, report) of one plain ``diagnose``: the shipped variant when ``new``, else the baseline (for
    ``code-before``, the code in ``tree``)."""
    if compare == "code-before":
        seconds = process_diagnose(field_csv, model, out, cache, tree=None if new else tree)
        return seconds, json.loads(out.read_text())
    if compare in KERNEL_BASELINES:
        seconds = process_diagnose(field_csv, model, out, cache, "" if new else KERNEL_BASELINES[compare])
        return seconds, json.loads(out.read_text())
    cached = model_error.ErrorModel._input_terms
    shipped = {name: getattr(model_error, name) for name in _TIME_TERMS_BASELINE}
    shipped_passes = {key: getattr(*key) for key in _PASSES_BASELINE}
    jobs = threads if (compare == "threads" and new) or compare in ("kept-runs", "processes", "schedule",
                                                                     "reverse-refits") else 1
    grid_bytes = diag_fit.GRID_CACHE_BYTES
    if compare == "kept-runs" and not new:
        diag_fit.GRID_CACHE_BYTES = 0
        Problem._search = _unkept_search
    if compare == "input-terms" and not new:
        model_error.ErrorModel._input_terms = _recomputed
    if compare == "band-travel" and not new:
        model_error.ErrorModel._input_terms = _bench_travel
    if compare == "time-terms" and not new:
        for name, fn in _TIME_TERMS_BASELINE.items():
            setattr(model_error, name, fn)
    if compare == "opening-cap" and not new:
        Problem._opening_cost = _uncapped_opening
    if compare == "passes" and not new:
        for (module, name), fn in _PASSES_BASELINE.items():
            setattr(module, name, fn)
    if compare == "processes" and not new:
        diag_pool.can_fork = _no_fork
    if compare == "schedule" and not new:
        diagnose.Explorer.rounds = _one_by_one
        diagnose.hand_out_order = _as_asked
    if compare == "reverse-refits" and not new:
        diagnose_cmd.DiagnoseOptions = functools.partial(DiagnoseOptions, alone_share=math.inf)
    try:
        t0 = time.perf_counter()
        code, text = blind.run_cli(["diagnose", str(field_csv), "--model", str(model), "--report", str(out),
                                    "--quiet", "--jobs", str(jobs)])
        seconds = time.perf_counter() - t0
    finally:
        model_error.ErrorModel._input_terms = cached
        diag_fit.GRID_CACHE_BYTES = grid_bytes
        Problem._search = _SHIPPED_SEARCH
        Problem._opening_cost = _SHIPPED_OPENING
        diag_pool.can_fork = _SHIPPED_CAN_FORK
        diagnose.Explorer.rounds = _SHIPPED_ROUNDS
        diagnose.hand_out_order = _SHIPPED_ORDER
        diagnose_cmd.DiagnoseOptions = DiagnoseOptions
        for name, fn in shipped.items():
            setattr(model_error, name, fn)
        for (module, name), fn in shipped_passes.items():
            setattr(module, name, fn)
    if code != 0:
        raise RuntimeError(f"diagnose failed: {text}")
    return seconds, json.loads(out.read_text())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--compare", choices=("threads", "input-terms", "band-travel", "time-terms", "opening-cap",
                                              "trial-reach", "blow-up", "passes", "kept-runs", "processes",
                                              "schedule", "reverse-refits", "code-before"),
                    default="threads",
                    help="threads: --jobs 1 against --jobs N; input-terms: the correction's input terms reused "
                         "against recomputed; band-travel: the loop-shape terms stretched in travel with the band "
                         "against kept on the bench's travel scale; time-terms: the rate and lag terms from weights "
                         "kept per log and the plays in one pass against recomputed at every evaluation; "
                         "opening-cap: a play's start side judged with the capped forward map against the uncapped "
                         "one; trial-reach: the forward solve's trial warps bounded before a bracket against "
                         "unbounded; blow-up: a march bound to pass a blow-up of the state ended at once against "
                         "marched to the cap; passes: the per-evaluation terms (plays, lags, rate, start state) "
                         "in row-order compiled passes, and the input terms at a held band kept, against the code "
                         "before; kept-runs: the starting grids' core runs kept for every thread and each search's "
                         "end by its start, against each thread's last few runs only, on --threads threads; "
                         "processes: the fits on --threads worker processes against as many threads; schedule: "
                         "the jobs handed out longest first and the beam's second rounds together, against in "
                         "the order asked for and one round at a time, on --threads workers; reverse-refits: "
                         "round 2's refit from the new effect's own fit also for every candidate that closed a "
                         "share alone, against for the two of best screen only, on --threads workers; "
                         "code-before: this checkout against the code of --against, one thread each")
    ap.add_argument("--against", default="", metavar="REV", help="the git revision --compare code-before runs")
    ap.add_argument("--threads", type=int, default=2,
                    help="workers of the shipped variant (--compare threads; of both with kept-runs, processes, "
                         "schedule and reverse-refits)")
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--cases", default="10,12", help="case numbers of the blind benchmark (10-12: pairs)")
    ap.add_argument("--families", default=",".join(FAMILIES), help="plant families (default: all six)")
    ap.add_argument("--plant", type=int, default=0, help="which plant of each family (the blind benchmark draws 3)")
    ap.add_argument("--case", action="append", default=[], metavar="FAMILY/SEED/PLANT/CASE",
                    help="a case named in full (repeatable); instead of --families, --seed, --plant and --cases")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--cache", type=Path, default=blind.default_cache())
    a = ap.parse_args(argv)
    args = argparse.Namespace(cache=a.cache, bench_duration=blind.BENCH_S, rate=blind.RATE,
                              duration=blind.FIELD_S, timing_every=1)
    cases = [int(c) for c in a.cases.split(",")]
    rows = []
    base_name, new_name = {"threads": ("1 thread", f"{a.threads} workers"), "input-terms": ("recomputed", "reused"),
                           "band-travel": ("bench travel", "stretched"), "time-terms": ("before", "kept"),
                           "opening-cap": ("uncapped", "capped"), "trial-reach": ("unbounded", "bounded"),
                           "blow-up": ("to the cap", "ended"), "passes": ("before", "passes"),
                           "kept-runs": ("per thread", "kept"), "processes": ("threads", "processes"),
                           "schedule": ("as asked", "longest"), "reverse-refits": ("best two", "alone too"),
                           "code-before": (a.against or "before", "this code")}[a.compare]
    what = {"threads": f"one thread (baseline) vs {a.threads} worker processes (--jobs {a.threads})",
            "input-terms": "input terms reused (shipped) vs recomputed (baseline), one thread",
            "band-travel": "loop-shape terms stretched in travel with the band (shipped) vs on the bench's travel "
                           "scale (baseline), one thread",
            "time-terms": "rate and lag terms from weights kept per log, plays in one pass (shipped) vs recomputed "
                          "at every evaluation (baseline), one thread",
            "opening-cap": "a play's start side judged with the capped forward map on the opening (shipped) vs the "
                           "uncapped one (baseline), one thread",
            "trial-reach": f"the forward solve's trial warps within {kernels.TRIAL_REACH:g} deg before a bracket "
                           "(shipped) vs unbounded (baseline), one thread, each in its own process",
            "blow-up": f"a march bound to pass a blow-up of |z| ({kernels.BLOWUP_SPARE:g}x its bound) ended at once "
                       "(shipped) vs marched to the cap on |z| (baseline), one thread, each in its own process",
            "passes": "the plays, lags, rate and start state of each evaluation in row-order compiled passes, "
                      "the input terms at a held band kept (shipped) vs column passes, np.gradient and numpy "
                      "calls, those terms recomputed (baseline), one thread",
            "kept-runs": "the starting grids' core runs kept for every thread, each search's end by its start "
                         f"(shipped) vs each thread's last few runs only (baseline), {a.threads} threads",
            "processes": f"the fits on {a.threads} worker processes (shipped) vs on {a.threads} threads of one "
                         "process (baseline)",
            "schedule": "the fits handed out longest first, the beam's two second rounds side by side (shipped) vs "
                        f"in the order asked for, one round at a time (baseline), {a.threads} workers",
            "reverse-refits": "round 2's refit from the new effect's own fit for the two of best screen and every "
                              "candidate that alone closed a share of the gap (shipped) vs the two of best screen "
                              f"only (baseline), {a.threads} workers",
            "code-before": f"this checkout vs revision {a.against} (baseline), one thread, each in its own process",
            }[a.compare]
    if a.compare == "code-before" and not a.against:
        ap.error("--compare code-before needs --against REV")
    by_verdict = a.compare in ("band-travel", "reverse-refits")  # the two codes differ there: compare what they name
    same_what = "same verdict" if by_verdict else "same report"
    if a.case:
        todo = [(f, int(sd), int(pl), int(k)) for f, sd, pl, k in (c.split("/") for c in a.case)]
        which = "cases " + ", ".join(a.case)
    else:
        todo = [(f, a.seed, a.plant, k) for f in a.families.split(",") if f for k in cases]
        which = f"seed {a.seed}, plant {a.plant} of each family, cases {a.cases}"
    print(f"diagnose, 60 s at 500 Hz: {what}; {which}, "
          f"{a.repeats} repeat(s); load average at start {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores",
          flush=True)
    print(f"{'case':<28}{'truth':<26}{base_name + ' s':>13}{new_name + ' s':>13}{'ratio':>7}  {same_what:<12}"
          f"core runs", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        tree = revision_tree(a.against, work / "before") if a.compare == "code-before" else None
        for n, (family, seed, index, k) in enumerate(todo):
            plant = draw_plants(seed, family, index + 1)[index]
            model = blind.identified_model(plant, seed, index, args, work)
            names, case_seed = blind.draw_cases(seed, family, index, 2, 3)[k]
            fc = blind.field_case(plant, case_seed, tuple(names), args.duration, args.rate)
            lg = blind.run_log(plant, fc.t, fc.u, fc.airspeed, fc.spec, fc.noise, fc.f_seed)
            field_csv = work / f"{plant.name}-c{k}.csv"
            blind.write_log(field_csv, lg)
            for r in range(a.repeats):
                order = (False, True) if (n + k + r) % 2 == 0 else (True, False)
                got = {v: timed_diagnose(field_csv, model, work / f"rep-{v}.json", v, a.compare, a.threads,
                                             a.cache, tree)
                       for v in order}
                (tb, rb), (tr, rr) = got[False], got[True]
                same = rb["verdict"] == rr["verdict"] if by_verdict else _strip(rb) == _strip(rr)
                runs = (rb["model_evaluations"], rr["model_evaluations"])
                rows.append((tb, tr, same, runs))
                print(f"{plant.name + f'-c{k}':<28}{'+'.join(names):<26}{tb:>13.1f}{tr:>13.1f}{tr / tb:>7.2f}  "
                      f"{'yes' if same else 'NO':<12}{runs[0]:>7d} -> {runs[1]}", flush=True)
    ratios = [tr / tb for tb, tr, _, _ in rows]
    run_ratios = [b[1] / b[0] for *_, b in rows if b[0]]
    print(f"\n{len(rows)} runs: time ratio {new_name} / {base_name} median {statistics.median(ratios):.2f} "
          f"(range {min(ratios):.2f}-{max(ratios):.2f}); median: {base_name} "
          f"{statistics.median(r[0] for r in rows):.1f} s, {new_name} {statistics.median(r[1] for r in rows):.1f} s; "
          f"slowest: {base_name} {max(r[0] for r in rows):.1f} s, {new_name} {max(r[1] for r in rows):.1f} s; "
          f"{'verdicts' if by_verdict else 'reports'} identical {sum(r[2] for r in rows)}/{len(rows)}; core runs "
          f"ratio median {statistics.median(run_ratios):.2f} (range {min(run_ratios):.2f}-{max(run_ratios):.2f}); "
          f"load average at the end {os.getloadavg()[0]:.1f}")
    return 0 if by_verdict or all(r[2] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
