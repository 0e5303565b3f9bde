"""The docs stay true for users.

- docs/cli.md matches the commands' --help, and documents every subcommand and every field option;
- every relative link in README.md, CHANGELOG.md and docs/ (lab notes included) resolves, to the file and to
  the heading its #anchor names, and so does every `docs/PAGE.md#anchor` written out as text;
- no user page (README.md, docs/*.md; not docs/lab/ or CHANGELOG.md) is over 400 lines, speaks of the
  lab's sessions or machine load ("stop 12", "the idle box", "load average 5") or links docs/lab/ on its
  first screen;
- docs/index.md lists every user page;
- a newcomer's path: the commands of docs/getting-started.md run, in order, in an empty folder, and print
  what the page shows; so does docs/reconstruction.md's recon-eval example; and the README's Python example
  runs.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import click
import pytest

from helpers import defined_names
from spikenerf.cli import cli
from spikenerf.cli.reference import cli_reference, field_options

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
USER_PAGES = [ROOT / "README.md", *sorted(DOCS.glob("*.md"))]
ALL_PAGES = [*USER_PAGES, ROOT / "CHANGELOG.md", *sorted((DOCS / "lab").glob("*.md"))]
MAX_LINES = 400
#: generated from --help (checked by test_cli_reference_is_current): it grows with every option
LENGTH_EXEMPT = {"cli.md"}
DIARY = re.compile(
    (
        r"\bstops? \d+"  # "stop 12", "stops 9–10"
        r"|\b(?:this|that|each|every|last|next|earlier|previous) stop\b"
        r"|\bidle (?:2-core )?box\b|\b(?:shared|loaded|overloaded|busy) (?:2-core )?box\b"
        r"|\bload average\b|\bload (?:of )?[≈~]?\s*\d"  # "load average 5", "load ≈ 10", "load 13–17"
    ).replace(" ", r"\s+"),  # also across a line break
    re.IGNORECASE,
)
#: a user page states what the toolkit does now: the history of builds and of the project's issues is
#: CHANGELOG.md's and the lab notes'
HISTORY = re.compile(
    r"\bearlier builds?\b|\bprevious release\b|\bgit archive\b|\bissue \d+\b".replace(" ", r"\s+"),
    re.IGNORECASE,
)
#: the getting-started commands run at this size in the test (the page shows the full command)
TINY = {"--iters 300": "--iters 20"}
RUN_MARK = "<!-- test_docs: run -->"


def _strip_code(text: str) -> str:
    """The page without fenced code blocks and inline code spans (links there are not links)."""
    text = re.sub(r"^```.*?^```[^\n]*$", "", text, flags=re.MULTILINE | re.DOTALL)
    return re.sub(r"`[^`\n]*`", "", text)


def _anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading.strip()).lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    """The anchors of a page's headings, with GitHub's -1, -2 suffixes for repeats."""
    seen: dict[str, int] = {}
    found = set()
    text = re.sub(r"^```.*?^```[^\n]*$", "", page.read_text(), flags=re.MULTILINE | re.DOTALL)
    for heading in re.findall(r"^#{1,6} +(.+?) *#*$", text, flags=re.MULTILINE):
        base = _anchor(heading)
        n = seen.get(base, 0)
        seen[base] = n + 1
        found.add(base if n == 0 else f"{base}-{n}")
    return found


def _links_in(text: str) -> list[str]:
    """The relative link targets of markdown text, outside code."""
    targets = re.findall(r"\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)", _strip_code(text))
    return [t for t in targets if not re.match(r"[a-z]+:", t)]


def _links(page: Path) -> list[str]:
    return _links_in(page.read_text())


def _plain_references(text: str) -> list[str]:
    """The ``docs/PAGE.md`` and ``docs/PAGE.md#anchor`` mentions written out as text, outside links (paths
    from the repository root: a reader follows them too)."""
    unlinked = re.sub(r"\]\([^)]*\)", "]", text)
    return re.findall(r"(?<![\w/.-])(docs/(?:[\w-]+/)*[\w-]+\.md(?:#[\w-]+)?)", unlinked)


def test_cli_reference_is_current() -> None:
    committed = (DOCS / "cli.md").read_text()
    assert committed == cli_reference(), "regenerate: python -m spikenerf.cli.reference > docs/cli.md"


def test_every_subcommand_is_in_the_cli_reference() -> None:
    page = (DOCS / "cli.md").read_text()
    with click.Context(cli, info_name="spikenerf") as ctx:
        commands = cli.list_commands(ctx)
    assert len(commands) > 5
    missing = [name for name in commands if f"\n## spikenerf {name}\n" not in page]
    assert not missing, f"docs/cli.md lacks {missing}: python -m spikenerf.cli.reference > docs/cli.md"


def test_every_field_option_has_a_row_with_its_default_and_meaning() -> None:
    """A config key added without an entry in its class's ``Attributes`` docstring shows up here."""
    import dataclasses

    from spikenerf.fields.registry import FIELD_REGISTRY

    page = field_options()
    for kind, entry in FIELD_REGISTRY.items():
        table = page.split(f"### `--field {kind}`", 1)[1].split("###", 1)[0]
        rows = {row.split(" | ")[0]: row.split(" | ") for row in table.splitlines() if row.startswith("| `")}
        keys = [k for head in rows for k in re.findall(r"`(\w+)`", head)]
        names = [f.name for f in dataclasses.fields(entry.config)]
        assert sorted(keys) == sorted(names), (kind, set(keys) ^ set(names))
        for head, cells in rows.items():
            assert len(cells) == 4 and len(cells[3]) > 12, f"{kind} {head}: no meaning in the docstring"
    assert "| `march` | `torch` | `torch`, `triton` | How the renderer places its samples" in page


