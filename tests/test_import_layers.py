"""Imports point down the pipeline: the CLI commands sit on top, training above rendering, and
the building blocks (data, model, losses) import neither. Checked on the source with ``ast``, so
lazy imports inside functions count too."""

from __future__ import annotations

import ast
from collections.abc import Callable
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "python" / "evsplat"

# Only the CLI and the commands themselves may import a command module.
COMMAND_IMPORTERS = ("evsplat.cli", "evsplat.commands")

# Layers below training: they must not import evsplat.train.
BELOW_TRAIN = (
    "evsplat.checkpoint",
    "evsplat.data",
    "evsplat.losses",
    "evsplat.model",
    "evsplat.projection",
    "evsplat.raster",
    "evsplat.render",
    "evsplat.run_state",
    "evsplat.scenes",
    "evsplat.video",
    "evsplat.viewer",
)

# Allowed upward imports, each with its reason; empty this list as the reasons go away.
ALLOWED: set[tuple[str, str]] = set()


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    """Every absolute module a file imports, at top level or inside functions
    (``from evsplat import x`` counts as ``evsplat.x``: x may be a subpackage)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module == "evsplat":
            found.update(f"evsplat.{alias.name}" for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module)
    return found


def _within(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def _upward_imports(importer: Callable[[str], bool], target: str) -> list[str]:
    """``module -> import`` for every module ``importer`` selects that imports ``target`` (or a
    module inside it), less the ALLOWED pairs."""
    graph = {_module_name(p): _imports(p) for p in sorted(PACKAGE.rglob("*.py"))}
    assert "evsplat.render" in graph, f"no package found at {PACKAGE}"  # else the test is vacuous
    return sorted(
        f"{module} -> {name}"
        for module, names in graph.items()
        if importer(module)
        for name in names
        if _within(name, target) and (module, name) not in ALLOWED
    )


def test_only_the_cli_imports_commands():
    def outside_the_cli(module: str) -> bool:
        return not any(_within(module, c) for c in COMMAND_IMPORTERS)

    assert _upward_imports(outside_the_cli, "evsplat.commands") == []


@pytest.mark.parametrize("layer", BELOW_TRAIN)
def test_layers_below_training_do_not_import_it(layer: str):
    assert _upward_imports(lambda module: _within(module, layer), "evsplat.train") == []
