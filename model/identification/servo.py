"""Step 4's servo: the servo's position loop smooths what the command does faster than it (a closed loop's
feed-forward jumps at each setpoint step) and crosses a large jump at its rated speed; the model fed the raw
command reverses where the tendon never went. ``lag_scan`` solves the design's best shapes again with the
input through first-order lags, then under speed caps; ``lag_checks`` tries a servo that lowers the
input-side cost less surely by a short refinement, and ``lag_pays`` decides, once the model through it is
final, whether it earns its parameters. The servo itself is ``data.Servo``."""

from __future__ import annotations

import logging
import math
from dataclasses import replace

import numpy as np
from scipy.optimize import minimize

from warpbridge.model.identification.data import LogData, Servo
from warpbridge.model.identification.delay import DELAY_GAIN, DELAY_SCAN_ITER, parabola_vertex
from warpbridge.model.identification.design import InputSide, WarpPath, distinct_best, shape_bounds
from warpbridge.model.identification.path import FIT_TOL_Z, SEARCH_POINTS, SEARCH_REVERSALS, FitPath, Objective, refine
from warpbridge.model.identification.refine import evaluate
from warpbridge.model.signals import effective_samples

log = logging.getLogger(__name__)

LAG_GRID_S = (0.005, 0.01, 0.02, 0.03, 0.05, 0.08)  # servo lags the scan tries (s)
LAG_GAIN = 0.1  # a lag is proposed when it lowers the design's best input-side cost by this share of the no-lag's
# ... and searched at once when by this share: a closed loop's jumps through the servo leave 0.17-0.39 of the
# cost on the SITL's logs; a smaller gain (0.6-0.8 left on bench logs, a sine's with no lag at all 0.69) is
# first checked by a short refinement of the model without it, with and without the lag (``lag_checks``)
LAG_GAIN_SURE = 0.5
LAG_SHARE = 0.05  # no lag longer than this share of the training part
LAG_SHAPES = 32  # the design's best distinct shapes (at no lag) the scan solves at each lag
# speed caps the scan tries, per the fastest the lagged command asks for: a servo crosses a large jump of the
# command at its rated speed (a hobby servo's 0.1 s per 60 deg on a 10 mm horn is about 100 mm/s of tendon)
RATE_FRACTIONS = (0.7, 0.5, 0.35, 0.25, 0.18, 0.12)
CHECK_LAG_SCALES = (1.0, 0.5, 0.7, 1.4)  # the scan's lag scaled by these in ``lag_checks``
# the servo tuned on the forward error (``servo_tune``): lags, speed caps (per the scan's) and dead bands (per the
# command's central range: a hobby servo's 1-8 us of pulse is 0.016-0.13 mm of tendon on a 10 mm horn) tried
TUNE_LAGS_S = (0.005, 0.01, 0.015, 0.02, 0.025, 0.03, 0.04, 0.05, 0.065, 0.08)
TUNE_RATE_FACTORS = (0.7, 0.85, 1.0, 1.2, 1.45)
TUNE_DEADBANDS = (0.0, 0.001, 0.002, 0.004, 0.008, 0.016, 0.032)
TUNE_ITER = 8  # refinement steps of the model through each servo tried
TUNE_PASSES = 2  # passes over the three coordinates (the second only when the first moved one)
# a coordinate moves only when the training RMS falls by this share: no dead band from the noise (a 0.15 mm band
# behind a 20 ms servo lowers a 20 s stepped log's by 1 %, refined 8 steps; an optimiser's own scatter is far less)
TUNE_GAIN = 0.005
# the joint tuning after the coordinate passes (``joint_tune``): a Nelder-Mead simplex over the logarithms of the
# servo's active parameters, at most this many servos (each refined ``TUNE_ITER`` steps), its first steps from the
# coordinates' servo (the dead band's inward: it often ends on its grid's largest), its lags within these (s)
JOINT_EVALS = 40
JOINT_STEPS = {"tau_s": 0.3, "rate_mm_s": 0.3, "deadband_mm": -0.7}
JOINT_LAGS_S = (0.003, 0.1)


