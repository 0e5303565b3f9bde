"""The layer rule: a package never imports a package above it (see docs/architecture.md)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from helpers import defined_names

SRC = Path(__file__).resolve().parents[1] / "src" / "spikenerf"
ORDER = [
    "core",
    "camera",
    "scenes",
    "recon",
    "data",
    "capture",
    "importing",
    "fields",
    "render",
    "train",
    "eval",
    "pipelines",
    "cli",
]


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


def _module_graph() -> dict[str, set[str]]:
    """spikenerf module → the spikenerf modules it imports, anywhere in the file: function bodies too, where
    a cycle would only be deferred, and ``if TYPE_CHECKING:`` blocks, where it would only be hidden."""
    modules = {
        ".".join(("spikenerf", *p.relative_to(SRC).with_suffix("").parts)).removesuffix(".__init__"): p
        for p in SRC.rglob("*.py")
    }
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        tree = ast.parse(path.read_text())
        edges: set[str] = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("spikenerf"):
                targets = [node.module, *(f"{node.module}.{a.name}" for a in node.names)]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                continue
            edges.update(t for t in targets if t in modules and t != name)
        graph[name] = edges
    return graph


def test_no_import_cycles_between_modules() -> None:
    graph = _module_graph()
    assert "spikenerf.pipelines.benchmark.cells" in graph["spikenerf.pipelines.report"]  # it sees imports
    state: dict[str, int] = {}  # 1 = on the current path, 2 = done

    def visit(name: str, path: list[str]) -> None:
        state[name] = 1
        for nxt in sorted(graph[name]):
            if state.get(nxt) == 1:
                cycle = [*path[path.index(nxt) :], nxt] if nxt in path else [name, nxt]
                pytest.fail(f"import cycle: {' → '.join(cycle)}")
            if nxt not in state:
                visit(nxt, [*path, nxt])
        state[name] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name, [name])


def test_one_psnr_implementation() -> None:
    """PSNR is computed in core/psnr.py only; train, eval and pipelines call it."""

    def calls_log10(path: Path) -> bool:
        return any(
            isinstance(n, ast.Call) and "log10" in ast.unparse(n.func)
            for n in ast.walk(ast.parse(path.read_text()))
        )

    users = sorted(p.relative_to(SRC).as_posix() for p in SRC.rglob("*.py") if calls_log10(p))
    assert users == ["core/psnr.py"], users


def test_a_command_never_imports_another_commands_module() -> None:
    """Shared CLI code lives in ``cli/types.py``, ``cli/options.py`` or ``cli/__init__.py``, not in a
    command's module (``reconstruct`` imported ``info``'s recording helper before). A command split by idea
    keeps its parts in ``cli/<command>_<part>.py`` (``train_options.py``), which only that command imports."""
    from spikenerf.cli import SUBCOMMANDS

    commands = {module.rsplit(".", 1)[1] for module, _ in SUBCOMMANDS.values()}
    shared = {"__init__", "types", "options", "reference"}
    owner = {name: name for name in commands}
    for stem in sorted({p.stem for p in (SRC / "cli").glob("*.py")} - commands - shared):
        owners = [name for name in commands if stem.startswith(f"{name}_")]
        assert len(owners) == 1, f"cli/{stem}.py is neither a command, a shared module nor one command's part"
        owner[stem] = owners[0]
    found = []
    for name in sorted(owner):
        for node in ast.walk(ast.parse((SRC / "cli" / f"{name}.py").read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("spikenerf.cli."):
                other = node.module.split(".")[2]
                if other in owner and owner[other] != owner[name]:
                    found.append(f"cli/{name}.py imports cli/{other}.py")
    assert not found, found
    assert {"train_options", "train_flags"} <= owner.keys() and owner["train_flags"] == "train"


def test_public_api_resolves_and_import_spikenerf_stays_light() -> None:
    import importlib
    import subprocess
    import sys

    from spikenerf.core.exports import PUBLIC_API

    for package in PUBLIC_API:
        module = importlib.import_module(package)
        assert module.__all__, package
        for name in (n for n in module.__all__ if n[0] != "_"):  # functions, classes, registries, choices
            value = getattr(module, name)
            assert callable(value) or (name.isupper() and isinstance(value, tuple | dict)), (package, name)
    code = "import spikenerf.render as r, spikenerf.fields as f; print(r.model.__name__, f.grid.__name__)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["spikenerf.render.model", "spikenerf.fields.grid"]  # submodules, as before lazy
    code = "import sys, spikenerf, spikenerf.camera; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


#: modules split by idea: the names that moved out live in sibling modules, and these no longer export them
SPLIT = (
    "camera/io", "camera/model", "camera/reconstruct", "capture/simulate", "data/dataset", "eval/video",
    "fields/grid", "fields/vm_kernel", "importing/alignment", "importing/importer", "importing/poses",
    "pipelines/report", "scenes/sequence", "train/config", "cli/train",
)  # fmt: skip


def _borrowed(path: Path, defined: dict[str, set[str]]) -> list[str]:
    """``from spikenerf.<split module> import NAME`` lines of ``path`` whose NAME that module only imports."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module in defined:
            found += [f"{node.module}.{a.name}" for a in node.names if a.name not in defined[node.module]]
    return found


def test_moved_names_are_imported_from_their_new_modules(tmp_path: Path) -> None:
    """No source, test or benchmark imports a name from a split module that only imports it itself (it
    works by accident, and breaks when that module stops using the name)."""
    root = SRC.parents[1]
    defined = {
        f"spikenerf.{m.replace('/', '.')}": defined_names((SRC / f"{m}.py").read_text(), top_level=True)
        for m in SPLIT
    }
    stale = {
        str(p.relative_to(root)): names
        for folder in ("src", "tests", "benchmarks")
        for p in sorted((root / folder).rglob("*.py"))
        if (names := _borrowed(p, defined))
    }
    assert stale == {}
    probe = tmp_path / "probe.py"  # (the check bites: a moved name; one defined where imported from)
    probe.write_text("from spikenerf.capture.simulate import SimulateOptions, simulate_dataset\n")
    assert _borrowed(probe, defined) == ["spikenerf.capture.simulate.SimulateOptions"]
