"""Tuning parameters: their definitions (``ParamSpec``) and the persisted store (``ParamStore``).

A parameter has a name of at most 16 characters (the MAVLink param_id), a default,
a range and a description written beside its definition; integer parameters hold
whole numbers. ``ParamStore.set`` validates (unknown name, NaN/inf, out of range,
not a number, not a whole number) and refuses with ``ParamError`` whose message
says why; accepted values are applied live through the spec's ``on_set`` and any
listeners, then persisted. The file is JSON (``{"format": "warpbridge-params/1",
"params": {name: value}}``, only values that differ from the default, like
ArduPilot) written atomically: temporary file in the same folder, flush, fsync,
``os.replace``, fsync of the folder, so a kill at any moment leaves either the
old or the new set. Writing happens on a background thread so a set never stalls
the control loop (``flush()`` waits for it, ``close()`` flushes). At start-up a
corrupt or truncated file falls back to defaults, is moved aside as
``<file>.corrupt-<time>`` and ``load_report`` holds one line saying so, for the
caller to send as STATUSTEXT.
"""

from __future__ import annotations

import json
import logging
import math
import os
import struct
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from warpbridge.bridge.atomic import write_text_atomic

log = logging.getLogger(__name__)

FORMAT = "warpbridge-params/1"
NAME_MAX = 16
# MAVLink carries values as float32: a value within this relative distance of a
# bound is taken as the bound (0.1 sent as float32 is 0.100000001).
_F32_TOL = 1e-6
FLOAT32_MAX = 3.4028234663852886e38


class ParamError(ValueError):
    """A refused parameter operation; the message is the reason, fit for a STATUSTEXT."""


@dataclass(frozen=True)
class ParamSpec:
    """One tuning parameter: MAVLink name (<= 16 chars), default, range, meaning."""

    name: str
    default: float
    min: float
    max: float
    description: str
    integer: bool = False
    on_set: Callable[[str, float], None] | None = None

    def __post_init__(self) -> None:
        if not self.name or len(self.name) > NAME_MAX or not self.name.isascii() or " " in self.name:
            raise ValueError(f"parameter name {self.name!r}: 1..{NAME_MAX} ASCII characters, no spaces")
        for v in (self.default, self.min, self.max):
            if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v):
                raise ValueError(f"{self.name}: default/min/max must be finite numbers")
            if abs(v) > FLOAT32_MAX:
                raise ValueError(f"{self.name}: default/min/max beyond what MAVLink's float32 carries")
        if not self.min <= self.default <= self.max:
            raise ValueError(f"{self.name}: default {self.default} outside {self.min}..{self.max}")
        if self.integer and not all(float(v).is_integer() for v in (self.default, self.min, self.max)):
            raise ValueError(f"{self.name}: integer parameter with non-integer default or bounds")

    def validate(self, value: Any) -> float:
        """Return ``value`` as stored (clamped onto a bound within float32 error, at float32's precision: see
        ``_float32_shortest``) or raise ParamError."""
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ParamError(f"{self.name}: not a number: {value!r}")
        try:
            v = float(value)
        except OverflowError:
            raise ParamError(f"{self.name}: {value!r:.20} is not a finite number") from None
        if not math.isfinite(v):
            raise ParamError(f"{self.name}: {v} is not a finite number")
        if v < self.min - _F32_TOL * max(1.0, abs(self.min)):
            raise ParamError(f"{self.name}: {_fmt(v)} below min {_fmt(self.min)}")
        if v > self.max + _F32_TOL * max(1.0, abs(self.max)):
            raise ParamError(f"{self.name}: {_fmt(v)} above max {_fmt(self.max)}")
        # at float32's precision, then onto the range; the default and the bounds as defined when MAVLink
        # carries them alike (a model's parameter is no short decimal)
        v = min(max(_float32_shortest(v), self.min), self.max)
        v = next((float(x) for x in (self.default, self.min, self.max) if _float32(x) == _float32(v)), v)
        if self.integer:
            r = round(v)
            if abs(v - r) > _F32_TOL * max(1.0, abs(v)):
                raise ParamError(f"{self.name}: must be a whole number, got {_fmt(v)}")
            v = float(r)
        return v


def _float32(v: float) -> float:
    return struct.unpack("<f", struct.pack("<f", v))[0]


def _float32_shortest(v: float) -> float:
    """The shortest decimal that MAVLink's float32 carries as the same value as ``v``: a value set from a
    ground station is stored as typed (0.6, where the float32 reads 0.6000000238418579), and one set to the
    default is the default."""
    f = _float32(v)
    for digits in range(1, 10):
        d = float(f"{f:.{digits}g}")
        if _float32(d) == f:
            return d
    return f


def _fmt(v: float) -> str:
    return f"{v:.6g}"


