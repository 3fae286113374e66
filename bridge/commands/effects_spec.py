"""Parsing effect switches written on a command line: ``delay=0.03,backlash=0.2,pretension=0.3:0.95``.

Each effect name of the design brief takes its parameters in the order of
``model.effect_registry.EFFECT_FIELDS`` separated by ``:``; omitted trailing ones keep
their neutral value. A single parameter may also be set by its own name
(``aero_deg_per_kpa=2``). ``warpbridge simulate --effects`` and
``warpbridge sitl --effects`` both read this form.
"""

from __future__ import annotations

from dataclasses import fields as dataclass_fields

from warpbridge.bridge.errors import UserError
from warpbridge.model.effect_registry import EFFECT_FIELDS
from warpbridge.model.effects import Effects

PARAMETERS = frozenset(f.name for f in dataclass_fields(Effects))


def parse_effects(spec: str | None) -> Effects:
    """Effects from ``name=v1[:v2],...`` (effect names, or single parameter names); empty or None gives no
    effect. Errors are ``UserError``s naming the ``--effects`` option."""
    if not spec:
        return Effects()
    kw: dict[str, float] = {}
    for item in spec.split(","):
        item = item.strip()
        if not item:
            continue
        name, sep, vals = item.partition("=")
        name = name.strip()
        if name in EFFECT_FIELDS:
            names = EFFECT_FIELDS[name][0]
            example = f"{name}={describe(name)}"
        elif name in PARAMETERS:
            names = (name,)
            example = f"{name}=<value>"
        else:
            raise UserError(f"--effects: unknown effect {name!r} (known: {', '.join(EFFECT_FIELDS)}, or one of "
                            "their parameters by name)")
        if not sep or not vals.strip():
            raise UserError(f"--effects: effect {name!r} needs a value, e.g. {example}")
        parts = vals.split(":")
        if len(parts) > len(names):
            raise UserError(f"--effects: {name!r} takes at most {len(names)} value(s): {', '.join(names)}")
        for f, v in zip(names, parts, strict=False):
            try:
                kw[f] = float(v)
            except ValueError:
                raise UserError(f"--effects: effect {name!r}: {v!r} is not a number") from None
    try:
        return Effects(**kw)
    except ValueError as e:
        raise UserError(f"--effects: {e}") from None


def describe(name: str) -> str:
    fields, neutral, _ = EFFECT_FIELDS[name]
    return ":".join(f"<{f}>" for f in fields)


def help_text() -> str:
    return ("; ".join(f"{n}={describe(n)}" for n in EFFECT_FIELDS)
            + "; or one parameter by its name (aero_deg_per_kpa=2)")
