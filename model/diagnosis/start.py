"""The diagnosis's start: the log checked, the fitting problem set up with the model's initial state and
error correction, and the floor (noise and the model's known error) the gap is measured from."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from warpbridge.model.diagnosis.check import known_error_on_check
from warpbridge.model.diagnosis.options import DiagnoseOptions
from warpbridge.model.diagnosis.problem import Fit, Problem
from warpbridge.model.diagnosis.search import Explorer
from warpbridge.model.effect_registry import LOAD_EFFECT, candidates
from warpbridge.model.initial_state import estimate_plant_start
from warpbridge.model.model_error import ErrorModel
from warpbridge.model.modelfile import FitQuality, ModelFile
from warpbridge.model.plant import Plant
from warpbridge.model.signals import noise_floor


def model_error(fit: FitQuality, noise: float) -> float:
    """The model's own error beyond noise that identification measured (0 if it did not say)."""
    held = fit.heldout_rms_deg
    nz = fit.noise_deg if math.isfinite(fit.noise_deg) else noise
    if not math.isfinite(held) or not math.isfinite(nz):
        return 0.0
    return math.sqrt(max(held ** 2 - nz ** 2, 0.0))


def known_error(model: ModelFile, noise: float, use_model_error: bool) -> float:
    """What the nominal model (with its model-error correction, if used) is known to get wrong beyond noise:
    on its bench log, or on the check log of another input ``identify --check`` scored it on, if larger."""
    bench = bench_known_error(model, noise, use_model_error)
    check = known_error_on_check(model.fit.extra, use_model_error and model.model_error is not None)
    return max(bench, check) if math.isfinite(check) else bench


def bench_known_error(model: ModelFile, noise: float, use_model_error: bool) -> float:
    """The known error measured on the bench log alone (the model-error model's, or identify's held-out)."""
    em = model.model_error if use_model_error else None
    if em is not None and math.isfinite(em.known_error_deg):
        return em.known_error_deg
    return model_error(model.fit, noise)


def initial_state(t, u, w, airspeed, model: ModelFile, em: ErrorModel | None) -> tuple[float, float]:
    """(z0, the play's slack side) that explain the log's first samples with the model, its effects and its
    error correction (``initial_state.estimate_plant_start``)."""
    return estimate_plant_start(Plant(model.params, model.effects, em), t, u, w, airspeed)


@dataclass
class Setup:
    """What every decision of a diagnosis starts from: the fitting problem (log, nominal model, its initial
    state and error correction), the floor (noise and the model's known error) and the candidates."""

    prob: Problem
    ex: Explorer
    noise: float
    e_m: float
    skipped: dict[str, str]
    z0: float  # the initial state estimated from the log's opening stretch
    slack_side: float  # where the play's slack is taken up at the start (``initial_state``)
    error_model: ErrorModel | None  # the model-error correction applied (None: not used)


def set_up(t, u, w, airspeed, model: ModelFile, opt: DiagnoseOptions,
           progress: Callable[[str, int, int], None] | None = None) -> Setup:
    """Check a cleaned log and set up its diagnosis against ``model`` (``diagnose``'s first step)."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    u = np.ascontiguousarray(u, dtype=np.float64)
    w = np.ascontiguousarray(w, dtype=np.float64)
    if not (t.size == u.size == w.size) or (airspeed is not None and np.size(airspeed) != t.size):
        raise ValueError("t, u, warp (and airspeed) must have the same length")
    if t.size < 100:
        raise ValueError(f"log too short to diagnose: {t.size} samples (need at least 100)")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(u)) and np.all(np.isfinite(w))):
        raise ValueError("t, u and warp must be finite")
    if np.ptp(u) <= 0:
        raise ValueError("the tendon input never changes: nothing to diagnose")
    if progress:
        progress("initial state", 0, 1)
    em = model.model_error if opt.use_model_error else None
    z0, side = initial_state(t, u, w, airspeed, model, em)
    prob = Problem(t, u, w, airspeed, model.params, model.effects, z0, error_model=em, slack_side=side)
    sp = prob.split
    if sp.score.sum() < 20 or sp.train.sum() < 20:
        raise ValueError("log too short after the warm-up to split into training and scoring blocks")
    base = model.effects
    w_nom = prob.predict(base)
    noise = noise_floor(w)
    e_m = known_error(model, noise, opt.use_model_error)
    tried = opt.effects if opt.effects is not None else candidates()
    names = [n for n in tried if n != LOAD_EFFECT or prob.has_airspeed]
    why = "the log has no airspeed" if airspeed is None else "the airspeed is zero throughout the log"
    skipped = {n: why for n in tried if n not in names}
    nominal = Fit((), base, w_nom, prob.mse(w_nom, sp.train), prob.mse(w_nom, sp.score), 0)
    ex = Explorer(prob, names, base, nominal, noise ** 2 + e_m ** 2, opt, progress)
    return Setup(prob, ex, noise, e_m, skipped, z0, side, em)
