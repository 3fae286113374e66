"""An effect added at run time: one registry entry with its operator, and the diagnosis finds it with nothing
else changed (docs/effects.md)."""

from __future__ import annotations

import numpy as np
import pytest

from warpbridge.model.boucwen import BoucWenParams, inverse
from warpbridge.model.diagnosis import diagnose
from warpbridge.model.effect_registry import Box, EffectSpec, Param, candidates, registered
from warpbridge.model.effects import Effects
from warpbridge.model.excitation import filtered_random
from warpbridge.model.modelfile import FitQuality, ModelFile
from warpbridge.model.plant import Plant, PlantStepper

FS, NOISE = 200.0, 0.03
P = BoucWenParams.paper()


def stepped(eff: Effects, t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """A servo that holds positions a fixed step apart (a coarse potentiometer or gear): travel in steps."""
    q = eff.servo_step_mm
    return x if q <= 0.0 else q * np.round(x / q)


def saturated(eff: Effects, t: np.ndarray, w: np.ndarray) -> np.ndarray:
    """A warp sensor that saturates softly: w -> S tanh(w / S), S its range in degrees (inf: linear)."""
    s = eff.sensor_range_deg
    return w if not np.isfinite(s) else s * np.tanh(w / s)


SERVO_STEPS = EffectSpec(
    "servo_steps", "the servo holds positions a fixed step apart", (Param("servo_step_mm", "mm", 0.0, in_core=True),),
    operator="", apply=stepped, side="input",
    forms=lambda s: [[Box("servo_step_mm", 1e-3 * s.span, 0.2 * s.span, log=True)]])
SENSOR_RANGE = EffectSpec(
    "sensor_range", "the warp sensor saturates softly at the ends of its range",
    (Param("sensor_range_deg", "deg", np.inf),), operator="", apply=saturated, side="warp",
    forms=lambda s: [[Box("sensor_range_deg", 2.0, 2000.0, log=True, neutral_at_hi=True)]])


def log_with(effects: Effects, seed: int):
    t = np.arange(int(20.0 * FS)) / FS
    u, _ = inverse(P, filtered_random(t, 1.0, 4.5, 7.0, seed=seed))
    v = filtered_random(t, 0.1, 6.0, 14.0, seed=seed + 100)
    _, w = Plant(P, effects).simulate(t, u, v)
    return t, u, w + NOISE * np.random.default_rng(seed + 1).standard_normal(t.size), v


def nominal() -> ModelFile:
    return ModelFile(params=P, fit=FitQuality(train_rms_deg=NOISE, heldout_rms_deg=NOISE, noise_deg=NOISE))


def test_an_added_effect_is_carried_written_and_read_like_a_built_in_one():
    with registered(SERVO_STEPS):
        eff = Effects(delay_s=0.01).with_values(servo_step_mm=0.3)
        assert eff.servo_step_mm == 0.3 and Effects().servo_step_mm == 0.0
        assert eff.active() == ["delay", "servo_steps"]
        assert Effects.from_dict(eff.to_dict()) == eff
        assert eff.with_values(servo_step_mm=0.0) == Effects(delay_s=0.01)  # neutral again: the same effects
        assert "servo_steps" in candidates()
        with pytest.raises(ValueError, match="built-in effects only"):
            PlantStepper(Plant(P, eff), 0.0, 5.0)
    assert "servo_steps" not in candidates()
    with pytest.raises(AttributeError):
        _ = Effects().servo_step_mm
    with pytest.raises(TypeError, match="servo_step_mm"):
        Effects().with_values(servo_step_mm=0.3)


def test_a_registry_entry_needs_an_operator_and_new_parameters():
    with pytest.raises(ValueError, match="apply"):
        with registered(EffectSpec("x", "x", (Param("x_mm", "mm", 0.0),), operator="")):
            pass
    clash = EffectSpec("x", "x", (Param("delay_s", "s", 0.0),), operator="", apply=stepped, side="input")
    with pytest.raises(ValueError, match="delay_s"):
        with registered(clash):
            pass


@pytest.mark.slow
def test_the_diagnosis_finds_an_added_effect_and_sizes_it():
    with registered(SENSOR_RANGE):
        t, u, w, v = log_with(Effects().with_values(sensor_range_deg=25.0), seed=5)
        d = diagnose(t, u, w, v, nominal())
        assert d.verdict == ["sensor_range"]
        assert d.report["effects"]["sensor_range"]["sensor_range_deg"] == pytest.approx(25.0, rel=0.2)
        assert d.report["shrinkage"]["gap_closed"] > 0.8
        # and not where the log has none: the added candidate does not claim the noise
        t, u, w, v = log_with(Effects(), seed=6)
        assert diagnose(t, u, w, v, nominal()).verdict == []
