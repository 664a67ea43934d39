"""The strict base model, config paths and the validators shared by several config sections."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, ValidationInfo
from pydantic import Strict as StrictMode

from avoidd.fileread import not_regular


class Strict(BaseModel):
    """Base of every config section: frozen, unknown keys are errors, numbers are finite.

    NaN and infinity are refused everywhere: no physical quantity in a configuration is
    either, and one that slipped through (a NaN mount position) made every bin read clear.
    Values are never converted (pydantic strict mode): ``system_id: "7"`` or ``true``,
    ``fps: "15"``, ``enabled: 1`` are errors, not 7, 15.0 and True; a whole number is fine
    where a decimal one is asked for. Paths and tuples, which YAML cannot spell, are the
    exceptions (see ``Lax``).
    """

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False, strict=True)


Lax = StrictMode(False)
"""Annotation for what YAML cannot spell as such: a path (a string) and a tuple (a list).
The items of a lax tuple stay strict."""


def _whole_number(value: object) -> object:
    # A Literal of numbers takes 1.0 and true for 1, even in strict mode.
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError("must be a whole number, written without quotes or a decimal point")
    return value


WholeNumber = BeforeValidator(_whole_number)
"""Annotation for a Literal of whole numbers (``version``, window sizes): refuses 1.0 and
true where 1 is meant."""


def _resolve_path(value: Path, info: ValidationInfo) -> Path:
    base = (info.context or {}).get("base_dir")
    path = value.expanduser()
    if not path.is_absolute() and base is not None:
        path = Path(base) / path
    return path


ConfigPath = Annotated[Path, Lax, AfterValidator(_resolve_path)]
"""A path in the config; relative paths are relative to the config file's folder."""


def _existing_file(value: Path) -> Path:
    reason = not_regular(value)
    if reason is not None:
        raise ValueError(f"{value} is {reason}; give the path of a file")
    if not value.is_file():
        raise ValueError(f"file not found: {value}; check the path (relative to the config file)")
    return value


def _existing_path(value: Path, info: ValidationInfo) -> Path:
    # A command given its own input (``--input``) does not read this path: no need for it.
    if (info.context or {}).get("input_given"):
        return value
    if not value.exists():
        raise ValueError(f"not found: {value}; check the path (relative to the config file)")
    return value


def _multiple_of_16(value: int) -> int:
    if value % 16:
        raise ValueError(f"must be a multiple of 16; use {((value + 15) // 16) * 16}")
    return value


def _odd(value: int) -> int:
    if value % 2 == 0:
        raise ValueError(f"must be odd; use {value + 1}")
    return value