def test_relative_links_and_anchors_resolve() -> None:
    broken = []
    for page in ALL_PAGES:
        for target in _links(page):
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            if not dest.exists():
                broken.append(f"{page.relative_to(ROOT)}: {target} (no such file)")
            elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
                broken.append(f"{page.relative_to(ROOT)}: {target} (no such heading)")
        for mention in _plain_references(page.read_text()):
            path, _, anchor = mention.partition("#")
            if not (ROOT / path).is_file():
                broken.append(f"{page.relative_to(ROOT)}: {mention} (no such file)")
            elif anchor and anchor not in _anchors(ROOT / path):
                broken.append(f"{page.relative_to(ROOT)}: {mention} (no such heading)")
    assert not broken, "broken links:\n" + "\n".join(broken)


def test_the_link_check_sees_a_broken_anchor() -> None:
    assert _anchor("The acceptance run, gray: six scenes, 200×200, 3 seeds") == (
        "the-acceptance-run-gray-six-scenes-200200-3-seeds"
    )
    assert _anchor("Test-time pose optimisation (`--test-pose-opt N`)") == (
        "test-time-pose-optimisation---test-pose-opt-n"
    )
    assert "where-we-differ-from-the-paper" in _anchors(DOCS / "method.md")
    assert _plain_references("see docs/metrics.md#psnr, [a](docs/b.md#c) or `docs/lab/x.md`") == [
        "docs/metrics.md#psnr", "docs/lab/x.md"
    ]  # fmt: skip
    assert "no-such-heading" not in _anchors(DOCS / "method.md")


def test_user_pages_are_short() -> None:
    long = [
        f"{page.relative_to(ROOT)}: {n} lines"
        for page in USER_PAGES
        if page.name not in LENGTH_EXEMPT and (n := len(page.read_text().splitlines())) > MAX_LINES
    ]
    hint = "move history to docs/lab/, details to a page of their own"
    assert not long, f"over {MAX_LINES} lines ({hint}):\n" + "\n".join(long)


def test_user_pages_keep_no_lab_diary() -> None:
    hits = [
        f"{page.relative_to(ROOT)}:{text.count(chr(10), 0, m.start()) + 1}: {m.group(0)!r}"
        for page in USER_PAGES
        for text in [page.read_text()]
        for m in DIARY.finditer(text)
    ]
    assert not hits, "session or load wording in a user page (it belongs in docs/lab/ or CHANGELOG.md):\n" + (
        "\n".join(hits)
    )


def test_the_diary_check_sees_diary_wording() -> None:
    for text in [
        "measured in stop 12",
        "stops 9–10",
        "on the idle box",
        "load\naverage 3–11",
        "load ≈ 10",
        "load 13–17",
    ]:
        assert DIARY.search(text), text
    for text in ["a scene box", "the spike loss stops", "loads the weights", "non-stop"]:
        assert not DIARY.search(text), text


def test_user_pages_keep_no_build_history() -> None:
    hits = [
        f"{page.relative_to(ROOT)}:{text.count(chr(10), 0, m.start()) + 1}: {m.group(0)!r}"
        for page in USER_PAGES
        if page.name not in LENGTH_EXEMPT  # cli.md is --help
        for text in [page.read_text()]
        for m in HISTORY.finditer(text)
    ]
    assert not hits, "history in a user page (say what the toolkit does now; history: CHANGELOG.md):\n" + (
        "\n".join(hits)
    )
    for text in ["In earlier builds, runs failed", "the previous\nrelease measured", "issue 27's targets"]:
        assert HISTORY.search(text), text
    for text in ["an issue with the lens", "the release notes", "a build folder"]:
        assert not HISTORY.search(text), text


