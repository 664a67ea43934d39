"""YAML files validated into pydantic models, with errors that name the file, line and key path."""

from __future__ import annotations

import difflib
import re
import types
import typing
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError
from pydantic_core import ErrorDetails

from avoidd.errors import ConfigError
from avoidd.fileread import UnreadableFile, read_bounded

M = TypeVar("M", bound=BaseModel)
LocPart = str | int


@dataclass(frozen=True)
class YamlDocument:
    """A parsed YAML file that remembers where every key came from.

    Attributes:
        path: The file the document was read from.
        data: The plain Python data (dicts, lists, scalars).
        root: The YAML node tree, for line numbers.
    """

    path: Path
    data: Any
    root: yaml.Node


MAX_FILE_BYTES = 1_000_000
"""A configuration, calibration, world or scenario file is a few kilobytes; more is refused
before parsing."""
MAX_DEPTH = 32
"""Nesting deeper than this is refused (no file of ours nests more than 6 levels)."""
MAX_NODES = 100_000
"""Values a document may hold with every alias written out: aliases are fine, an alias bomb
("billion laughs", a kilobyte that expands to 10**9 values) is not."""


class _BoundedLoader(yaml.SafeLoader):
    """PyYAML's safe loader with its nesting bounded and value errors tied to their line.

    It also reads ``1e-3`` as a number, as YAML 1.2 does (YAML 1.1 wants ``1.0e-3``, and the
    config refuses strings for numbers).
    """

    def __init__(self, text: str, path: Path) -> None:
        super().__init__(text)
        self._path = path
        self._depth = 0

    def compose_node(self, parent: yaml.Node | None, index: Any) -> yaml.Node | None:
        self._depth += 1
        try:
            if self._depth > MAX_DEPTH:
                line = self.peek_event().start_mark.line + 1  # type: ignore[no-untyped-call]
                raise ConfigError(
                    [
                        f"{self._path}:{line}: nested more than {MAX_DEPTH} levels deep; is it "
                        "the right file?"
                    ]
                )
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_object(self, node: yaml.Node, deep: bool = False) -> Any:
        try:
            return super().construct_object(node, deep)
        except (ValueError, OverflowError) as exc:
            # int() of a 5000-digit number, a 13th month in a date...
            line = node.start_mark.line + 1
            reason = str(exc).split(";")[0]
            raise ConfigError(
                [f"{self._path}:{line}: cannot read the value {_short(node)} ({reason}); fix it"]
            ) from None


_BoundedLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def _short(node: yaml.Node) -> str:
    text = repr(node.value) if isinstance(node, yaml.ScalarNode) else "here"
    return text if len(text) <= 40 else text[:37] + "..."


def _check_expansion(path: Path, root: yaml.Node) -> None:
    """Refuse a document that expands beyond ``MAX_NODES`` values, or refers to itself."""
    sizes: dict[int, int] = {}
    open_nodes: set[int] = set()

    def size(node: yaml.Node) -> int:
        key = id(node)
        if key in sizes:
            return sizes[key]
        if key in open_nodes:
            line = node.start_mark.line + 1
            raise ConfigError(
                [f"{path}:{line}: an alias refers to the node that contains it; remove the cycle"]
            )
        open_nodes.add(key)
        if isinstance(node, yaml.SequenceNode):
            children: list[yaml.Node] = list(node.value)
        elif isinstance(node, yaml.MappingNode):
            children = [part for pair in node.value for part in pair]
        else:
            children = []
        total = 1
        for child in children:
            total += size(child)
            if total > MAX_NODES:
                raise ConfigError(
                    [
                        f"{path}:{root.start_mark.line + 1}: the document expands to more than "
                        f"{MAX_NODES} values through its aliases (an alias bomb?); write it out "
                        "or use fewer aliases"
                    ]
                )
        open_nodes.discard(key)
        sizes[key] = total
        return total

    size(root)


_NOT_IN_YAML = re.compile(
    "[^\x09\x0a\x0d\x20-\x7e\x85\xa0-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]"
)
"""Characters YAML does not allow in a file (PyYAML's own test): control characters such as NUL,
BEL, ESC and DEL, and the non-characters U+FFFE and U+FFFF."""
_CONTROL_NAMES = {0x00: "NUL", 0x07: "BEL", 0x08: "BS", 0x1B: "ESC", 0x7F: "DEL"}


