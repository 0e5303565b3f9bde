"""The docs stay true: docs/cli.md matches the commands' --help, and relative links resolve."""

from __future__ import annotations

import re
from pathlib import Path

from spikenerf.cli.reference import cli_reference

ROOT = Path(__file__).resolve().parents[1]


def test_cli_reference_is_current() -> None:
    committed = (ROOT / "docs" / "cli.md").read_text()
    assert committed == cli_reference(), "regenerate: python -m spikenerf.cli.reference > docs/cli.md"


def test_relative_links_in_docs_resolve() -> None:
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for target in re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", page.read_text()):
            assert (page.parent / target).exists(), f"{page.name}: broken link {target}"


def test_readme_python_example_runs(tmp_path: Path, monkeypatch, capsys) -> None:  # type: ignore[no-untyped-def]
    readme = (ROOT / "README.md").read_text()
    block = readme.split("## Python API", 1)[1].split("```python\n", 1)[1].split("```", 1)[0]
    monkeypatch.chdir(tmp_path)
    exec(compile(block, "README.md", "exec"), {"__name__": "readme_example"})
    out = capsys.readouterr().out
    assert "TFP error 0.0" in out and "10 iterations, test PSNR" in out
    assert (tmp_path / "orbs" / "transforms_tfp.json").is_file() and (
        tmp_path / "orbs_run" / "summary.json"
    ).is_file()
