"""Reading and writing MODEL.json files (format ``warpbridge-model/1``), with one-line errors."""

from __future__ import annotations

import json
import os
from pathlib import Path

from warpbridge.bridge.commands.logfile import write_text_atomic
from warpbridge.bridge.errors import UserError
from warpbridge.model.modelfile import ModelFile


def load_model(path: str | os.PathLike) -> ModelFile:
    """Load a model file; ``paper`` gives the paper's identified model."""
    if str(path) == "paper":
        from warpbridge.model.boucwen import BoucWenParams

        return ModelFile(params=BoucWenParams.paper(), meta={"source": "Lee et al. 2017, eq. (2)"})
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise UserError(f"{p}: no such model file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise UserError(f"{p}: cannot read model file ({e})") from None
    try:
        d = json.loads(text)
    except json.JSONDecodeError as e:
        raise UserError(f"{p}: not valid JSON (line {e.lineno}: {e.msg})") from None
    except RecursionError:
        raise UserError(f"{p}: JSON nested too deeply to be a model file") from None
    try:
        return ModelFile.from_dict(d)
    except (ValueError, TypeError, RecursionError) as e:
        raise UserError(f"{p}: {e}") from None


def save_model(path: str | os.PathLike, model: ModelFile) -> None:
    """Write a model file atomically."""
    write_text_atomic(path, json.dumps(model.to_dict(), indent=2, allow_nan=False) + "\n")


def travel_note(model: ModelFile, u) -> str | None:
    """A note when more than 1 % of a log drives the tendon beyond the travel the model was identified on."""
    out = model.travel_outside(u)
    if out is None or out[2] + out[3] <= 0.01:
        return None
    lo, hi, below, above = out
    return (f"{below + above:.0%} of the log drives the tendon beyond the travel of the log the model was "
            f"identified on ({lo:.2f}..{hi:.2f} mm; {below:.0%} below it, {above:.0%} above): the model "
            "extrapolates there, and its errors there are not the bench's")