class ParamStore:
    """Validated, live, persisted parameter values; see the module docstring."""

    def __init__(
        self, specs: Iterable[ParamSpec], path: str | os.PathLike[str] | None, *, background: bool = True
    ) -> None:
        self.specs: dict[str, ParamSpec] = {}
        for spec in specs:
            if spec.name in self.specs:
                raise ValueError(f"parameter {spec.name} defined twice")
            self.specs[spec.name] = spec
        self.names: list[str] = list(self.specs)  # MAVLink param_index order
        self.path = Path(path) if path is not None else None
        self._values = {n: float(s.default) for n, s in self.specs.items()}
        self._listeners: list[Callable[[str, float], None]] = []
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._version = 0  # bumped by every accepted set
        self._saved = 0  # version last written
        self._closed = False
        self._thread: threading.Thread | None = None
        self.save_errors = 0
        self.load_report: str | None = self.load()
        if background and self.path is not None:
            self._thread = threading.Thread(target=self._writer, name="param-writer", daemon=True)
            self._thread.start()
        self._background = background

    # ------------------------------------------------------------------ access

    def __contains__(self, name: str) -> bool:
        return name in self.specs

    def __len__(self) -> int:
        return len(self.names)

    def get(self, name: str) -> float:
        try:
            return self._values[name]
        except KeyError:
            raise ParamError(f"unknown parameter {name!r}") from None

    def values(self) -> dict[str, float]:
        with self._lock:
            return dict(self._values)

    def index(self, name: str) -> int:
        return self.names.index(name)

    def add_listener(self, callback: Callable[[str, float], None]) -> None:
        """Call ``callback(name, value)`` after every accepted change."""
        self._listeners.append(callback)

    def set(self, name: str, value: Any) -> float:
        """Validate, apply live and persist; returns the stored value or raises ParamError."""
        spec = self.specs.get(name)
        if spec is None:
            raise ParamError(f"unknown parameter {name!r}")
        v = spec.validate(value)
        old = self._values[name]
        if _float32(v) == _float32(old):  # what MAVLink carries of the value held: no change
            return old
        if spec.on_set is not None:
            try:
                spec.on_set(name, v)
            except Exception as e:  # noqa: BLE001 - the owner refused or failed to apply it
                raise ParamError(f"{name}: not applied: {e}") from e
        with self._cond:
            self._values[name] = v
            self._version += 1
            self._cond.notify_all()
        for cb in self._listeners:
            try:
                cb(name, v)
            except Exception:  # noqa: BLE001
                log.exception("parameter listener failed for %s", name)
        if not self._background:
            self.save()
        return v

    # ------------------------------------------------------------------ persistence

    def load(self) -> str | None:
        """Read the file (missing: defaults). Returns a one-line report if anything was wrong."""
        if self.path is None:
            return None
        self._remove_stale_temps()
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return None
        except OSError as e:
            return f"params: cannot read {self.path.name} ({e.strerror}); defaults used"
        except ValueError:  # not UTF-8: corrupt
            text = None
        try:
            if text is None:
                raise ValueError("not UTF-8 text")
            doc = json.loads(text)
            if not isinstance(doc, dict) or doc.get("format") != FORMAT or not isinstance(doc.get("params"), dict):
                raise ValueError("not a warpbridge parameter file")
        except (ValueError, RecursionError) as e:
            kept = self._move_aside()
            log.error("parameter file %s is corrupt (%s); defaults loaded, kept as %s", self.path, e, kept)
            return f"params file corrupt: defaults loaded, kept as {kept}"
        refused = []
        for name, value in doc["params"].items():
            spec = self.specs.get(name)
            if spec is None:
                log.warning("parameter file: %s is not a parameter any more; ignored", name)
                continue
            try:
                self._values[name] = spec.validate(value)
            except ParamError as e:
                refused.append(name)
                log.warning("parameter file: %s; default kept", e)
        if refused:
            return f"params: default kept for {', '.join(refused)} (invalid in file)"
        return None

    def _move_aside(self) -> str:
        assert self.path is not None
        aside = self.path.with_name(f"{self.path.name}.corrupt-{time.strftime('%Y%m%dT%H%M%S')}")
        n = 1
        while aside.exists():
            aside = aside.with_name(f"{aside.name.split('~')[0]}~{n}")
            n += 1
        try:
            os.replace(self.path, aside)
        except OSError as e:
            log.error("could not move %s aside: %s", self.path, e)
            return self.path.name
        return aside.name

    def _temp_prefix(self) -> str:
        assert self.path is not None
        return f".{self.path.name}.tmp-"

    def _remove_stale_temps(self) -> None:
        assert self.path is not None
        folder = self.path.parent
        if not folder.is_dir():
            return
        for p in folder.glob(self._temp_prefix() + "*"):
            try:
                p.unlink()
            except OSError:
                pass

    def save(self) -> bool:
        """Write the current values now (atomically); False if the write failed."""
        if self.path is None:
            return True
        with self._lock:
            version = self._version
            changed = {n: v for n, v in self._values.items() if v != self.specs[n].default}
        doc = {"format": FORMAT, "params": changed}
        try:
            write_text_atomic(self.path, json.dumps(doc, indent=1, sort_keys=True) + "\n",
                              temp_prefix=self._temp_prefix(), make_dirs=True)
        except OSError as e:
            self.save_errors += 1
            log.error("could not save parameters to %s: %s", self.path, e)
            return False
        with self._cond:
            self._saved = max(self._saved, version)
            self._cond.notify_all()
        return True

    def _writer(self) -> None:
        while True:
            with self._cond:
                while self._saved >= self._version and not self._closed:
                    self._cond.wait()
                if self._closed and self._saved >= self._version:
                    return
            if not self.save():
                time.sleep(1.0)  # disk full or read-only: try again later

    def flush(self, timeout: float = 5.0) -> bool:
        """Wait until every accepted change is on disk; False on timeout."""
        if self.path is None:
            return True
        if self._thread is None:
            return self.save() if self._saved < self._version else True
        with self._cond:
            return self._cond.wait_for(lambda: self._saved >= self._version, timeout)

    def close(self, timeout: float = 5.0) -> None:
        """Flush and stop the writer thread."""
        self.flush(timeout)
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None


