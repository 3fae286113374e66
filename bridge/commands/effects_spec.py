"""Parsing effect switches written on a command line: ``delay=0.03,backlash=0.2,pretension=0.3:0.95``.

Each effect name of the design brief takes its parameters in the order of
``model.effects.EFFECT_FIELDS`` separated by ``:``; omitted trailing ones keep
their neutral value.
"""

from __future__ import annotations

from warpbridge.bridge.errors import UserError
from warpbridge.model.effects import EFFECT_FIELDS, EFFECT_NAMES, Effects


def parse_effects(spec: str | None) -> Effects:
    """Effects from ``name=v1[:v2],...``; empty or None gives no effect."""
    if not spec:
        return Effects()
    kw: dict[str, float] = {}
    for item in spec.split(","):
        item = item.strip()
        if not item:
            continue
        name, sep, vals = item.partition("=")
        name = name.strip()
        if name not in EFFECT_FIELDS:
            raise UserError(f"unknown effect {name!r} (known: {', '.join(EFFECT_NAMES)})")
        if not sep or not vals.strip():
            raise UserError(f"effect {name!r} needs a value, e.g. {name}={describe(name)}")
        fields = EFFECT_FIELDS[name][0]
        parts = vals.split(":")
        if len(parts) > len(fields):
            raise UserError(f"effect {name!r} takes at most {len(fields)} value(s): {', '.join(fields)}")
        for f, v in zip(fields, parts, strict=False):
            try:
                kw[f] = float(v)
            except ValueError:
                raise UserError(f"effect {name!r}: {v!r} is not a number") from None
    try:
        return Effects(**kw)
    except ValueError as e:
        raise UserError(str(e)) from None


def describe(name: str) -> str:
    fields, neutral, _ = EFFECT_FIELDS[name]
    return ":".join(f"<{f}>" for f in fields)


def help_text() -> str:
    return "; ".join(f"{n}={describe(n)}" for n in EFFECT_NAMES)
