"""What ``warpbridge run`` does before the rest of the bridge loads: the model file, and neutral on the servos.

A bridge process that starts while the tendon servos are powered (a restart by
systemd after a crash, the companion computer rebooting in flight) finds them
wherever the last process left them, possibly at full pull. ``command_neutral``
therefore opens the servo board and puts each wing at its neutral tendon
position before numpy, the MAVLink library and the rest of the bridge are
imported: it needs the config, three numbers of the model file (read with the
standard library; the full, validated read follows when the bridge starts) and
the serial port.

Neutral for a one-sided tendon is not the servo's middle pulse: 1500 us may be
several millimetres of pull on one wing and slack on the other. It is the
tendon travel at which the wing holds its neutral warp (``bias_deg``, capped at
``max_warp_deg``; 0 = unloaded): the model's centre line
``u = a1 b^2 + a2 b + a3`` (hysteretic state z = 0, the middle of the loop; the
real wing sits within half a loop width of it), clamped to the wing's tendon
limits, turned into a pulse by the wing's own servo calibration (its zero and
its sign). That is also what the first control cycle commands in ``ff`` with
no aileron input yet, so the hand-over is smooth. The model file's pre-tension
effect is folded in (u = offset + u_model / gain); persisted ``WB_BIAS`` /
``WB_MAXWARP`` values and per-wing calibrations apply from the first cycle on.
With ``[servo] backend = "fc:..."`` there is nothing to do before the link is up.
"""

from __future__ import annotations

import json
import logging
import math
from typing import TYPE_CHECKING, Any

from warpbridge.bridge.config import Config, WingConfig
from warpbridge.bridge.errors import UserError
from warpbridge.hw import DeviceError, open_servo
from warpbridge.hw.calibration import ServoCalibration

if TYPE_CHECKING:
    from warpbridge.model.boucwen import BoucWenParams
    from warpbridge.model.modelfile import ModelFile

log = logging.getLogger(__name__)

# a1 (mm/deg^2), a2 (mm/deg), a3 (mm) of BoucWenParams.paper(), for the start before numpy loads
# (tests/test_startup.py holds them equal)
PAPER_CENTRE = (-0.0205, 0.7120, 0.7958)


def load_model_file(config: Config) -> ModelFile:
    """The whole ``[model] file``: parameters and effects (the paper's parameters for ``"paper"``)."""
    from warpbridge.model.boucwen import BoucWenParams
    from warpbridge.model.compensation import INVERTIBLE
    from warpbridge.model.modelfile import ModelFile

    if config.model_file is None:
        return ModelFile(params=BoucWenParams.paper())
    try:
        doc = json.loads(config.model_file.read_text(encoding="utf-8"))
        mf = ModelFile.from_dict(doc)
    except RecursionError:
        raise UserError(f"[model] file: {config.model_file}: JSON nested too deeply") from None
    except OSError as e:
        raise UserError(f"[model] file: cannot read {config.model_file}: {e.strerror or e}") from None
    except (ValueError, TypeError, UnicodeDecodeError) as e:
        raise UserError(f"[model] file: {config.model_file}: {e}") from None
    left = [e for e in mf.effects.active() if e not in INVERTIBLE and e != "delay"]
    if left:
        log.warning("model effects %s cannot be inverted by a feed-forward; the PI trim handles them",
                    ", ".join(left))
    if mf.effects.delay_s > 0:  # identify's transport delay: the rig's servo, link and sensor lag
        log.info("model: the warp follows the tendon %.0f ms late (transport delay); the feed-forward inverts "
                 "the hysteresis only, the PI trim sees the delay", 1e3 * mf.effects.delay_s)
    if mf.effects.has_servo:  # identify's servo: the tendon follows the command through its position loop
        rate = mf.effects.servo_rate_mm_s
        band = mf.effects.servo_deadband_mm
        log.info("model: the servo follows its command with a %.0f ms lag%s%s; the feed-forward leads it (the "
                 "command that brings it to the model's travel by the next step)", 1e3 * mf.effects.servo_tau_s,
                 f", at most {rate:.3g} mm/s" if math.isfinite(rate) else "",
                 f", within a {band:.3g} mm dead band" if band > 0 else "")
    return mf


def load_model(config: Config) -> BoucWenParams:
    """The Bouc-Wen parameters named by ``[model] file`` with its friction and pre-tension folded in."""
    from warpbridge.model.effects import core_params

    mf = load_model_file(config)
    return core_params(mf.params, mf.effects)


