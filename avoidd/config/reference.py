"""The configuration reference (``docs/config-reference.md``), generated from the config models.

Every key of the configuration file gets a row: its path, type, default, allowed range and the
meaning written in its model's ``Attributes:`` docstring. The reference is generated, never
edited by hand, so it cannot drift from what ``load_config`` accepts; a test compares the file
with :func:`render_reference` and ``make config-reference`` rewrites it::

    python -m avoidd.config.reference > docs/config-reference.md
"""

from __future__ import annotations

import inspect
import re
import sys
import types
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, Union, get_args, get_origin

import annotated_types
from pydantic import BaseModel
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

from avoidd.config.app import AppConfig

_BOUNDS = (
    (annotated_types.Ge, ">="),
    (annotated_types.Gt, ">"),
    (annotated_types.Le, "<="),
    (annotated_types.Lt, "<"),
)


@dataclass(frozen=True)
class Row:
    """One key of the reference.

    Attributes:
        key: The key's name in its section (``[]`` marks a list of sections).
        type_text: Its type, as a user writes it.
        default_text: Its default, or ``required``.
        range_text: Its bounds, or empty.
        meaning: Its description from the model's docstring, or empty.
    """

    key: str
    type_text: str
    default_text: str
    range_text: str
    meaning: str


def attribute_docs(model: type[BaseModel]) -> dict[str, str]:
    """The ``Attributes:`` section of a model's Google-style docstring, by attribute name.

    Args:
        model: A config model.

    Returns:
        Each documented attribute's description, joined into one line.
    """
    doc = inspect.getdoc(model) or ""
    found: dict[str, str] = {}
    in_section = False
    current: str | None = None
    for line in doc.splitlines():
        if line.strip() == "Attributes:":
            in_section = True
            continue
        if not in_section:
            continue
        if line and not line.startswith(" "):
            break  # the next section
        match = re.match(r"^    (\w+)(?: \([^)]*\))?: ?(.*)$", line)
        if match:
            current = match.group(1)
            found[current] = match.group(2).strip()
        elif current is not None and line.strip():
            found[current] = f"{found[current]} {line.strip()}".strip()
    return found


def _strip_annotated(annotation: Any) -> tuple[Any, list[Any]]:
    metadata: list[Any] = []
    while get_origin(annotation) is Annotated:
        args = get_args(annotation)
        annotation, metadata = args[0], [*metadata, *args[1:]]
    return annotation, metadata


def _is_model(annotation: Any) -> bool:
    return isinstance(annotation, type) and issubclass(annotation, BaseModel)


def type_text(annotation: Any) -> str:
    """A type as a user writes it in YAML terms (``number``, ``list of ...``).

    Args:
        annotation: A field's annotation.

    Returns:
        Its readable name.
    """
    annotation, _ = _strip_annotated(annotation)
    origin = get_origin(annotation)
    if origin is Literal:
        return " | ".join(repr(value) for value in get_args(annotation))
    if origin in (Union, types.UnionType):
        args = get_args(annotation)
        tags = [_variant_tag(_strip_annotated(arg)[0]) for arg in args]
        if len(args) > 1 and all(tags):
            return f"{tags[0].split(':')[0]}: " + " | ".join(tag.split(": ")[1] for tag in tags)
        return " | ".join(type_text(arg) for arg in args)
    if origin is list:
        item = type_text(get_args(annotation)[0])
        return "list of sections" if item == "section" else f"list of {item}"
    if origin is tuple:
        return "[" + ", ".join(type_text(arg) for arg in get_args(annotation)) + "]"
    if origin is dict:
        key, value = get_args(annotation)
        return f"map of {type_text(key)} to {type_text(value)}"
    if annotation is type(None):
        return "null"
    if _is_model(annotation):
        return "section"
    names = {bool: "true/false", int: "integer", float: "number", str: "text", Path: "path"}
    return names.get(annotation, getattr(annotation, "__name__", str(annotation)))


def _bounds(metadata: list[Any]) -> str:
    parts = []
    for item in metadata:
        if isinstance(item, FieldInfo):  # Field(...) inside Annotated[...]
            parts += [part for part in [_bounds(item.metadata)] if part]
            continue
        for kind, symbol in _BOUNDS:
            if isinstance(item, kind):
                parts.append(f"{symbol} {getattr(item, kind.__name__.lower())}")
        if isinstance(item, annotated_types.MinLen):
            parts.append(f"at least {item.min_length} items")
        if isinstance(item, annotated_types.MaxLen):
            parts.append(f"at most {item.max_length} items")
    return ", ".join(parts)