def lag_scan(data: LogData, S: np.ndarray, max_lag_s: float) -> tuple[Servo, float]:
    """Step 4's servo: the position loop in front of the model (a first-order lag, capped at a rated speed)
    under which the design's best shapes explain the input best. The servo smooths what the command does
    faster than it (a closed loop's feed-forward jumps at every step of the setpoint) and a large jump it
    crosses at its rated speed: the model fed the raw command reverses where the tendon never went, and every
    loop after it is wrong. The input-side cost of the ``LAG_SHAPES`` best distinct shapes at no lag is solved
    again at each lag of ``LAG_GRID_S`` (up to ``max_lag_s`` and a twentieth of the training part), then at the
    best lag under speed caps of ``RATE_FRACTIONS`` of the fastest the lagged command asks for; a cap that
    lowers the cost by ``LAG_GAIN`` is kept and the lags are scanned again under it. A parabola through the
    best lag and its neighbours places it between grid points (the cap likewise, in its logarithm). Returns
    (servo, cost with it / cost without); no servo unless it lowers the cost by ``LAG_GAIN``; the forward
    error decides later."""
    n_end = data.n_train_end
    grid = [d for d in LAG_GRID_S if d <= max_lag_s and d <= LAG_SHARE * data.train_duration]
    if not grid:
        return Servo(), 1.0
    lo, hi = shape_bounds(data.two_sided)

    def cost_at(servo: Servo, shapes: np.ndarray) -> np.ndarray:
        d = data.with_servo(servo)
        wp = WarpPath.build(d.x_hat, d.w_hat, n_end, d.noise / d.norm.ws, "input")
        return InputSide(wp, d.norm.c).solve(shapes).cost

    c0 = cost_at(Servo(), S)
    keep = distinct_best(S, c0, LAG_SHAPES, lo, hi)
    if keep.size == 0:
        return Servo(), 1.0
    shapes = S[keep]
    none = float(np.min(c0[keep]))

    def lags_at(rate: float) -> dict[float, float]:
        tried = {0.0: none} if math.isinf(rate) else {}
        for lag in grid if math.isinf(rate) else [0.0, *grid]:
            c = cost_at(Servo(lag, rate), shapes)
            tried[lag] = float(np.min(c)) if np.isfinite(c).any() else math.inf
        return tried

    rate, tried = math.inf, lags_at(math.inf)
    lag = min(tried, key=lambda k: tried[k])
    fastest = fastest_rate(data, lag)
    if fastest > 0:
        by_rate = {math.log(f * fastest): float(np.min(cost_at(Servo(lag, f * fastest), shapes)))
                   for f in RATE_FRACTIONS}
        best_log = min(by_rate, key=lambda k: by_rate[k])
        if by_rate[best_log] <= (1.0 - LAG_GAIN) * tried[lag]:
            by_rate[math.log(fastest)] = tried[lag]  # the cap the command never reaches: none
            rate = math.exp(parabola_vertex(by_rate, best_log))
            tried = lags_at(rate)
            lag = min(tried, key=lambda k: tried[k])
    servo = Servo(parabola_vertex(tried, lag), rate)
    ratio = tried[lag] / none if none > 0 else 1.0
    if not servo.active or not ratio <= 1.0 - LAG_GAIN:
        return Servo(), 1.0
    log.info("servo %s: the design's best input-side cost %.3g at no lag, %.3g at the scan's best", servo, none,
             tried[lag])
    return servo, ratio


def fastest_rate(data: LogData, tau_s: float) -> float:
    """The fastest the training part's command asks of the tendon through a lag of ``tau_s`` (mm/s)."""
    t, n_end = data.t[:data.n_train_end], data.n_train_end
    return float(np.max(np.abs(np.diff(Servo(tau_s).apply(t, data.u[:n_end]))) / np.diff(t)))


