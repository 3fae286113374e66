"""MODEL.json as a plain dict (``"format": "warpbridge-model/1"``) and back; no file I/O here.

A model file holds the Bouc-Wen parameters, the initial state, optional
effects (applied by ``predict`` and the bridge's feed-forward), the fit
quality ``identify`` measured, free-form provenance and, optionally, the
model-error model learned from the bench residual (``"model_error"``, read by
``diagnose``). ``fit.travel_mm`` is the tendon travel of the log the model was
identified on: ``predict`` and ``diagnose`` say when a log leaves it, where the
model extrapolates (``ModelFile.travel_outside``). The field is optional both ways: files without it load as
before, and readers that predate it ignore it.

``"effect_forms": 2`` marks the forms of ``friction`` (the band of z scaled)
and ``pretension`` (the backbone moved) that ``model.effects`` has used since
they changed. A file without the mark that carries either effect was written
with the earlier forms (friction scaled az, pre-tension mapped the input,
u_eff = gain (u - offset)); both are static, so they are folded exactly into
its Bouc-Wen parameters on reading (``fold_legacy_rigging``) and the file means
what it meant when it was written.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from warpbridge.model.boucwen import BoucWenParams
from warpbridge.model.effects import Effects, fold_rigging, friction_core
from warpbridge.model.model_error import ErrorModel
from warpbridge.model.plant import Plant

FORMAT = "warpbridge-model/1"
EFFECT_FORMS = 2
TRAVEL_MARGIN = 0.02  # a sample this share of the identified travel's span beyond it is outside it


def fold_legacy_rigging(params: BoucWenParams, effects: Effects) -> tuple[BoucWenParams, Effects]:
    """Parameters and effects of a file written with the earlier friction and pre-tension forms: both
    folded into the parameters exactly (az scaled about the band's middle, then u = offset + f(w) / gain),
    the effects left without them."""
    s, o, g = effects.friction_scale, effects.pretension_offset_mm, effects.pretension_gain
    if s == 1.0 and o == 0.0 and g == 1.0:
        return params, effects
    # the earlier friction moved a3 as today's does, but scaled az instead of the saturation of z
    p = replace(friction_core(params, s), az=params.az * s, b=params.b)
    return fold_rigging(p, o, g), replace(effects, friction_scale=1.0, pretension_offset_mm=0.0,
                                          pretension_gain=1.0)


@dataclass
class FitQuality:
    """What identification measured: RMS on the training and held-out parts, noise floor (deg)."""

    train_rms_deg: float = math.nan
    heldout_rms_deg: float = math.nan
    noise_deg: float = math.nan
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        d = {"train_rms_deg": self.train_rms_deg, "heldout_rms_deg": self.heldout_rms_deg,
             "noise_deg": self.noise_deg}
        d.update(self.extra)
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}

    @classmethod
    def from_dict(cls, d: dict) -> FitQuality:
        def num(k):
            v = d.get(k)
            return math.nan if v is None else float(v)
        extra = {k: v for k, v in d.items() if k not in ("train_rms_deg", "heldout_rms_deg", "noise_deg")}
        return cls(num("train_rms_deg"), num("heldout_rms_deg"), num("noise_deg"), extra)


@dataclass
class ModelFile:
    """Everything a MODEL.json carries."""

    params: BoucWenParams
    effects: Effects = field(default_factory=Effects)
    z0: float = 0.0
    fit: FitQuality = field(default_factory=FitQuality)
    meta: dict = field(default_factory=dict)
    model_error: ErrorModel | None = None

    @property
    def plant(self) -> Plant:
        return Plant(self.params, self.effects)

    def travel_outside(self, u: np.ndarray) -> tuple[float, float, float, float] | None:
        """(lo, hi, below, above): the tendon travel of the log the model was identified on (``fit.travel_mm``)
        and the shares of a log's samples below and above it (2 % of its span of margin); None when the file does
        not say (identified before it was recorded, or not identified)."""
        tr = self.fit.extra.get("travel_mm")
        if not (isinstance(tr, list | tuple) and len(tr) == 2):
            return None
        try:
            lo, hi = float(tr[0]), float(tr[1])
        except (TypeError, ValueError):
            return None
        u = np.asarray(u, dtype=np.float64)
        u = u[np.isfinite(u)]
        if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo) or not u.size:
            return None
        m = TRAVEL_MARGIN * (hi - lo)
        return lo, hi, float(np.mean(u < lo - m)), float(np.mean(u > hi + m))

    def to_dict(self) -> dict:
        d = {
            "format": FORMAT,
            "model": "generalized-bouc-wen",
            "units": {"u": "mm", "warp": "deg", "t": "s", "airspeed": "m/s"},
            "params": self.params.to_dict(),
            "z0": self.z0,
            "effects": self.effects.to_dict(),
            "effect_forms": EFFECT_FORMS,
            "fit": self.fit.to_dict(),
            "meta": self.meta,
        }
        if self.model_error is not None:
            d["model_error"] = self.model_error.to_dict()
        return d

    @classmethod
    def from_dict(cls, d) -> ModelFile:
        if not isinstance(d, dict):
            raise ValueError("a model file must hold a JSON object")
        fmt = d.get("format")
        if fmt is None:
            raise ValueError("not a warpbridge model file (no \"format\" field)")
        if not isinstance(fmt, str) or not fmt.startswith("warpbridge-model/"):
            raise ValueError(f"not a warpbridge model file (format {fmt!r})")
        if fmt != FORMAT:
            raise ValueError(f"unsupported model format version {fmt!r} (this warpbridge reads {FORMAT!r})")
        if "params" not in d:
            raise ValueError("model file has no \"params\"")
        params = BoucWenParams.from_dict(d["params"])
        effects = Effects.from_dict(d.get("effects") or {})
        try:
            z0 = float(d.get("z0", 0.0))
        except (TypeError, ValueError):
            raise ValueError("model file z0 must be a number") from None
        fit = FitQuality.from_dict(d.get("fit") or {})
        em = d.get("model_error")
        model_error = ErrorModel.from_dict(em) if em is not None else None
        meta = dict(d.get("meta") or {})
        forms = d.get("effect_forms", 1)
        if forms not in (1, EFFECT_FORMS):
            raise ValueError(f"unsupported effect_forms {forms!r} (this warpbridge reads 1 and {EFFECT_FORMS})")
        if forms == 1:
            folded, effects2 = fold_legacy_rigging(params, effects)
            if effects2 != effects:
                params, effects = folded, effects2
                meta["folded_on_reading"] = ("friction and pretension of the earlier effect forms, folded into "
                                             "params")
        return cls(params=params, effects=effects, z0=z0, fit=fit, meta=meta, model_error=model_error)
