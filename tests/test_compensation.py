"""An augmented model's invertible effects cancel through the feed-forward compensator."""

import numpy as np
import pytest

from warpbridge.model.boucwen import BoucWenParams
from warpbridge.model.compensation import Compensator
from warpbridge.model.effects import Effects
from warpbridge.model.excitation import filtered_random
from warpbridge.model.plant import Plant, PlantStepper

P = BoucWenParams.paper()


@pytest.mark.parametrize("effects", [
    Effects(),
    Effects(pretension_offset_mm=0.4, pretension_gain=0.9),
    Effects(friction_scale=1.4),
    Effects(aero_gain_per_kpa=1.5, aero_deg_per_kpa=2.0),
    Effects(backlash_mm=0.3),
    Effects(pretension_offset_mm=-0.3, pretension_gain=1.1, friction_scale=0.8, backlash_mm=0.2,
            aero_gain_per_kpa=1.0),
])
def test_feed_forward_through_the_augmented_model_tracks_the_setpoint(effects):
    t = np.arange(0, 12, 0.01)
    w_sp = filtered_random(t, 1.0, 3.0, offset=7.0, seed=2)
    v = 10 + 3 * np.sin(0.5 * t)
    plant = Plant(P, effects)
    comp = Compensator(plant, w0=w_sp[0])
    u0 = comp.step(w_sp[0], v[0])
    wing = PlantStepper(plant, t[0], u0)
    err = []
    for k in range(1, t.size):
        u = comp.step(w_sp[k], v[k])
        w_true, _ = wing.step(t[k], u, v[k])
        err.append(w_true - w_sp[k])
    rms = float(np.sqrt(np.mean(np.square(err[200:]))))
    assert rms < 0.02
    # and without the compensation the same wing misses by far more, unless there is no effect
    naive = Compensator(Plant(P), w0=w_sp[0])
    wing2 = PlantStepper(plant, t[0], naive.step(w_sp[0], v[0]))
    err2 = [wing2.step(t[k], naive.step(w_sp[k], v[k]), v[k])[0] - w_sp[k] for k in range(1, t.size)]
    rms2 = float(np.sqrt(np.mean(np.square(err2[200:]))))
    if effects.active():
        assert rms2 > 5 * max(rms, 0.01)