def refined_through(data: LogData, servo: Servo, start: np.ndarray) -> tuple[float, np.ndarray]:
    """(training RMS of the model run free, the model) through ``servo`` after a short refinement (``TUNE_ITER``
    steps on the search's path) of ``start``: how ``servo_tune`` and ``joint_tune`` judge a servo."""
    lo, hi = data.bounds
    d = data.with_servo(servo)
    obj = Objective(FitPath.build(d.x_hat, d.w_hat, d.n_train_end, SEARCH_POINTS, SEARCH_REVERSALS), d.norm.c)
    th = refine(obj, start, lo, hi, TUNE_ITER, tol=FIT_TOL_Z).theta
    return evaluate(d, th, 0.0).train_rms, th


def servo_tune(data: LogData, theta: np.ndarray, servo: Servo) -> Servo:
    """The scan's servo tuned on the forward error: its dead band, its lag and its speed cap, one at a time, each
    over a grid (``TUNE_DEADBANDS`` of the command's central range, ``LogData.travel_span``; ``TUNE_LAGS_S``;
    ``TUNE_RATE_FACTORS`` of the scan's cap and none, or without one the scan's ``RATE_FRACTIONS`` of the fastest
    the command asks for), every servo judged by the training RMS of the model run free
    after a short refinement (``TUNE_ITER`` steps on the search's path) of ``theta`` through it. The input-side
    cost the scan uses cannot judge a dead band, which moves the tendon by less than the warp's noise is worth
    in travel, nor tell a lag from a cap; nor can the search's stretches, each started from the state its own
    first samples imply: the tendon's whole path through the model can. A coordinate moves to its grid's best
    value, and only when that improves the fit by ``TUNE_GAIN``. Returns the servo that fits best."""
    tried: dict[Servo, tuple[float, np.ndarray]] = {}

    def rms(sv: Servo, start: np.ndarray) -> float:
        if sv not in tried:
            tried[sv] = refined_through(data, sv, start)
        return tried[sv][0]

    best, start = servo, theta
    r_best = rms(best, start)
    if math.isfinite(servo.rate_mm_s):
        rates = [math.inf] + [f * servo.rate_mm_s for f in TUNE_RATE_FACTORS]
    else:  # the scan's cap was not worth its gain there; on the forward error it may be: the scan's caps again
        fastest = fastest_rate(data, servo.tau_s)
        rates = [math.inf] + ([f * fastest for f in RATE_FRACTIONS] if fastest > 0 else [])
    grids = (("deadband_mm", [f * data.travel_span for f in TUNE_DEADBANDS]), ("tau_s", [servo.tau_s, *TUNE_LAGS_S]),
             ("rate_mm_s", rates))  # the band first: the scan could not see it, and a lag or cap stands in for it
    for _ in range(TUNE_PASSES):
        moved = False
        for name, grid in grids:
            # the grid's best, not its first value past the gain: a coordinate moves once, to where it fits best
            sv = min((replace(best, **{name: float(v)}) for v in grid), key=lambda s: rms(s, start))
            r = rms(sv, start)
            if r < (1.0 - TUNE_GAIN) * r_best:
                best, r_best, moved = sv, r, True
            start = tried[best][1]
        if not moved:
            break
    log.info("servo tuned on the forward error: %s (from %s; %d servos tried)", best, servo, len(tried))
    return joint_tune(data, theta, best)


