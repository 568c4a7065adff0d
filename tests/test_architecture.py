"""The layers of docs/architecture.md hold: every import of the package points to its own package or a lower
layer, never up and never sideways."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from conftest import PROJECT_ROOT

PACKAGE = PROJECT_ROOT / "python" / "hippo_nav"

LAYERS = [
    {"_core"},
    {"_defaults", "geometry", "io", "workers"},
    {"plugs"},
    {"datasets", "engine", "map", "memory", "metrics", "recording", "theory"},
    {"vo", "view_cells", "closure", "synthetic", "openfield"},
    {"system"},
    {"pipeline"},
    {"viewer", "sweep"},
    {"report"},
    {"cli", "__init__"},
]
"""docs/architecture.md, "Layers and the import rule": lowest first."""


def _part(module: str) -> str:
    """The top-level part of `hippo_nav.<part>…` (a package or a module)."""
    return module.split(".")[1] if module.count(".") else "__init__"


def _layer(part: str) -> int:
    for index, parts in enumerate(LAYERS):
        if part in parts:
            return index
    raise AssertionError(f"hippo_nav.{part} is in no layer of docs/architecture.md; add it to one")


def _from_root(name: str) -> str:
    is_module = (PACKAGE / name).is_dir() or (PACKAGE / f"{name}.py").is_file() or name == "_core"
    return f"hippo_nav.{name}" if is_module else "hippo_nav"


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every hippo_nav import in a file, at any depth (functions, TYPE_CHECKING)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if node.module == "hippo_nav":  # a submodule, or a name the package root re-exports
                found += [(node.lineno, _from_root(alias.name)) for alias in node.names]
            elif node.module.startswith("hippo_nav."):
                found.append((node.lineno, node.module))
        elif isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names if a.name.startswith("hippo_nav.")]
    return found


def _modules() -> list[Path]:
    return sorted(p for p in PACKAGE.rglob("*.py"))


def test_every_part_of_the_package_is_in_a_layer():
    parts = {p.relative_to(PACKAGE).parts[0].removesuffix(".py") for p in _modules()} | {"_core"}
    for part in parts:
        _layer(part)


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_imports_point_down_the_layers(path: Path):
    own = path.relative_to(PACKAGE).parts[0].removesuffix(".py")
    for line, module in _imports(path):
        target = _part(module)
        if target == own:
            continue
        assert _layer(target) < _layer(own), (
            f"{path.relative_to(PROJECT_ROOT)}:{line} imports {module}: hippo_nav.{own} (layer {_layer(own)}) "
            f"may import only from lower layers (hippo_nav.{target} is layer {_layer(target)})"
        )


def test_the_rule_catches_an_upward_import(tmp_path: Path):
    """The check itself: an engine module that imported the pipeline would be caught."""
    bad = tmp_path / "engine.py"
    bad.write_text("def f():\n    from hippo_nav.pipeline import run\n    return run\n")
    ((line, module),) = _imports(bad)
    assert (line, module) == (2, "hippo_nav.pipeline") and _layer(_part(module)) > _layer("engine")


def test_the_system_sits_below_its_runner_and_its_config_below_the_plug_board():
    """The per-frame system (`hippo_nav.system`) may not import the runner (`hippo_nav.pipeline`), nor anything
    above it; inside the system, the config derives its sections from the parts' own registries and never
    imports the plug board that builds the parts from it (no config ↔ parts circle)."""
    assert _layer("system") < _layer("pipeline") < _layer("cli")
    for path in (PACKAGE / "system").glob("*.py"):
        targets = {_part(module) for _, module in _imports(path)}
        assert "pipeline" not in targets, path
    config_imports = {module for _, module in _imports(PACKAGE / "system" / "config.py")}
    assert "hippo_nav.system.parts" not in config_imports and "hippo_nav.system" not in config_imports
