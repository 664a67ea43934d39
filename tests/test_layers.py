"""The package's layers: nothing imports from a layer above its own (checked on the source)."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "avoidd"

# Top to bottom. A module may import from its own layer and from any layer below it.
LAYERS: list[tuple[str, tuple[str, ...]]] = [
    ("cli", ("avoidd.cli", "avoidd.__main__")),
    ("commands", ("avoidd.commands",)),
    (
        "runtimes",
        (
            "avoidd.daemon",
            "avoidd.debugview",
            "avoidd.replay",
            "avoidd.replay_plot",
            "avoidd.record",
            "avoidd.sim",
            "avoidd.evaluation",
            "avoidd.bench",
        ),
    ),
    ("services", ("avoidd.pipeline", "avoidd.planner", "avoidd.loading")),
    (
        "domain",
        (
            "avoidd.perception",
            "avoidd.vision",
            "avoidd.sources",
            "avoidd.mavlink",
            "avoidd.calibrate",
        ),
    ),
    (
        "foundation",
        (
            "avoidd.config",
            "avoidd.types",
            "avoidd.errors",
            "avoidd.yamlfile",
            "avoidd.aio",
            "avoidd.slot",
            "avoidd.looplag",
            "avoidd.logrepeat",
            "avoidd.progress",
            "avoidd.fileread",
            "avoidd.foreignlog",
        ),
    ),
]


def layer_of(module: str) -> int | None:
    """Index of a module's layer (0 = top), or None for a module no layer names."""
    for index, (_, prefixes) in enumerate(LAYERS):
        if any(module == p or module.startswith(p + ".") for p in prefixes):
            return index
    return None


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_module(name: str) -> bool:
    path = PACKAGE.parent.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def imports_of(path: Path, module: str) -> list[tuple[int, str]]:
    """Every avoidd module a file imports (also inside functions and TYPE_CHECKING blocks)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            # "from avoidd.x import y": x is imported, and y too when it is a module
            found.append((node.lineno, base))
            found += [
                (node.lineno, f"{base}.{alias.name}")
                for alias in node.names
                if _is_module(f"{base}.{alias.name}")
            ]
    return [(line, name) for line, name in found if name.split(".")[0] == "avoidd"]


def test_every_module_has_a_layer() -> None:
    unplaced = [
        module_name(path)
        for path in sorted(PACKAGE.rglob("*.py"))
        if module_name(path) != "avoidd" and layer_of(module_name(path)) is None
    ]
    assert not unplaced, f"add these modules to a layer in {__file__}: {unplaced}"


def test_no_import_runs_upward() -> None:
    upward = []
    for path in sorted(PACKAGE.rglob("*.py")):
        module = module_name(path)
        own = layer_of(module)
        if own is None:
            continue
        for line, imported in imports_of(path, module):
            target = layer_of(imported)
            if target is not None and target < own:
                upward.append(
                    f"{path.relative_to(PACKAGE.parent)}:{line}: {module} "
                    f"({LAYERS[own][0]}) imports {imported} ({LAYERS[target][0]})"
                )
    assert not upward, "\n".join(upward)


def test_the_checker_sees_an_upward_import(tmp_path: Path) -> None:
    # The check itself must be able to fail: a domain module importing the daemon is caught.
    fake = tmp_path / "avoidd" / "vision" / "oops.py"
    fake.parent.mkdir(parents=True)
    fake.write_text("def f():\n    from avoidd.daemon import Daemon\n    return Daemon\n")
    found = imports_of(fake, "avoidd.vision.oops")
    assert (2, "avoidd.daemon") in found
    assert layer_of("avoidd.daemon") is not None
    assert layer_of("avoidd.daemon") < layer_of("avoidd.vision.oops")  # type: ignore[operator]
