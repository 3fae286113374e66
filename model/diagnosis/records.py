"""Report records: dataclasses written to REPORT.json field by field (docs/report-format.md)."""

from __future__ import annotations

from dataclasses import fields
from typing import ClassVar


def plain(v):
    """The JSON-ready form of a report value: records by their ``to_dict``, lists and dicts item by item."""
    if hasattr(v, "to_dict"):
        return v.to_dict()
    if isinstance(v, (list, tuple)):
        return [plain(x) for x in v]
    if isinstance(v, dict):
        return {k: plain(x) for k, x in v.items()}
    return v


class Record:
    """A report record: written field by field, in field order, under its field's name (``KEYS`` renames one;
    a field in ``OPTIONAL`` is left out when it is None)."""

    KEYS: ClassVar[dict[str, str]] = {}
    OPTIONAL: ClassVar[tuple[str, ...]] = ()

    def to_dict(self) -> dict:
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if v is None and f.name in self.OPTIONAL:
                continue
            out[self.KEYS.get(f.name, f.name)] = plain(v)
        return out
