"""The paper's comparison like for like: a controller identified on a bench log, flying a re-rigged wing.

The simulated wing is the physics-based tendon-sheath plant (``sitl.sheath``), not the Bouc-Wen
model's own class. On the bench (``BENCH``, the SITL's default sheath rig) it is driven with a
low-passed random tendon command and logged through the flex sensor's noise and ADC
(``sitl.wing.bench_log``); ``warpbridge identify`` fits the bridge's model to that log, as a user
does (docs/identify.md). The wing then flown is the same sheath re-rigged
(``rigged``): pre-tension and friction changed, as after folding and unfolding the wing, so the
identified model is off twice over: in its form and in its parameters.
"""

from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path

import numpy as np

from warpbridge.sitl.wing import SheathWing, WingSpec, bench_log

log = logging.getLogger(__name__)

PRETENSION_CHANGE = 1.4  # the re-rigged tendon's pre-tension over the bench's
FRICTION_CHANGE = 1.15  # the re-routed sheath's friction coefficient over the bench's


def bench_params():
    """The bench sheath: the SITL's default rig (``sitl.sheath.rigged_sheath``)."""
    from warpbridge.sitl.sheath import rigged_sheath

    return rigged_sheath()


def rigged(params):
    """The same sheath after re-rigging: pre-tension x1.4, friction x1.15."""
    return params.with_changes(pretension_n=params.pretension_n * PRETENSION_CHANGE,
                               mu=params.mu * FRICTION_CHANGE)


def sheath_spec(params) -> WingSpec:
    return WingSpec(plant=SheathWing(params))


def write_bench_log(params, path: Path, *, max_warp_deg: float = 12.0, seconds: float = 90.0,
                    rate_hz: float = 200.0, seed: int = 0) -> Path:
    """The bench log (``t,u,warp``) of the sheath wing swept over warp 0..``max_warp_deg``."""
    from warpbridge.sitl.sheath import SheathPlant

    lo, hi = SheathPlant(params).travel_range(max_warp_deg)
    cols = bench_log(sheath_spec(params), lo, hi, seconds=seconds, rate_hz=rate_hz, seed=seed)
    np.savetxt(path, np.column_stack([cols["t"], cols["u"], cols["warp"]]), delimiter=",", header="t,u,warp",
               comments="", fmt=["%.4f", "%.6f", "%.6f"])
    return path


def identify_bench(params, out_dir: Path, *, seed: int = 0, seconds: float = 90.0, quiet: bool = True,
                   max_delay: float = 0.0) -> Path:
    """Record the bench log into ``out_dir`` and run ``warpbridge identify`` on it (``--max-delay``
    ``max_delay``); returns MODEL.json."""
    out_dir.mkdir(parents=True, exist_ok=True)
    csv = write_bench_log(params, out_dir / "bench.csv", seconds=seconds, seed=seed)
    model = out_dir / "wing.json"
    cmd = [sys.executable, "-m", "warpbridge.bridge.cli", "identify", str(csv), "-o", str(model),
           "--seed", str(seed), "--max-delay", str(max_delay)] + (["--quiet"] if quiet else [])
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"identify failed on the bench log: {r.stderr.strip()[-500:]}")
    log.info("%s", r.stdout.strip())
    (out_dir / "identify.txt").write_text(r.stdout, encoding="utf-8")
    return model