def _read_text(path: Path) -> str:
    """The file as text: a regular file, bounded in size, UTF-8, of characters YAML allows.

    Every refusal names the file (and line) and the remedy.
    """
    try:
        data = read_bounded(path, MAX_FILE_BYTES)
    except FileNotFoundError as exc:
        raise ConfigError([f"{path}: no such file; check the path"]) from exc
    except UnreadableFile as exc:
        hint = (
            "too large for a YAML file of avoidd; is it the right file?"
            if exc.reason.startswith("larger")
            else "give the path of a YAML file"
        )
        raise ConfigError([f"{path}: {exc.reason}; {hint}"]) from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise ConfigError(
            [f"{path}:{line}: byte 0x{data[exc.start]:02x} is not UTF-8; save the file as UTF-8"]
        ) from None
    bad = _NOT_IN_YAML.search(text)
    if bad is not None:
        code = ord(bad.group())
        name = _CONTROL_NAMES.get(code, "a control character" if code < 0xA0 else "a non-character")
        line = text.count("\n", 0, bad.start()) + 1
        raise ConfigError(
            [
                f"{path}:{line}: character U+{code:04X} ({name}) is not allowed in YAML; "
                "remove it (is it the right file?)"
            ]
        )
    return text


def load_yaml(path: Path, prepare: Callable[[str], str] | None = None) -> YamlDocument:
    """Read a YAML file, rejecting syntax errors, several documents and duplicate keys.

    Files over ``MAX_FILE_BYTES``, bytes that are not UTF-8, nesting deeper than
    ``MAX_DEPTH`` and documents whose aliases expand to more than ``MAX_NODES`` values are
    refused before anything is built from them.

    Args:
        path: The file to read.
        prepare: Rewrites the text before parsing, keeping its lines (another tool's header
            that YAML parsers reject, such as OpenCV's ``%YAML:1.0``).

    Returns:
        The document with its node tree.

    Raises:
        ConfigError: The file cannot be read or is not valid YAML.
    """
    text = _read_text(path)
    if prepare is not None:
        text = prepare(text)
    loader: _BoundedLoader | None = None
    try:
        loader = _BoundedLoader(text, path)
        root = loader.get_single_node()
        if root is None:
            raise ConfigError([f"{path}:1: the file is empty; it needs at least 'version: 1'"])
        _check_expansion(path, root)
        problems = _duplicate_keys(path, root)
        if problems:
            raise ConfigError(problems)
        data = loader.construct_document(root)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark is not None else 1
        what = exc.problem or str(exc)
        raise ConfigError(
            [f"{path}:{line}: YAML syntax error: {what}; check indentation and quoting"]
        ) from exc
    except yaml.YAMLError as exc:
        reason = " ".join(str(exc).split())
        raise ConfigError([f"{path}: YAML error: {reason}; fix the file"]) from None
    finally:
        if loader is not None:
            loader.dispose()
    return YamlDocument(path, data, root)


def validate_document(doc: YamlDocument, model: type[M], context: dict[str, Any]) -> M:
    """Validate a document into a model; every problem becomes one line of a ConfigError.

    Args:
        doc: The loaded document.
        model: The pydantic model of the whole file.
        context: Validation context handed to the model's validators.

    Returns:
        The validated model.

    Raises:
        ConfigError: One line per validation error, ``FILE:LINE: key.path: message (got value)``.
    """
    try:
        return model.model_validate(doc.data, context=context)
    except ValidationError as exc:
        names = _field_names(model)
        raise ConfigError(
            [_format_error(doc, err, names, model) for err in exc.errors(include_url=False)]
        ) from exc


def _duplicate_keys(path: Path, node: yaml.Node, where: list[LocPart] | None = None) -> list[str]:
    where = where or []
    problems: list[str] = []
    if isinstance(node, yaml.MappingNode):
        seen: set[str] = set()
        for key_node, value_node in node.value:
            key = str(key_node.value)
            if key in seen:
                line = key_node.start_mark.line + 1
                dotted = _format_path([*where, key])
                problems.append(f"{path}:{line}: {dotted}: duplicate key; keep only one of them")
            seen.add(key)
            problems.extend(_duplicate_keys(path, value_node, [*where, key]))
    elif isinstance(node, yaml.SequenceNode):
        for index, item in enumerate(node.value):
            problems.extend(_duplicate_keys(path, item, [*where, index]))
    return problems


def _mapping_child(node: yaml.Node, key: str) -> tuple[yaml.Node, yaml.Node] | None:
    if not isinstance(node, yaml.MappingNode):
        return None
    for key_node, value_node in node.value:
        if str(key_node.value) == key:
            return key_node, value_node
    return None


def _locate(root: yaml.Node, err: ErrorDetails) -> tuple[int, list[LocPart]]:
    """Line (1-based) and real key path of a pydantic error location.

    Parts that are not keys of the document are union tags that pydantic inserts (skipped), except
    a missing key, which is named in the path and reported on its parent's line.
    """
    loc = list(err["loc"])
    node = root
    line = root.start_mark.line + 1
    path: list[LocPart] = []
    for position, part in enumerate(loc):
        last = position == len(loc) - 1
        if isinstance(part, int) and isinstance(node, yaml.SequenceNode):
            if 0 <= part < len(node.value):
                node = node.value[part]
                line = node.start_mark.line + 1
                path.append(part)
            continue
        child = _mapping_child(node, str(part))
        if child is not None:
            key_node, node = child
            line = key_node.start_mark.line + 1
            path.append(part)
        elif last and err["type"] == "missing":
            path.append(part)
    if err["type"] in ("union_tag_invalid", "union_tag_not_found"):
        tag = str(err.get("ctx", {}).get("discriminator", "")).strip("'")
        child = _mapping_child(node, tag)
        if child is None:
            # A discriminator function (the matchers') names no key: they choose by ``kind``.
            tag = "kind"
            child = _mapping_child(node, tag)
        if child is not None:
            line = child[0].start_mark.line + 1
            path.append(tag)
    return line, path


