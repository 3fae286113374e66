"""The effects' registry is the one description of every effect: what it says agrees with the code that applies
the effects and with the tables derived from it."""

from __future__ import annotations

import math
from dataclasses import fields

import numpy as np
import pytest

from warpbridge.model import effects as E
from warpbridge.model.effect_registry import (
    EFFECT_FIELDS,
    LOAD_COUPLED,
    REGISTRY,
    SEPARATE,
    UNITS,
    LogScale,
    forms_for,
    spec,
)

T = np.linspace(0.0, 20.0, 4001)
U = 5.0 + 3.0 * np.sin(2 * np.pi * 0.5 * T)


def test_every_field_of_effects_is_one_registered_parameter_with_its_neutral_as_default():
    params = [p for s in REGISTRY for p in s.params]
    assert sorted(p.field for p in params) == sorted(f.name for f in fields(E.Effects) if f.name != "extra")
    assert len({p.field for p in params}) == len(params)  # no parameter belongs to two effects
    default = E.Effects()
    for p in params:
        assert getattr(default, p.field) == p.neutral, p.field


def test_every_effect_names_an_operator_of_model_effects_and_a_unit_per_parameter():
    for s in REGISTRY:
        assert callable(getattr(E, s.operator, None)), s.name
        assert all(p.field in UNITS for p in s.params)
        assert s.meaning


@pytest.mark.parametrize("name", [s.name for s in REGISTRY])
def test_each_form_searches_only_its_own_nonlinear_parameters_inside_the_log_scaled_boxes(name):
    s = spec(name)
    own = {p.field for p in s.params if not p.linear}
    for form in forms_for(name, T, U):
        for box in form:
            assert box.field in own, (name, box.field)
            assert box.lo <= box.hi and math.isfinite(box.lo) and math.isfinite(box.hi)
            if not box.fixed:  # a form's flag is held, not searched
                assert box.coord(box.value(0.5)) == pytest.approx(0.5)
    if not s.candidate:  # the rig's own effects are identified with the model, not searched
        assert forms_for(name, T, U) == [[]]


def test_the_readings_tables_name_registered_effects_and_their_own_parameters():
    names = set(EFFECT_FIELDS)
    assert all(pair <= names and len(pair) == 2 for pair in SEPARATE)
    assert set(LOAD_COUPLED) <= names
    for s in REGISTRY:
        assert all(param in s.fields and edge in ("lower", "upper") for param, edge in s.bound_hints)
        assert s.latency is None or s.latency in s.fields


def test_the_boxes_scale_with_the_log():
    # 20 s of a 3 mm sine at 0.5 Hz: its fastest motion is 3 pi mm/s
    scale = LogScale.of(T, U)
    assert scale.duration == 20.0 and scale.fs == pytest.approx(200.0)
    assert scale.vmax == pytest.approx(3 * math.pi, rel=1e-3)
    assert forms_for("drift", T, U)[0][0].lo == pytest.approx(0.25 * 20.0)
    assert spec("rate_limit").forms(scale)[0][0].hi == pytest.approx(1.02 * 3 * math.pi, rel=1e-3)
    assert forms_for("drift", T[:401], U[:401])[0][0].lo == pytest.approx(0.25 * 2.0)  # a tenth of the log


def test_an_unknown_effect_is_named_with_the_known_ones():
    with pytest.raises(KeyError, match="known: delay"):
        spec("flutter")
