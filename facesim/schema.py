"""Reading YAML files into pydantic models, with one-line errors.

Every error names the file, the field path and what was expected, for example
``happy.yaml: muscles -> zygomaticus_major_l: Input should be less than or equal to 1``.
"""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError

from .errors import InputError

Model = TypeVar("Model", bound=BaseModel)
#: libyaml's safe loader where PyYAML was built with it (its wheels are): the same
#: documents, the same errors with their line, read 7 times faster (the head's muscle file
#: 36.8 -> 5.2 ms, 2026-12-03), which a fresh `facesim render` waits for.
SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class Strict(BaseModel):
    """Base of every file schema: unknown fields are errors, models are frozen, and
    ``.inf`` or ``.nan`` is no number (YAML reads both as floats)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


def describe(exc: ValidationError) -> str:
    """The first error of a pydantic ValidationError as ``a -> b: message``."""
    first = exc.errors()[0]
    where = " -> ".join(str(p) for p in first["loc"]) or "(top level)"
    message = first["msg"]
    if first["type"] == "extra_forbidden":
        message = "unknown field"
    got = first.get("input")
    if first["type"] not in ("missing", "extra_forbidden") and not isinstance(got, (dict, list)):
        message += f", got {got!r}"
    return f"{where}: {message}"


def read_yaml(path: Path) -> object:
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    try:
        return yaml.load(path.read_text(), Loader=SAFE_LOADER)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark else ""
        raise InputError(f"{path}: malformed YAML{where}: {getattr(exc, 'problem', exc)}") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file") from None


def load_model(path: str | Path, model: type[Model], context: dict | None = None) -> Model:
    """Read ``path`` as YAML and validate it against ``model``."""
    path = Path(path)
    data = read_yaml(path)
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a mapping of fields at the top level")
    try:
        return model.model_validate(data, context=context)
    except ValidationError as exc:
        raise InputError(f"{path}: {describe(exc)}") from None