def _range_text(field: FieldInfo) -> str:
    annotation, inner = _strip_annotated(field.annotation)
    texts = [_bounds([*field.metadata, *inner])]
    # The bounds of each item of a tuple or list (position_m: three numbers within +-5 m).
    items = {_bounds(_strip_annotated(arg)[1]) for arg in get_args(annotation)}
    items.discard("")
    if len(items) == 1:
        texts.append(f"each {items.pop()}")
    return "; ".join(text for text in texts if text)


def _default_text(field: FieldInfo) -> str:
    if field.is_required():
        return "required"
    if field.default_factory is not None:
        return "(see section)"
    value = field.default
    if value is PydanticUndefined:
        return "required"
    if isinstance(value, BaseModel):
        return "(see section)"
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, tuple | list):
        return "[" + ", ".join(str(item) for item in value) + "]"
    return str(value)


def _sections(annotation: Any) -> list[tuple[str, type[BaseModel]]]:
    """The models a field holds, with the suffix of their path (``[]``, ``(kind: files)``)."""
    annotation, _ = _strip_annotated(annotation)
    origin = get_origin(annotation)
    if _is_model(annotation):
        return [("", annotation)]
    if origin is list:
        return [(f"[]{suffix}", model) for suffix, model in _sections(get_args(annotation)[0])]
    if origin in (Union, types.UnionType):
        variants = [arg for arg in get_args(annotation) if _is_model(_strip_annotated(arg)[0])]
        found = []
        for arg in variants:
            model = _strip_annotated(arg)[0]
            tag = _variant_tag(model)
            found.append((f" ({tag})" if tag and len(variants) > 1 else "", model))
        return found
    return []


def _variant_tag(model: Any) -> str:
    if not _is_model(model):
        return ""
    for name in ("kind", "shape"):
        field = model.model_fields.get(name)
        if field is not None:
            annotation, _ = _strip_annotated(field.annotation)
            if get_origin(annotation) is Literal:
                return f"{name}: {get_args(annotation)[0]}"
    return ""


def rows(model: type[BaseModel]) -> list[Row]:
    """One row per field of a model, in declaration order.

    Args:
        model: A config model.

    Returns:
        The rows of its table.
    """
    docs = attribute_docs(model)
    return [
        Row(
            key=name,
            type_text=type_text(field.annotation),
            default_text=_default_text(field),
            range_text=_range_text(field),
            meaning=docs.get(name) or field.description or _implied_meaning(name, field),
        )
        for name, field in model.model_fields.items()
    ]


def _implied_meaning(name: str, field: FieldInfo) -> str:
    """What an undocumented field means when its type says it: a form's tag or a section."""
    annotation, _ = _strip_annotated(field.annotation)
    if name in ("kind", "shape") and get_origin(annotation) is Literal:
        return f"Selects this form of the section ({name}: {get_args(annotation)[0]})."
    sections = _sections(field.annotation)
    if len(sections) == 1:
        return _summary(sections[0][1])
    if sections:
        return "One of the forms below, chosen by its " + _variant_tag(sections[0][1]).split(":")[0]
    return ""


def _summary(model: type[BaseModel]) -> str:
    return (inspect.getdoc(model) or "").split("\n\n")[0].replace("\n", " ")


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def render_reference(root: type[BaseModel] = AppConfig) -> str:
    """The whole reference in Markdown: a table per section, sections in file order.

    Args:
        root: The model of the file's top level.

    Returns:
        The Markdown text (what ``docs/config-reference.md`` holds).
    """
    lines = [
        "# Configuration reference",
        "",
        "Generated from the config models by `make config-reference` (`python -m",
        "avoidd.config.reference`); do not edit by hand, a test fails when this file and the",
        "models differ. The guide with a full example is [configuration.md](configuration.md).",
        "Every section refuses unknown keys, NaN and infinity, and converts no value",
        '(`"7"` is not 7). `[]` marks a list of sections; `(kind: x)` one form of a section',
        "chosen by its `kind`.",
    ]
    pending: list[tuple[str, type[BaseModel]]] = [("", root)]
    while pending:
        path, model = pending.pop(0)
        title = path or "top level"
        lines += ["", f"## `{title}`" if path else f"## {title}", "", _summary(model), ""]
        lines += ["| key | type | default | range | meaning |", "|---|---|---|---|---|"]
        children = []
        for row in rows(model):
            cells = (row.key, row.type_text, row.default_text, row.range_text, row.meaning)
            lines.append("| " + " | ".join(_cell(cell) for cell in cells) + " |")
            field = model.model_fields[row.key]
            for suffix, child in _sections(field.annotation):
                children.append((f"{path}.{row.key}{suffix}".lstrip("."), child))
        pending = children + pending
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.stdout.write(render_reference())
