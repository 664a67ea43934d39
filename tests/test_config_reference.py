"""The generated configuration reference matches the config models and documents every key."""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, Field

from avoidd.config.app import AppConfig
from avoidd.config.base import Strict
from avoidd.config.reference import attribute_docs, render_reference, rows, type_text

REFERENCE = Path(__file__).resolve().parents[1] / "docs" / "config-reference.md"


def _models(root: type[BaseModel]) -> list[type[BaseModel]]:
    """Every config model reachable from ``root`` (through fields, lists and unions)."""
    from avoidd.config.reference import _sections

    found: list[type[BaseModel]] = []
    pending = [root]
    while pending:
        model = pending.pop()
        if model in found:
            continue
        found.append(model)
        for field in model.model_fields.values():
            pending += [child for _, child in _sections(field.annotation)]
    return found


def test_reference_file_matches_the_models() -> None:
    assert REFERENCE.read_text(encoding="utf-8") == render_reference(), (
        "docs/config-reference.md differs from the config models: run `make config-reference`"
    )


def test_every_key_is_documented() -> None:
    undocumented = [
        f"{model.__name__}.{row.key}"
        for model in _models(AppConfig)
        for row in rows(model)
        if not row.meaning
    ]
    assert undocumented == [], (
        "describe these in their model's Attributes: docstring section: " + ", ".join(undocumented)
    )


def test_reference_carries_types_defaults_and_bounds() -> None:
    text = render_reference()
    assert "## `mavlink`" in text
    assert "| heartbeat_hz | number | 1.0 | >= 0.5, <= 10.0 |" in text
    assert "## `heads[].source (kind: v4l2)`" in text
    assert "| source | kind: synthetic \\| files \\| v4l2 \\| sim | required |" in text
    # The bounds of each item of a tuple reach its row.
    assert "| position_m | [number, number, number] | [0.0, 0.0, 0.0] | each >= -5.0, <= 5.0 |" in (
        text
    )


class _Sample(Strict):
    """A sample section.

    Attributes:
        speed_m_s: How fast, over two
            lines.
        mode: Which mode.
    """

    speed_m_s: float = Field(2.0, gt=0.0, le=10.0)
    mode: str = "a"
    undocumented: int = 3


def test_rows_read_the_attributes_section() -> None:
    assert attribute_docs(_Sample) == {
        "speed_m_s": "How fast, over two lines.",
        "mode": "Which mode.",
    }
    by_key = {row.key: row for row in rows(_Sample)}
    assert by_key["speed_m_s"].range_text == "> 0.0, <= 10.0"
    assert by_key["speed_m_s"].default_text == "2.0"
    assert by_key["undocumented"].meaning == ""
    assert type_text(list[int] | None) == "list of integer | null"
