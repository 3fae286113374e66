"""Validate a REPORT.json or MODEL.json document against the schema the package ships (for any test that writes one).

    from schema_check import validate_model, validate_report
    validate_report(json.loads(path.read_text()))

Each raises ``AssertionError`` listing every violation (its JSON path and message), so a failing test says
which field broke the format.
"""

from __future__ import annotations

from functools import cache

from jsonschema import Draft202012Validator, FormatChecker

from warpbridge.bridge.commands.schemas import load_schema


@cache
def validator(name: str) -> Draft202012Validator:
    """A validator of schema ``name`` (``"report"`` or ``"model"``), its formats checked too."""
    schema = load_schema(name)
    Draft202012Validator.check_schema(schema)
    return Draft202012Validator(schema, format_checker=FormatChecker())


def violations(doc: object, name: str) -> list[str]:
    """Every way ``doc`` breaks schema ``name``, as ``path: message`` lines (empty: it is valid)."""
    errors = sorted(validator(name).iter_errors(doc), key=lambda e: list(map(str, e.absolute_path)))
    return [f"{'/'.join(map(str, e.absolute_path)) or '(top)'}: {e.message}" for e in errors]


def _check(doc: object, name: str) -> None:
    bad = violations(doc, name)
    assert not bad, f"not a valid {name} document ({len(bad)} violations):\n" + "\n".join(bad[:20])


def validate_report(doc: object) -> None:
    """Assert that ``doc`` is a valid REPORT.json (``warpbridge-diagnosis/1``)."""
    _check(doc, "report")


def validate_model(doc: object) -> None:
    """Assert that ``doc`` is a valid MODEL.json as warpbridge writes it (``warpbridge-model/1``)."""
    _check(doc, "model")