def _format_path(path: list[LocPart]) -> str:
    text = ""
    for part in path:
        if isinstance(part, int):
            text += f"[{part}]"
        else:
            text += f".{part}" if text else part
    return text or "(top level)"


def _format_value(value: Any) -> str:
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _format_error(
    doc: YamlDocument, err: ErrorDetails, names: set[str], model: type[BaseModel]
) -> str:
    line, path = _locate(doc.root, err)
    message = err["msg"].removeprefix("Value error, ").removeprefix("Assertion failed, ")
    kind = err["type"]
    if kind == "missing":
        loc = err["loc"]
        if loc and isinstance(loc[-1], int):
            # A tuple given too few values: pydantic reports the first one missing.
            where = _format_path(path[:-1] if path and isinstance(path[-1], int) else path)
            return (
                f"{doc.path}:{line}: {where}: too few values (value {loc[-1] + 1} is missing); "
                f"give every one (got {_format_value(err.get('input'))})"
            )
        return f"{doc.path}:{line}: {_format_path(path)}: required key is missing; add it"
    if kind == "extra_forbidden":
        key = str(path[-1]) if path else ""
        here = _names_at(model, err["loc"][:-1]) or names
        close = difflib.get_close_matches(key, sorted(here), n=1, cutoff=0.6)
        if (key in names and key not in here) or close[:1] == [key]:
            # Spelt right, but a key of another section or source kind (a files source
            # given a synthetic camera's seed): suggesting itself would not help.
            hint = "a key of another section or kind, not of this one; remove it here"
        elif close:
            hint = f"did you mean '{close[0]}'?"
        else:
            hint = "remove it or check the spelling"
        return f"{doc.path}:{line}: {_format_path(path)}: unknown key; {hint}"
    if kind == "union_tag_invalid":
        ctx = err.get("ctx", {})
        expected = ctx.get("expected_tags", "")
        tag = ctx.get("tag", "")
        where = f"{doc.path}:{line}: {_format_path(path)}"
        return f"{where}: unknown kind '{tag}'; use one of {expected}"
    value = _format_value(err.get("input"))
    return f"{doc.path}:{line}: {_format_path(path)}: {message} (got {value})"


def _models_in(annotation: Any) -> list[type[BaseModel]]:
    """The models an annotation names, through unions, lists, mappings and ``Annotated``."""
    found: list[type[BaseModel]] = []
    pending = [annotation]
    while pending:
        item = pending.pop()
        if isinstance(item, type) and issubclass(item, BaseModel):
            found.append(item)
        elif typing.get_origin(item) is not None or isinstance(item, types.UnionType):
            pending.extend(typing.get_args(item))
    return found


def _keys(model: type[BaseModel]) -> dict[str, Any]:
    """A model's fields by the key a file gives them (the alias where there is one)."""
    return {info.alias or name: info for name, info in model.model_fields.items()}


def _tags(model: type[BaseModel]) -> set[Any]:
    """The values of a model's literal fields (``kind``, ``shape``: its tag under a union)."""
    return {
        value
        for info in model.model_fields.values()
        if typing.get_origin(info.annotation) is typing.Literal
        for value in typing.get_args(info.annotation)
    }


def _names_at(model: type[BaseModel], loc: tuple[int | str, ...]) -> set[str]:
    """The keys valid in the mapping at ``loc`` (every variant's, under a union).

    A part of ``loc`` that is no key (a list index, a mapping's key) keeps the models found
    so far; a union's tag keeps the variants it names.
    """
    models = [model]
    for part in loc:
        if not isinstance(part, str):
            continue
        holding = [_keys(m)[part] for m in models if part in _keys(m)]
        if holding:
            models = [found for info in holding for found in _models_in(info.annotation)]
            if not models:
                return set()  # a field that holds no model
            continue
        tagged = [m for m in models if part in _tags(m)]
        models = tagged or models
    return {key for m in models for key in _keys(m)}


def _field_names(model: type[BaseModel]) -> set[str]:
    """Every field name of a model and the models nested in it, for spelling suggestions."""
    names: set[str] = set()
    pending: list[Any] = [model]
    seen: set[Any] = set()
    while pending:
        item = pending.pop()
        if item in seen:
            continue
        seen.add(item)
        if isinstance(item, type) and issubclass(item, BaseModel):
            for name, info in item.model_fields.items():
                names.add(name)
                pending.append(info.annotation)
        else:
            origin = typing.get_origin(item)
            if origin is not None or isinstance(item, types.UnionType):
                pending.extend(typing.get_args(item))
    return names