def centre_line(config: Config) -> tuple[float, float, float] | None:
    """(a1, a2, a3) of the model's centre line, pre-tension folded in, read with the standard library only;
    None if the model file cannot be read that way (the bridge's full read then reports why)."""
    if config.model_file is None:
        return PAPER_CENTRE
    try:
        doc = json.loads(config.model_file.read_text(encoding="utf-8"))
        a1, a2, a3 = (float(doc["params"][k]) for k in ("a1", "a2", "a3"))
        effects = doc.get("effects") or {}
        pt = effects.get("pretension") or {}
        off, gain = float(pt.get("pretension_offset_mm", 0.0)), float(pt.get("pretension_gain", 1.0))
        friction = effects.get("friction") or {}
        scale = float(friction.get("friction_scale", 1.0))
        pivot = float(friction.get("friction_pivot", 0.0))
        shift = _friction_shift(doc["params"], scale, pivot) if scale != 1.0 else 0.0
        whole_loop = float(pt.get("pretension_loop", 0.0)) == 1.0  # the band scaled with the backbone
        if doc.get("effect_forms", 1) == 1 or whole_loop:  # the earlier forms, or the whole loop: the shift
            shift /= gain  # is folded after the gain scaled az
    except (OSError, ValueError, TypeError, KeyError, AttributeError, RecursionError, ZeroDivisionError,
            OverflowError):
        return None
    if not all(math.isfinite(x) for x in (a1, a2, a3, off, gain, shift)) or not gain > 0:
        return None
    return a1 / gain, a2 / gain, a3 / gain + off + shift


def _friction_shift(params: dict, scale: float, pivot: float = 0.0) -> float:
    """The move of a3 that keeps the level ``pivot`` of the hysteresis band (0 its middle, +-1 its edges) in
    place when the friction change ``scale`` widens the loop (``model.effects.friction_core``, on positive
    warp), in plain Python."""
    az, A, n = float(params["az"]), float(params["A"]), float(params["n"])
    b1, b2, b3, b4, b5, b6 = (float(x) for x in params["b"])
    psi_hi = b1 + b2 + b3 + b4 + b5 + b6  # loading, z > 0
    psi_lo = b1 - b2 - b3 - b4 - b5 + b6  # unloading, z < 0
    if not (psi_hi > 0 and psi_lo > 0 and A > 0):
        return 0.0
    hi, lo = (A / psi_hi) ** (1.0 / n), -((A / psi_lo) ** (1.0 / n))
    return az * (1.0 - scale) * (0.5 * (hi + lo) + pivot * 0.5 * (hi - lo))


def servo_calibration(wing: WingConfig) -> ServoCalibration:
    """The wing's servo calibration (pulse <-> tendon mm); UserError if the config's values are unusable."""
    s = wing.servo
    try:
        return ServoCalibration(s.pulse_min_us, s.pulse_max_us, s.pulse_zero_us, s.mm_per_us)
    except ValueError as e:
        raise UserError(f"[wing.{wing.name}] calibration: {e}") from None


def tendon_limits(wing: WingConfig) -> tuple[float, float]:
    """The wing's tendon travel limits (mm): ``[control] u_min_mm/u_max_mm`` or the servo's range."""
    lo, hi = wing.servo.mm_limits
    c = wing.control
    return (lo if c.u_min_mm is None else c.u_min_mm, hi if c.u_max_mm is None else c.u_max_mm)


def neutral_warp(wing: WingConfig) -> float:
    """The warp a wing holds at neutral aileron (deg): its bias, within [0, max warp]."""
    return min(max(wing.bias_deg, 0.0), wing.max_warp_deg)


def neutral_tendon_mm(centre: tuple[float, float, float] | BoucWenParams, wing: WingConfig) -> float:
    """Tendon travel (mm) of the wing's neutral warp on the model's centre line (z = 0), within its limits;
    ``centre`` is (a1, a2, a3) or a model."""
    a1, a2, a3 = (centre.a1, centre.a2, centre.a3) if hasattr(centre, "a1") else centre
    b = neutral_warp(wing)
    u = a1 * b * b + a2 * b + a3
    lo, hi = tendon_limits(wing)
    return min(hi, max(lo, u))


def neutral_pulses(config: Config, centre: tuple[float, float, float] | BoucWenParams) -> dict[int, float]:
    """Servo channel -> neutral pulse (us) for both wings."""
    return {w.servo_channel: servo_calibration(w).pulse_for_mm(neutral_tendon_mm(centre, w))
            for w in config.wings.values()}


def servo_limits(config: Config) -> dict[int, tuple[float, float]]:
    """Each wing's calibrated pulse range, keyed by its servo channel: the backend's safe range."""
    return {w.servo_channel: (w.servo.pulse_min_us, w.servo.pulse_max_us) for w in config.wings.values()}


def command_neutral(config: Config, limits: dict[int, tuple[float, float]]) -> Any:
    """Open the servo board and command every wing's neutral pulse; returns the open backend (the caller
    owns it), or None for ``fc:`` backends and when the board cannot be opened now (the bridge retries)."""
    spec = config.servo_backend
    if spec.strip().lower().startswith("fc:"):
        return None
    centre = centre_line(config)
    if centre is None:
        return None  # the bridge's own read of the model file says what is wrong with it
    pulses = neutral_pulses(config, centre)
    try:
        servo = open_servo(spec, limits=limits)
    except ValueError as e:
        raise UserError(f"[servo] backend: {e}") from None
    except DeviceError as e:
        log.warning("servo board: %s; neutral not commanded yet (the bridge keeps trying)", e)
        return None
    try:
        for channel, pulse in pulses.items():
            servo.set_pulse(channel, pulse)
    except DeviceError as e:
        log.warning("servo board: %s while commanding neutral", e)
    what = ", ".join(f"{w.name} ch {w.servo_channel} {pulses[w.servo_channel]:.0f} us" for w in config.wings.values())
    log.info("servo board %s: neutral %s", spec, what)
    return servo
