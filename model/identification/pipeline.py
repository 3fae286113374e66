"""Identification of the generalized Bouc-Wen model from a log, in named steps.

The method. In the paper's form the tendon travel is linear in the backbone and
state coefficients (a1, a2, a3, az) once the hysteretic state's trajectory is
fixed by the warp and the shape parameters (A, n, b). So, in steps that are
this package's modules (named in brackets where a step's name is not its module's):

1. ``read`` (``data``): the log's arrays checked (``check_log``), normalised (w / Ws,
   (u - uc) / Us: the search box is the same for any wing) and split; the last
   ``heldout_frac`` of the log (by time) is held out and only scored.
2. ``excite check`` (``excitation``): how many reversals the training part holds, at which levels
   of the warp range, over how wide a band (``excitation_check``); what a log
   does not excite is said, and the parameters it leaves open are flagged by
   the uncertainty step.
3. ``start design`` (``design``): a deterministic, well-spread set of trial shapes (a
   scrambled Sobol' sequence with a fixed seed; ``seed`` selects another
   scramble, 0 the default), the paper's shape and the prior's.
4. ``linear solve`` (``design``): for each trial shape the state is integrated once over the
   measured warp and (a1, a2, a3, az) are solved exactly by least squares on the
   input-side error (separable least squares, variable projection); the straight
   line and the quadratic without hysteresis are inside every solve (az = 0). The
   warp's jitter is removed first (every noise reversal would be a real reversal
   of the model): the log is cut into runs at the input's real turns (a turn of
   the input inside the model's dead zone moves the warp by less than its noise)
   and, for half of the starts, at the warp's own (a closed loop's command
   reacts to the sensor's noise, so its turns are not the warp's), and in each
   run the warp is replaced by its least-squares monotone fit.
   ``servo``: the servo's position loop smooths what the command does faster than it (a closed
   loop's feed-forward jumps at each setpoint step) and crosses a large jump at its rated speed; the
   model fed the raw command reverses where the tendon never went. The design's best shapes are solved
   again with the input through first-order lags, then under speed caps (``servo.lag_scan``; each row's
   command held until the next, ``effects.servo_follow``); the best servo, when it lowers their
   input-side cost by ``LAG_GAIN_SURE`` (or by ``LAG_GAIN`` and a short refinement of the final model
   without it fits better through it), is put in front of the model once the model without it is final
   (steps 5-8; with a servo the scan is sure of, that model is only a start and a yardstick, and its
   escalation waits for the model through the servo, running only when that is refused or misses the
   training part by more than ``WAIT_MISS`` of what the model without it misses; when the scan proposed
   none, a lag of ``LAG_PROBE_S`` is
   checked the same way, and goes on when that check or the model's miss of the training part asks for
   it): the design is solved again through
   it and refined, with the model found without it as one more start, checked for a fold and against the
   simpler models, through the servo with a dead band of ``LAG_PASS_BAND`` and without (the band kept when it
   fits better by ``TUNE_GAIN``: a closed loop's jitter reverses a model fed through no band); its dead band,
   lag and cap are then
   tuned on the forward error, one at a time and then together (``servo.servo_tune``, ``servo.joint_tune``:
   the input-side cost cannot see a dead band, and a cap or a band alone can fit worse than none) and the
   model refined again through the tuned servo when that fits better, for up to ``TUNE_ROUNDS`` rounds (a servo
   tuned from a model far from the data is off itself); the servo is kept only when
   the result fits the training part better by ``DELAY_GAIN`` and by what the information criterion asks
   of its parameters on the log's effective samples (``servo.lag_pays``; ``servo_tau_s``, ``servo_rate_mm_s``;
   not with a delay scan, whose delay stands for it).
5. ``local refine`` (``refine``): the distinct best shapes, with the straight line and the
   quadratic backbone, are scored on the forward output error (warp simulated
   from the logged tendon input, every stretch started from the state its own
   first samples imply) and the best few refined by Levenberg-Marquardt on the
   per-sample forward residuals (``path``), the best of them again on
   a larger part of the training data; the best start without hysteresis is
   always among those refined. A log with more reversals than a fit needs is
   scored on evenly spread stretches; a noisy input's reversals are counted
   above its noise for that (a closed-loop log's jitter would otherwise cut the
   stretches to a few samples each), while every reversal inside a stretch,
   jitter's included, is simulated as the model sees it. A result at the exponent's upper limit
   (n trades against the saturation levels along a flat ridge) is refined again
   from the next start, the better on training kept. When no two refined starts
   agree, or the result fits far above the noise floor (a wide two-sided loop
   whose basin the design can miss), the search escalates: a differential
   evolution with a fixed seed derived from the design's, seeded with the refined
   results and the design's best starts (``global_search``; ``escalate``), its best
   members refined the same way; the result that runs free over the training part
   best is kept (never chosen by held-out data).
6. ``delay``: with ``max_delay_s``, a scan of transport delays in front of the
   model (a short refinement each, from the best model so far) and a final
   refinement at the best; kept only when it lowers the training cost by
   ``DELAY_GAIN`` against the model without it (``delay_s``).
7. ``fold check`` (``checks``): a backbone u = a1 w^2 + a2 w + a3 that turns back inside the
   working range (``working_range``) is refined again from starts that do not
   fold, with folding backbones rejected; kept unless it fits the training part
   more than ``FOLD_KEEP`` worse (then the data show the fold). After an
   escalation the starts include a global search's over the backbones without a
   fold (``global_members``): on a poorly excited log the folding basins hold the
   escalation's search, and the design's starts alone can miss the best fit.
8. ``simpler models`` (``checks``): a fit whose training RMS is above the best straight
   line's (fitted on the same samples) is a failed search: the refinement
   starts again from the line and from the quadratic backbone, and a result
   worse than the line is never returned. A fit that cannot beat a line on the
   held-out part says so (``support_check``).
9. ``model-error model``: what the model still gets wrong on the log, learned for
   the diagnosis (``model.model_error``; the CLI step).
10. ``uncertainty``: a 95 % interval for every parameter from the Gauss-Newton
    curvature at the optimum with the residual variance scaled by the residuals'
    effective sample count (``uncertainty.intervals``); the parameters the data
    do not determine are named.

The default answer is reproducible: the design's scramble is fixed and the
refinements are deterministic. Another ``seed`` scrambles the design (and the
global searches) differently: on a log that excites the loop well the seeds end
at fits within a few percent of each other, on a poorly excited one they can end
in basins of different depth (the excitation step says when). Everything here is
pure numerics; progress is reported through a callback (stages "design",
"refine", "refine again", "global", "refine without a fold", "delay", "line").
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from warpbridge.model.boucwen import BoucWenParams
from warpbridge.model.effects import delayed
from warpbridge.model.identification.checks import fold_check, fold_range, folds, simpler_models, support_check
from warpbridge.model.identification.data import LogData, Servo, read
from warpbridge.model.identification.delay import DELAY_GAIN, delay_scan
from warpbridge.model.identification.design import Starts, linear_solve, start_design
from warpbridge.model.identification.excitation import excitation_check
from warpbridge.model.identification.global_search import GlobalResult, global_search
from warpbridge.model.identification.path import Objective, refine
from warpbridge.model.identification.refine import Candidate, Refiner, SearchTrace, at_exponent_edge, evaluate
from warpbridge.model.identification.result import IdentResult
from warpbridge.model.identification.servo import (
    LAG_GAIN_SURE,
    LAG_GRID_S,
    LAG_SHARE,
    TUNE_GAIN,
    lag_checks,
    lag_pays,
    lag_scan,
    servo_tune,
)
from warpbridge.model.identification.uncertainty import uncertainty
from warpbridge.model.signals import central_range, linear_baseline

log = logging.getLogger(__name__)

EDGE_FRAC = 0.01  # a result this close (share of the range) to the exponent's upper limit is at it
EDGE_AGREE = 0.01  # refined starts whose costs agree within this (std / mean) put n at the limit themselves
RANKED_PER_POPSIZE = 6  # distinct design starts ranked on the forward error, per unit of ``popsize``
REFINED_STARTS = 2  # starts refined on the search's path (the best by forward cost) ...
SEARCH_ITER = 40  # ... for at most this many steps each; the best again on the polish's path
# the search escalates (``escalate``) when no two refined starts agree ...
ESCALATE_NOISES = 5.0  # ... or when the first result's training RMS is above this many noise deviations
GLOBAL_SEEDED = 10  # the design's best starts placed in its first population, beside the refined results
POPSIZE_GLOBAL = 110  # its population (ten per parameter of a two-sided wing)
MAXITER_GLOBAL = 150  # generations of the escalation's global search at most (``global_search``)
# a servo is tried when the scan proposed none (or its short check refused it) but a short refinement through a
# lag of ``LAG_PROBE_S`` fits better (``servo.lag_checks``), or the model without one misses the training part by
# more than ``LAG_PROBE_NOISES`` noise deviations: through the true servo the design's best input-side cost can
# exceed the raw command's (a stepped log through a 20 ms, 100 mm/s servo: 0.012 against 0.004; the scan of an
# open-loop bench log through a 20 ms servo proposes none on 3 of 10 seeds), and a short refinement from the model
# without a servo, settled in its own basin, can miss it too
LAG_PROBE_NOISES = 2.0
LAG_PROBE_S = 0.02  # the servo tried then: a hobby servo's position loop (tuned on the forward error from there)
# the servo is tuned again from the model refined through the tuned one (a servo tuned from a model far from the
# data, through a servo the scan placed far off, is off itself) at most this many rounds, while a round lowers the
# training RMS by ``TUNE_ROUND_GAIN`` and the fit stays above ``TUNE_ROUND_NOISES`` noise deviations (a fit within
# 1.1x the noise through a servo tuned from a model 3x off can still miss the held-out part 4x: a 23 ms servo
# without a cap, where the truth is 20 ms capped at 100 mm/s; the next round reaches it)
TUNE_ROUNDS = 3
TUNE_ROUND_GAIN = 0.05
TUNE_ROUND_NOISES = 1.0
# with a servo the scan is sure of, the model without it escalates only once the servo is refused, or when the
# model through it misses the training part by more than this share of that model's miss (not decisively better)
WAIT_MISS = 0.5
# the dead band the lag pass also searches through, per the command's central range (``LogData.travel_span``;
# ``servo.TUNE_DEADBANDS``' middle: 44 um on the SITL's 5.5 mm; the tuning moves it after)
LAG_PASS_BAND = 0.008
# the search trace's record of the fold and simpler-model steps: the lag's pass writes its own, kept with it
LAG_PASS_FIELDS = ("fold_deg", "working_range_deg", "fold_outcome", "fold_train_rms", "line_restart", "kept_start")


def identify(t, u, w, *, heldout_frac: float = 0.25, seed: int = 0, popsize: int = 10, maxiter: int = 150,
             polish_evals: int = 2500, max_fit_points: int = 2500,
             prior: BoucWenParams | None = None, max_delay_s: float = 0.0, max_lag_s: float = LAG_GRID_S[-1],
             sent=None, progress: Callable[[str, int, int], None] | None = None) -> IdentResult:
    """Identify the Bouc-Wen model (warp -> tendon) from a log by forward output error (see the module).

    ``t`` s, ``u`` mm, ``w`` deg, cleaned (finite, t strictly increasing). The last ``heldout_frac`` of the log
    (by time) is held out. ``seed`` selects the scramble of the start design (0: the fixed default; see the
    module for what another seed changes); ``popsize`` distinct design starts are ranked on
    the forward error; each refinement takes at most ``maxiter`` Gauss-Newton steps and ``polish_evals``
    evaluations; ``prior`` (default: the paper's parameters) adds its shape to the design. ``max_lag_s`` bounds
    the servo lag the scan tries in front of the model (0: none), ``max_delay_s`` the transport delay (with a
    delay scan no lag is scanned: the delay stands for the servo, link and sensor lag together). ``sent``: when
    each row's command reached the servo, s after the row's time (a cycle log records it; the servo in front of
    the model then holds the row before's command until then). ``progress(stage, i, n)`` is called once per
    refinement step."""
    data = read(t, u, w, heldout_frac, sent)
    n_end = data.n_train_end
    exc = excitation_check(data.u[:n_end], data.w[:n_end], data.noise)
    trace = SearchTrace()
    lo, hi = data.bounds
    max_iter = max(1, min(maxiter, SEARCH_ITER, polish_evals // (lo.size + 1)))
    if progress:
        progress("design", 0, 1)
    S, labels = start_design(data, seed, prior)
    keep_starts = max(1, RANKED_PER_POPSIZE * popsize)
    # with a delay scan asked for, the delay stands for the servo, link and sensor lag together
    lag, lag_ratio = lag_scan(data, S, max_lag_s) if max_lag_s > 0 and max_delay_s <= 0 else (Servo(), 1.0)
    starts = linear_solve(data, S, labels, keep_starts)
    trace.design_size = int(S.shape[0])
    if progress:
        progress("design", 1, 1)
    calls = [starts.evaluations]
    refiners: list[Refiner] = []

    def search(thetas: np.ndarray, names: list[str], fold, stage: str, n_refine: int = REFINED_STARTS,
               ) -> tuple[np.ndarray, float]:
        """Steps 5-6 from these starts: (theta, delay)."""
        ref = Refiner(data, data.x_hat, max_fit_points, fold, trace, max_iter, progress, stage)
        refiners.append(ref)
        theta, cost, label = ref.run(thetas, names, n_refine)
        trace.kept_start = label
        calls[0] += ref.calls
        delay = 0.0
        if max_delay_s > 0:
            delay, x_start, scan_calls = delay_scan(data, theta, max_delay_s, fold, progress)
            calls[0] += scan_calls
            if delay > 0:
                ref_d = Refiner(data, delayed(data.t, data.x_hat, delay), max_fit_points, fold, trace, max_iter,
                                progress, stage)
                r = refine(ref_d.polish_obj, x_start, lo, hi, max_iter, ref_d._polish_cb)
                calls[0] += ref_d.calls
                if r.cost > (1.0 - DELAY_GAIN) * cost:
                    log.info("transport delay %.1f ms not kept: refined, it fits no better than none", 1e3 * delay)
                    delay = 0.0
                else:
                    theta = r.theta
        return theta, delay

    best = evaluate(data, *search(starts.thetas, starts.labels, None, "refine"))
    first = refiners[-1]
    if at_exponent_edge(best.theta, lo, hi, EDGE_FRAC) and trace.spread[-1] > EDGE_AGREE:
        # the exponent n trades against the saturation levels along a long, flat ridge, and a refinement can
        # walk up it to the box's upper limit; unless the refined starts all agree there (then the data put it
        # there), the next starts are refined, the better on training kept
        log.info("the refinement settled at the exponent's upper limit (n = %.3g): refining the next starts",
                 best.params.n)
        trace.restarts += 1
        costs = Refiner(data, data.x_hat, max_fit_points, None, trace, max_iter, None, "").rank(starts.thetas)
        order = [int(i) for i in np.argsort(costs)][REFINED_STARTS:] or list(range(len(starts.labels)))
        again = evaluate(data, *search(starts.thetas[order], [starts.labels[i] for i in order], None,
                                       "refine again"))
        if again.train_rms < best.train_rms:
            trace.restart_kept = True
            best = again
    escalates = not first.agreed or best.train_rms > ESCALATE_NOISES * data.noise
    # a servo the scan is sure of goes in front of the final model, and the model without it is then only a
    # start of the search through it and the yardstick it must beat: its escalation waits until the servo is
    # refused or fits not decisively better (``WAIT_MISS``; on the SITL's cycle logs the wait halves the time)
    waits = escalates and lag.active and lag_ratio <= 1.0 - LAG_GAIN_SURE

    def settle(cand: Candidate, escalated: bool) -> Candidate:
        """Step 5's escalation when ``escalated``, then steps 7-8, on the log without a servo."""
        if escalated:
            cand = escalate(data, cand, first, starts, seed, trace, search, progress)
        unfolded = None
        if trace.global_search and folds(data, cand.theta):
            # the refinement without the fold (step 7) searches globally too: on a poorly excited log the
            # folding basins hold the escalation's search, and the design's unfolded starts alone can miss the
            # best fit without a fold (a bend log with three reversals: 0.61 deg from them, 0.43 with it)
            unfolded = global_members(data, first, starts, seed, fold_range(data), progress).thetas
        cand = fold_check(data, cand, starts, trace, search, unfolded)
        return simpler_models(data, cand, starts, trace, search, progress)

    raw = best
    best = settle(best, escalates and not waits)

    def fresh_record() -> None:
        """The fold check's and simpler models' record started afresh (a later pass writes its own)."""
        for k in LAG_PASS_FIELDS:
            setattr(trace, k, getattr(SearchTrace(), k))
    if lag.active and lag_ratio > 1.0 - LAG_GAIN_SURE:
        checked = lag_checks(data, best.theta, lag)
        if not checked.active:
            trace.lag_s, trace.lag_rate_mm_s = lag.tau_s, lag.rate_mm_s  # proposed, refused by the short refinement
        lag = checked
    probe_fits = max_delay_s <= 0 and LAG_PROBE_S <= min(max_lag_s, LAG_SHARE * data.train_duration)
    if not lag.active and probe_fits:
        # the input-side cost can miss a servo (``LAG_PROBE_S``): a short refinement through a hobby servo's lag
        # decides, or the model without one missing the training part by ``LAG_PROBE_NOISES`` noise deviations
        probe = lag_checks(data, best.theta, Servo(LAG_PROBE_S))
        if probe.active or best.train_rms > LAG_PROBE_NOISES * data.noise:
            log.info("no servo from the scan; trying %s (the model without one: training RMS %.3g deg, noise %.3g)",
                     probe if probe.active else Servo(LAG_PROBE_S), best.train_rms, data.noise)
            lag = probe if probe.active else Servo(LAG_PROBE_S)
    if lag.active:  # the scan's servo: the design solved through it and refined, the model without it a start
        plain = data
        kept_trace = {k: getattr(trace, k) for k in LAG_PASS_FIELDS}  # what the model without the lag did

        def through(servo: Servo) -> tuple[Candidate, LogData, dict]:
            """The design solved through ``servo`` and refined (``search`` runs on ``data``, set to the log through
            it), the model without it a start."""
            nonlocal data
            data = plain.with_servo(servo)
            fresh_record()  # the pass's own record (a fold of the model without the servo is not its)
            lag_starts = linear_solve(data, S, labels, keep_starts)
            th, d = search(np.vstack([best.theta, lag_starts.thetas]), ["no lag", *lag_starts.labels], None, "lag")
            cand = fold_check(data, evaluate(data, th, d), lag_starts, trace, search)
            cand = simpler_models(data, cand, lag_starts, trace, search, progress)
            return cand, data, {k: getattr(trace, k) for k in LAG_PASS_FIELDS}

        # the scan cannot see a dead band, and a closed loop's command jitters: through a servo without one every
        # jitter is a reversal of the model, and the search can settle far from the noise (0.98 deg on a stepped
        # log whose servo, with its 31 um band, fits at 0.033); the model is searched through the scan's servo
        # with and without a band (``LAG_PASS_BAND`` of the command's central range), the band kept when it fits
        # better by what the tuning asks of a coordinate (``TUNE_GAIN``)
        passes = [through(lag)]
        if lag.deadband_mm <= 0:
            banded = replace(lag, deadband_mm=LAG_PASS_BAND * plain.travel_span)
            passes.append(through(banded))
            if passes[1][0].train_rms < (1.0 - TUNE_GAIN) * passes[0][0].train_rms:  # as the tuning moves a band
                log.info("servo %s: the model fits better through it with a dead band, %s (%.4g deg against %.4g)",
                         lag, banded, passes[1][0].train_rms, passes[0][0].train_rms)
                lag = banded
            else:
                passes.pop()
        with_lag, data, fields = passes[-1]
        for k, v in fields.items():
            setattr(trace, k, v)
        for _ in range(TUNE_ROUNDS):
            tuned = servo_tune(data, with_lag.theta, lag)
            if tuned == lag:
                break
            # the model refined again through the servo tuned on the forward error, from the model through the
            # servo before and from the design solved through the tuned one: a servo the scan placed far off (a
            # cap without a lag) leaves a model no short refinement brings back
            scanned, data = data, plain.with_servo(tuned)
            tuned_starts = linear_solve(data, S, labels, keep_starts)
            th, d = search(np.vstack([with_lag.theta, tuned_starts.thetas]), ["servo tuned", *tuned_starts.labels],
                           None, "lag")
            again = fold_check(data, evaluate(data, th, d), tuned_starts, trace, search)
            gain = again.train_rms < (1.0 - TUNE_ROUND_GAIN) * with_lag.train_rms
            if again.train_rms < with_lag.train_rms:
                lag, with_lag = tuned, again
            else:
                data = scanned
            if not gain or with_lag.train_rms <= TUNE_ROUND_NOISES * data.noise:
                break
        trace.lag_s, trace.lag_rate_mm_s = lag.tau_s, lag.rate_mm_s

        def pays() -> bool:
            return lag_pays(best.train_rms, with_lag.train_rms, (best.w_pred - plain.w)[plain.train_mask],
                            lag.parameters)
        if waits and (with_lag.train_rms > WAIT_MISS * best.train_rms or not pays()):
            # the servo is refused, or did not cut the miss of the model without it decisively: that model is
            # escalated now, from where it stood before its fold check (as without the wait), the yardstick the
            # servo is judged against
            through_data, pass_record = data, {k: getattr(trace, k) for k in LAG_PASS_FIELDS}
            data = plain
            fresh_record()
            best = settle(raw, True)
            kept_trace = {k: getattr(trace, k) for k in LAG_PASS_FIELDS}
            data = through_data
            for k, v in pass_record.items():
                setattr(trace, k, v)
        trace.lag_train_rms = (best.train_rms, with_lag.train_rms)
        if pays():
            best = with_lag
        else:
            log.info("servo %s not kept: the model fits the training part no better with it (%.4g deg "
                     "against %.4g without)", lag, with_lag.train_rms, best.train_rms)
            data = plain
            for k, v in kept_trace.items():
                setattr(trace, k, v)
    err = best.w_pred - data.w
    held_rms = float(np.sqrt(np.mean(err[data.held_mask] ** 2))) if data.held_mask.any() else float("nan")
    unc = uncertainty(data, best, exc)
    return IdentResult(
        params=best.params, train_rms=best.train_rms, heldout_rms=held_rms, noise=data.noise,
        linear_heldout_rms=linear_baseline(data.u, data.w, data.train_mask, data.held_mask),
        n_train=int(data.train_mask.sum()), n_heldout=int(data.held_mask.sum()), two_sided=data.two_sided,
        evaluations=calls[0], split_time=data.split_time, w_pred=best.w_pred, train_mask=data.train_mask,
        heldout_mask=data.held_mask, z0=best.z0, trace=trace,
        support=support_check(data.t, data.u, data.w, best.w_pred, data.train_mask, data.held_mask, data.noise),
        delay_s=best.delay, travel_mm=central_range(data.u), uncertainty=unc, excitation=exc,
        linear_train_rms=trace.line_train_rms, seed=seed, servo_tau_s=data.servo.tau_s,
        servo_rate_mm_s=data.servo.rate_mm_s, servo_deadband_mm=data.servo.deadband_mm)


def global_members(data: LogData, first: Refiner, starts: Starts, seed: int, fold: tuple[float, float] | None,
                   progress) -> GlobalResult:
    """A global search (``global_search``, seed derived from the design's) over
    the refinement's objective, backbones folding inside ``fold`` (normalised warp) rejected when it is given;
    its first population holds the first refinement's results and the design's best starts."""
    lo, hi = data.bounds
    refined = sorted(first.refined, key=lambda x: x[0])
    seeded = np.vstack([np.array([x[1] for x in refined]).reshape(-1, lo.size), starts.thetas[:GLOBAL_SEEDED]])

    def cb(i: int) -> None:
        if progress:
            progress("global", min(i, MAXITER_GLOBAL), MAXITER_GLOBAL)

    obj = first.search if fold is None else Objective(first.search.path, first.search.c, first.search.tol, fold=fold)
    return global_search(obj, lo, hi, seeded, seed, popsize=POPSIZE_GLOBAL, maxiter=MAXITER_GLOBAL, callback=cb)


def escalate(data: LogData, best: Candidate, first: Refiner, starts: Starts, seed: int, trace: SearchTrace,
             search, progress) -> Candidate:
    """Step 5's escalation: no two refined design starts agreed, or the result fits far above the noise
    floor, so the design may have missed the best basin. A global search (``global_members``) whose best
    members are refined like the design's; the result that runs free over the training part better is kept."""
    log.info("no two refined starts agree, or the fit is far above the noise floor (training RMS %.3g deg, noise "
             "%.3g): a global search (differential evolution) from the refined starts", best.train_rms, data.noise)
    trace.global_search = True
    g = global_members(data, first, starts, seed, None, progress)
    trace.global_generations = g.generations
    th, d = search(g.thetas, ["global"] * len(g.thetas), None, "global")
    cand = evaluate(data, th, d)
    log.info("global search: training RMS %.4g deg against %.4g deg from the design", cand.train_rms, best.train_rms)
    trace.global_train_rms = (best.train_rms, cand.train_rms)
    if cand.train_rms < best.train_rms:
        trace.global_kept = True
        trace.kept_start = "global"
        return cand
    return best
