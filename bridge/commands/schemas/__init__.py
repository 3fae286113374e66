"""JSON Schemas (draft 2020-12) of the files the offline commands write, shipped as package data.

``report`` is REPORT.json (``"format": "warpbridge-diagnosis/1"``, written by ``warpbridge diagnose``),
``model`` is MODEL.json (``"format": "warpbridge-model/1"``, written by ``identify`` and ``diagnose
--out-model``). docs/report-format.md describes them field by field. The commands do not validate what they
write (the tests do, with ``jsonschema``); these are for the tests and for anyone reading the files.
"""

from __future__ import annotations

import json
from functools import cache
from importlib import resources

SCHEMAS: dict[str, str] = {"report": "report.schema.json", "model": "model.schema.json"}


@cache
def _text(name: str) -> str:
    if name not in SCHEMAS:
        raise KeyError(f"no schema {name!r} (known: {', '.join(SCHEMAS)})")
    return resources.files(__name__).joinpath(SCHEMAS[name]).read_text(encoding="utf-8")


def load_schema(name: str) -> dict:
    """The schema ``name`` (``"report"`` or ``"model"``) as a fresh dict."""
    return json.loads(_text(name))