def test_user_pages_do_not_open_with_the_lab_notes() -> None:
    """History lives in docs/lab/; a user page may point there, but not on its first screen."""
    early = [
        page.name
        for page in USER_PAGES
        if any("lab/" in target for target in _links_in("\n".join(page.read_text().splitlines()[:40])))
    ]
    assert not early, f"a link into docs/lab/ in the first 40 lines of {early}"


def test_the_index_lists_every_user_page() -> None:
    index = (DOCS / "index.md").read_text()
    missing = [p.name for p in DOCS.glob("*.md") if p.name != "index.md" and f"]({p.name}" not in index]
    assert not missing, f"docs/index.md does not list {missing}"


def _marked_blocks(page: str = "getting-started.md") -> list[tuple[list[str], list[str]]]:
    """(commands, the output shown after them) for each block of a docs page marked with RUN_MARK."""
    text = (DOCS / page).read_text()
    found = []
    for block in text.split(RUN_MARK)[1:]:
        code = block.split("```bash\n", 1)[1].split("```", 1)[0]
        commands = [c for c in code.replace("\\\n", " ").splitlines() if c.strip() and not c.startswith("#")]
        after = block.split("```", 2)[2].lstrip("\n")  # what follows the block: its shown output, if any
        shown = []
        if after.startswith("```text\n"):
            shown = after.removeprefix("```text\n").split("```", 1)[0].splitlines()
        found.append((commands, shown))
    return found


