"""The strict base model, config paths and the validators shared by several config sections."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from pydantic import AfterValidator, BaseModel, ConfigDict, ValidationInfo


class Strict(BaseModel):
    """Base of every config section: frozen, unknown keys are errors, numbers are finite.

    NaN and infinity are refused everywhere: no physical quantity in a configuration is
    either, and one that slipped through (a NaN mount position) made every bin read clear.
    """

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)


def _resolve_path(value: Path, info: ValidationInfo) -> Path:
    base = (info.context or {}).get("base_dir")
    path = value.expanduser()
    if not path.is_absolute() and base is not None:
        path = Path(base) / path
    return path


ConfigPath = Annotated[Path, AfterValidator(_resolve_path)]
"""A path in the config; relative paths are relative to the config file's folder."""


def _existing_file(value: Path) -> Path:
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