def joint_tune(data: LogData, theta: np.ndarray, servo: Servo) -> Servo:
    """The coordinates' servo tuned in all its active parameters at once: a lag, a cap and a band each fit worse
    alone than none (on a stepped closed-loop log, a servo of 20 ms, 105 mm/s and 31 um settles one coordinate at
    a time on 24 ms, 137 mm/s and 178 um, 1.6x the noise; together they reach it). A Nelder-Mead simplex over
    the logarithms of the parameters ``servo`` has active (``JOINT_EVALS`` servos at most, each judged as in
    ``servo_tune`` from ``theta``), never adding one the coordinates left out (a cap that fits the training
    part's slower rates can miss a faster log by 2x) and the dead band no wider than ``servo_tune``'s grid. The
    simplex's servo when it fits better by ``TUNE_GAIN``, else ``servo``."""
    if servo.tau_s <= 0:
        return servo
    tried: dict[Servo, float] = {}

    def rms(sv: Servo) -> float:
        if sv not in tried:
            tried[sv] = refined_through(data, sv, theta)[0]
        return tried[sv]

    names = [k for k, on in (("tau_s", True), ("rate_mm_s", math.isfinite(servo.rate_mm_s)),
                             ("deadband_mm", servo.deadband_mm > 0)) if on]
    bounds = {"tau_s": tuple(math.log(v) for v in JOINT_LAGS_S), "rate_mm_s": (-10.0, 20.0),
              "deadband_mm": (-20.0, math.log(TUNE_DEADBANDS[-1] * data.travel_span))}
    x0 = np.array([min(math.log(getattr(servo, k)), bounds[k][1] - (0.3 if k == "deadband_mm" else 0.0))
                   for k in names])
    simplex = np.array([x0] + [x0 + JOINT_STEPS[k] * np.eye(len(names))[i] for i, k in enumerate(names)])

    def servo_at(v: np.ndarray) -> Servo:
        return replace(servo, **{k: float(math.exp(x)) for k, x in zip(names, v, strict=True)})

    res = minimize(lambda v: rms(servo_at(v)), x0, method="Nelder-Mead", bounds=[bounds[k] for k in names],
                   options={"maxfev": JOINT_EVALS, "initial_simplex": simplex, "xatol": 0.02, "fatol": 1e-5})
    joint = servo_at(res.x)
    r0, r1 = rms(servo), rms(joint)
    log.info("servo tuned jointly: %s, training RMS %.4g (the coordinates' %s: %.4g; %d servos tried)", joint, r1,
             servo, r0, len(tried))
    return joint if r1 < (1.0 - TUNE_GAIN) * r0 else servo


def lag_checks(data: LogData, theta: np.ndarray, servo: Servo) -> Servo:
    """The servo a short refinement (``DELAY_SCAN_ITER`` steps on the search's path) from the model without one
    fits the training part best through, of the scan's and the scan's with its lag scaled by ``CHECK_LAG_SCALES``
    (the input-side cost places a lag only roughly: 31-37 ms on a log whose servo is 15-20 ms); that servo when it
    fits better by ``DELAY_GAIN`` than none, else none (``Servo()``)."""
    lo, hi = data.bounds

    def cost(x: np.ndarray) -> float:
        obj = Objective(FitPath.build(x, data.w_hat, data.n_train_end, SEARCH_POINTS, SEARCH_REVERSALS), data.norm.c)
        return refine(obj, theta, lo, hi, DELAY_SCAN_ITER, tol=FIT_TOL_Z).cost

    none = cost(data.x_hat)
    tried = list(dict.fromkeys(replace(servo, tau_s=f * servo.tau_s) for f in CHECK_LAG_SCALES))  # a cap alone: once
    costs = [cost(data.with_servo(sv).x_hat) for sv in tried]
    k = int(np.argmin(costs))
    log.info("servo %s, a short refinement: cost %.4g without it, %.4g with %s", servo, none, costs[k], tried[k])
    return tried[k] if costs[k] <= (1.0 - DELAY_GAIN) * none else Servo()


def lag_pays(rms_without: float, rms_with: float, residuals: np.ndarray, parameters: int = 1) -> bool:
    """Does the servo earn its ``parameters``? The training cost must fall by ``DELAY_GAIN`` and by more than
    the Bayesian information criterion asks of them on the residuals' effective sample count
    (n_eff ln(c0 / c1) > k ln n_eff): a short log with few independent samples needs a clear gain."""
    c0, c1 = rms_without ** 2, rms_with ** 2
    if not (c1 > 0 and c1 <= (1.0 - DELAY_GAIN) * c0):
        return c1 == 0.0 < c0
    n_eff = max(effective_samples(residuals), 2.0)
    return bool(n_eff * math.log(c0 / c1) > max(parameters, 1) * math.log(n_eff))