def _run_spikenerf(command: str, cwd: Path, env: dict[str, str]) -> str:
    """Run one ``spikenerf ...`` line of a page in ``cwd``; what it printed (it must exit 0)."""
    argv = shlex.split(command)
    assert argv[0] == "spikenerf", command
    done = subprocess.run(
        [sys.executable, "-m", "spikenerf", *argv[1:]],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, f"{command}\n{(done.stdout + done.stderr)[-2000:]}"
    return done.stdout + done.stderr


def test_getting_started_commands_run_in_order(tmp_path: Path) -> None:
    """A newcomer's path: simulate → reconstruct → train → eval → render, at a tiny size (TINY)."""
    blocks = _marked_blocks()
    assert [c.split()[1] for commands, _ in blocks for c in commands] == [
        "simulate", "info", "reconstruct", "train", "eval", "render", "info"
    ]  # fmt: skip
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    for commands, shown in blocks:
        printed = ""
        for command in commands:
            for full, tiny in TINY.items():
                command = command.replace(full, tiny)
            printed += _run_spikenerf(command, tmp_path, env)
        for line in shown:
            if line.strip() != "...":  # the shown output up to its first number must be printed
                stem = re.split(r"\d", line, maxsplit=1)[0]
                assert stem in printed, f"{commands}: the page shows {line!r}, they printed\n{printed}"
    assert (tmp_path / "orbs" / "spikes_gray.dat").is_file() and (tmp_path / "tfp.png").is_file()
    assert (tmp_path / "run" / "metrics.json").is_file()
    assert (tmp_path / "render" / "spikes_gray.dat").is_file()


def test_the_recon_eval_table_of_the_reconstruction_page(tmp_path: Path) -> None:
    """docs/reconstruction.md's `recon-eval` example runs as shown and prints its table: every row's method
    and window, and its scores within a rounding of the spikes (numpy versions differ in a few spikes)."""
    [(commands, shown)] = _marked_blocks("reconstruction.md")
    assert [c.split()[3] for c in commands] == ["simulate", "recon-eval"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    printed = "".join(_run_spikenerf(command, tmp_path, env) for command in commands)
    lines = [line.replace("not computed", "n/a").split() for line in printed.splitlines()]
    assert shown[0] in printed and shown[-1] in printed, printed  # the caption and the files written
    assert shown[1].split() in lines, printed  # the column heads
    rows = {cells[0]: cells for cells in lines if cells[:1] in (["tfp"], ["tfi"], ["tfstp"], ["learned"])}
    assert len(rows) == len(shown) - 3, printed
    for row in shown[2:-1]:
        want, got = row.split(), rows.get(row.split()[0], [])
        assert got[:2] == want[:2], (row, printed)  # method and window
        assert abs(float(got[2]) - float(want[2])) < 0.3 and abs(float(got[3]) - float(want[3])) < 0.01, got
        if got[4] != "n/a":  # LPIPS needs the lpips extra
            assert abs(float(got[4]) - float(want[4])) < 0.01, (row, got)
    assert all((tmp_path / "scores48" / name).is_file() for name in ("scores.json", "scores.csv"))


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


def test_the_python_api_page_runs_as_one_script(tmp_path: Path, monkeypatch, capsys) -> None:  # type: ignore[no-untyped-def]
    """Every ```python block of docs/python-api.md, in order, in one namespace (the page says so)."""
    text = (DOCS / "python-api.md").read_text()
    blocks = re.findall(r"^```python\n(.*?)^```", text, flags=re.MULTILINE | re.DOTALL)
    assert len(blocks) >= 7
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {"__name__": "python_api_page"}
    for i, block in enumerate(blocks):
        exec(compile(block, f"docs/python-api.md block {i + 1}", "exec"), namespace)
    out = capsys.readouterr().out.splitlines()
    errors = {name: float(out_line.split()[2]) for out_line in out for name in ("TFP", "TFI")
              if out_line.startswith(f"{name} error")}  # fmt: skip
    assert errors["TFP"] < 0.06 and errors["TFI"] < 0.2, out  # the reconstructions see the ramp
    assert "20 iterations so far" in out and any(line.startswith("40 iterations, test PSNR") for line in out)
    assert "(32, 32, 1) (100, 32, 32)" in out  # a view and a 100-step novel stream of the 32×32 scene
    rendered = namespace["rendered"]
    assert rendered.grad is not None and rendered.grad.abs().sum() > 0  # type: ignore[attr-defined]
    assert out[-1].startswith("ramp.dat: file size") and "23 high" in out[-1], out[-1]  # the Errors block
    assert (tmp_path / "run" / "metrics.json").is_file() and (tmp_path / "novel.dat").is_file()


@pytest.mark.parametrize("page", ["getting-started.md", "index.md", "results.md", "real-data.md"])
def test_the_readme_reaches_the_user_pages(page: str) -> None:
    assert f"](docs/{page}" in (ROOT / "README.md").read_text()


def _python_imports(text: str) -> list[tuple[str, list[str]]]:
    """(module, names) of each `from spikenerf… import …` or `import spikenerf…` in ```python blocks."""
    found = []
    for block in re.findall(r"^```python\n(.*?)^```", text, flags=re.MULTILINE | re.DOTALL):
        for module, names in re.findall(r"^\s*from (spikenerf[\w.]*) import ([\w, ]+)$", block, flags=re.M):
            found.append((module, [n.strip() for n in names.split(",") if n.strip()]))
        found += [(module, []) for module in re.findall(r"^\s*import (spikenerf[\w.]*)$", block, flags=re.M)]
    return found


def test_the_python_examples_import_what_exists() -> None:
    """Every spikenerf name a ```python block of the docs imports exists (the examples' first line runs)."""
    import importlib

    checked = 0
    for page in ALL_PAGES:
        for module, names in _python_imports(page.read_text()):
            loaded = importlib.import_module(module)
            missing = [n for n in names if not hasattr(loaded, n)]
            assert not missing, f"{page.relative_to(ROOT)}: {module} has no {', '.join(missing)}"
            checked += 1
    assert checked >= 3
    assert _python_imports("```python\nfrom spikenerf.x import a, b\n```\n") == [("spikenerf.x", ["a", "b"])]


def _misplaced(table: str) -> list[str]:
    """The ``name`` of each row of a "| what | how | where |" table that none of the row's ``*.py`` files
    (under src/spikenerf/) defines: a stale "where" after a module split."""
    import builtins

    wrong = []
    for row in table.splitlines():
        cells = row.split("|")
        if len(cells) < 5 or set(cells[3].strip()) <= {"-"}:
            continue
        files = re.findall(r"`([\w/]+\.py)`", cells[3])
        names = [n for n in re.findall(r"`([A-Za-z_]\w*)`", cells[2]) if not hasattr(builtins, n)]
        if not files or not names:
            continue
        sources = [ROOT / "src" / "spikenerf" / f for f in files]
        defined = set().union(*(defined_names(p.read_text()) for p in sources if p.is_file()))
        wrong += [f"{n} (not in {', '.join(files)})" for n in names if n not in defined]
    return wrong


def test_the_reliability_table_names_the_files_that_hold_each_mechanism() -> None:
    """docs/reliability.md's "Where" column holds the function or class its "How" column names (a module
    split moves names: the table must follow them)."""
    assert _misplaced((DOCS / "reliability.md").read_text()) == []
    assert _misplaced("| a | `load_dataset` | `train/run.py` |\n") == ["load_dataset (not in train/run.py)"]
