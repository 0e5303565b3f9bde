"""The layer rule: a package never imports a package above it (see docs/architecture.md)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "spikenerf"
ORDER = ["core", "camera", "scenes", "recon", "data", "fields", "render", "train", "eval", "pipelines", "cli"]


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("spikenerf."):
            found.add(node.module.split(".")[1])
        elif isinstance(node, ast.Import):
            found.update(a.name.split(".")[1] for a in node.names if a.name.startswith("spikenerf."))
    return found


@pytest.mark.parametrize("layer", ORDER)
def test_lower_layers_never_import_higher_ones(layer: str) -> None:
    rank = ORDER.index(layer)
    for path in sorted((SRC / layer).rglob("*.py")):
        for imported in _imports(path):
            assert imported in ORDER, f"{path}: imports unknown package spikenerf.{imported}"
            assert ORDER.index(imported) <= rank, f"{path}: {layer} imports higher layer {imported}"
