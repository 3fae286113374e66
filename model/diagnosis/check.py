"""How well an identified model carries to another input: its error on a second bench log.

A model identified on one bench log is scored on the held-out end of that log,
an input of the same kind. On a sheath whose friction holds a long memory of
reversals (a large capstan wrap) the model, and the correction learned from its
bench residual, may fit that input well and another one (a sweep, a multisine)
several times worse. ``input_check`` predicts a second bench log, recorded with
another input and no change of the rig, from its own initial state, with and
without the model-error correction, and returns the error beyond that log's
noise: what ``diagnose`` then takes as the model's known error when it is the
larger (``known_error_on_check``), so an effect is named by what changed, not by
what the model never carried to another input. No I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from warpbridge.model.diagnosis.records import Record
from warpbridge.model.initial_state import estimate_plant_start
from warpbridge.model.model_error import ErrorModel
from warpbridge.model.plant import Plant
from warpbridge.model.signals import noise_floor

SKIP_S = 1.0  # the first second is left out: the initial state is estimated from it
MIN_SAMPLES = 200


def _beyond_noise(rms: float, noise: float) -> float:
    return math.sqrt(max(rms ** 2 - noise ** 2, 0.0)) if math.isfinite(rms) else math.nan


@dataclass(frozen=True)
class CheckScore(Record):
    """A model's error on a check log (``input_check``), deg: the samples scored and the log's noise; the model's
    RMS bare and its error beyond the noise; the same with the model-error correction, when it has one."""

    OPTIONAL = ("rms_corrected_deg", "known_error_corrected_deg")

    samples: int
    noise_deg: float
    rms_bare_deg: float
    known_error_bare_deg: float
    rms_corrected_deg: float | None = None
    known_error_corrected_deg: float | None = None


def input_check(params, effects, error_model: ErrorModel | None, t, u, w, airspeed=None) -> CheckScore:
    """The model's RMS on a check log (after its first ``SKIP_S``), bare and with ``error_model``, the log's
    noise, and each error beyond the noise. Raises ValueError on a log too short to say."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    u = np.ascontiguousarray(u, dtype=np.float64)
    w = np.ascontiguousarray(w, dtype=np.float64)
    ok = np.isfinite(w) & (t >= t[0] + SKIP_S)
    if int(ok.sum()) < MIN_SAMPLES:
        raise ValueError(f"the check log has {int(ok.sum())} samples with warp after its first {SKIP_S:g} s; "
                         f"at least {MIN_SAMPLES} are needed")
    noise = noise_floor(w[np.isfinite(w)])
    rms = {}
    for tag, em in (("bare", None), ("corrected", error_model)):
        if tag == "corrected" and em is None:
            continue
        z0, side = estimate_plant_start(Plant(params, effects, em), t, u, w, airspeed)
        plant = Plant(params, effects, em, side)
        _, w_pred = plant.simulate(t, u, airspeed, z0=z0)
        rms[tag] = float(np.sqrt(np.mean((w[ok] - w_pred[ok]) ** 2)))
    corrected = rms.get("corrected")
    return CheckScore(int(ok.sum()), noise, rms["bare"], _beyond_noise(rms["bare"], noise), corrected,
                      None if corrected is None else _beyond_noise(corrected, noise))


def known_error_on_check(fit_extra: dict, corrected: bool) -> float:
    """The error beyond noise a model file's check log measured (``fit.check``), corrected or bare; NaN when
    the file has no check (or not of that kind)."""
    chk = fit_extra.get("check") if isinstance(fit_extra, dict) else None
    if not isinstance(chk, dict):
        return math.nan
    v = chk.get("known_error_corrected_deg" if corrected else "known_error_bare_deg")
    try:
        v = float(v)
    except (TypeError, ValueError):
        return math.nan
    return v if math.isfinite(v) and v >= 0 else math.nan
