"""docs/architecture.md stays a map of the code: it names every module.

A module ``spikenerf/PKG/NAME.py`` counts as named when the page mentions ``NAME.py`` (or ``PKG/NAME``); a
module of a deeper package (``scenes/blender/…``) when the page names its folder (``blender/``).
``__init__.py`` and ``__main__.py`` need no entry.
"""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "spikenerf"


def unnamed_modules(page: str, package: Path) -> list[str]:
    """The modules under ``package`` (paths relative to it) that ``page`` does not name."""
    missing = []
    for path in sorted(package.rglob("*.py")):
        rel = path.relative_to(package)
        if rel.name in {"__init__.py", "__main__.py"}:
            continue
        if len(rel.parts) > 2:  # a module of a sub-package: its folder's entry covers it
            named = f"{rel.parts[-2]}/" in page
        else:
            named = rel.name in page or rel.with_suffix("").as_posix() in page
        if not named:
            missing.append(rel.as_posix())
    return missing


def test_the_architecture_page_names_every_module() -> None:
    page = (ROOT / "docs" / "architecture.md").read_text()
    missing = unnamed_modules(page, PACKAGE)
    assert not missing, "docs/architecture.md does not name (add a line for each):\n" + "\n".join(missing)


def test_the_module_check_sees_an_unnamed_one(tmp_path: Path) -> None:
    for rel in [
        "core/__init__.py",
        "core/atomic.py",
        "core/newthing.py",
        "scenes/blender/x.py",
        "__main__.py",
    ]:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("")
    page = "`core/`: `atomic.py` writes files; `blender/`: the backend."
    assert unnamed_modules(page, tmp_path) == ["core/newthing.py"]
    assert unnamed_modules(page.replace("`blender/`", "Blender"), tmp_path) == [
        "core/newthing.py",
        "scenes/blender/x.py",
    ]
