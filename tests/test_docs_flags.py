"""The flags and keys the user pages tell users to type exist.

- every ``--flag`` of a ``spikenerf COMMAND …`` line (in code blocks and prose, continuation lines joined)
  and of an inline `` `COMMAND --flag …` `` span is an option of that command or of ``spikenerf`` itself;
- every ``--flag`` of a ``python -m benchmarks.… --flag`` line is declared (as a string literal) in that
  script or in a ``benchmarks`` module it imports;
- every ``--field-option KEY=`` names a key of some field's config, and every ``--set PATH=`` a field of
  ``TrainConfig`` (through its nested configs; ``field_config.KEY`` a field option).

The user pages are README.md and docs/*.md; docs/cli.md is generated from ``--help`` and CHANGELOG.md keeps
renamed options on purpose.
"""

from __future__ import annotations

import dataclasses
import re
import typing
from pathlib import Path

import click

from spikenerf.cli import SUBCOMMANDS, cli
from spikenerf.fields.registry import FIELD_REGISTRY
from spikenerf.train import TrainConfig

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted(p for p in (ROOT / "docs").glob("*.md") if p.name != "cli.md")]
_SUB = "|".join(sorted(map(re.escape, SUBCOMMANDS), key=len, reverse=True))
#: ``spikenerf`` or an opening backtick, the group's own options, a subcommand, then its arguments up to the
#: end of the command (a backtick, pipe, ``;``, comment, closing parenthesis or line end)
_COMMAND = re.compile(rf"(?:spikenerf|`)((?:\s+--[\w-]+(?:\s+\d+)?)*)\s*\b({_SUB})\b(?![-\w])([^`|;#\n)]*)")


def _options(command: click.Command) -> set[str]:
    return {o for p in command.params for o in [*p.opts, *p.secondary_opts] if o.startswith("--")}


def _command_options() -> tuple[set[str], dict[str, set[str]]]:
    """The group's long options and each subcommand's."""
    with click.Context(cli, info_name="spikenerf") as ctx:
        group = _options(cli) | {"--help", "--version"}
        return group, {name: _options(cli.get_command(ctx, name)) | {"--help"} for name in SUBCOMMANDS}


def unknown_flags(text: str, group: set[str], commands: dict[str, set[str]]) -> list[str]:
    """``"line N: COMMAND --flag"`` for each flag of a command in ``text`` that the command lacks."""
    joined = text.replace("\\\n", "  ")  # shell continuation lines; offsets and line numbers kept
    found = []
    for m in _COMMAND.finditer(joined):
        name = m.group(2)
        for flag in re.findall(r"(?<![\w-])(--[a-z][\w-]*)", m.group(3)):
            if flag not in commands[name] and flag not in group:
                found.append(f"line {text.count(chr(10), 0, m.start()) + 1}: {name} {flag}")
    return found


_SCRIPT = re.compile(r"-m\s+(benchmarks(?:\.\w+)+)([^`|;#\n)]*)")


def _declared_flags(module: str, seen: set[str] | None = None) -> set[str]:
    """The ``--flag`` string literals of a benchmarks module and of the benchmarks modules it imports."""
    seen = set() if seen is None else seen
    path = ROOT / (module.replace(".", "/") + ".py")
    if module in seen or not path.exists():
        return set()
    seen.add(module)
    source = path.read_text()
    flags = set(re.findall(r"[\"'](--[a-z][\w-]*)[\"']", source))
    for base, names in re.findall(r"^from (benchmarks(?:\.\w+)*) import ([\w, ]+)", source, re.MULTILINE):
        for sub in [base, *(f"{base}.{n.strip()}" for n in names.split(","))]:
            flags |= _declared_flags(sub, seen)
    return flags


def unknown_script_flags(text: str) -> list[str]:
    """``"line N: MODULE --flag"`` for each flag of a ``python -m benchmarks.…`` command that the script
    does not declare (and ``MODULE (no such script)`` for a missing one)."""
    found = []
    for m in _SCRIPT.finditer(text.replace("\\\n", "  ")):
        line, module = text.count("\n", 0, m.start()) + 1, m.group(1)
        if not (ROOT / (module.replace(".", "/") + ".py")).exists():
            found.append(f"line {line}: {module} (no such script)")
            continue
        declared = _declared_flags(module)
        for flag in re.findall(r"(?<![\w-])(--[a-z][\w-]*)", m.group(2)):
            if flag not in declared | {"--help"}:
                found.append(f"line {line}: {module} {flag}")
    return found


def _field_keys() -> set[str]:
    return {f.name for entry in FIELD_REGISTRY.values() for f in dataclasses.fields(entry.config)}


def _is_config_path(cls: type, path: str, field_keys: set[str]) -> bool:
    """Whether ``a.b.c`` names a field of the dataclass ``cls`` through its nested dataclasses."""
    parts = path.split(".")
    for i, part in enumerate(parts):
        if not dataclasses.is_dataclass(cls) or part not in {f.name for f in dataclasses.fields(cls)}:
            return False
        if part == "field_config":
            return i + 1 == len(parts) - 1 and parts[i + 1] in field_keys
        cls = typing.get_type_hints(cls)[part]
    return True


def unknown_keys(text: str) -> list[str]:
    """``--field-option KEY`` and ``--set PATH`` examples in ``text`` whose key does not exist."""
    keys = _field_keys()
    bad = [f"--field-option {k}" for k in re.findall(r"--field-option[ =]([a-z_]+)=", text) if k not in keys]
    paths = re.findall(r"--set[ =]([a-z_]+(?:\.[a-z_]+)*)=", text)
    return bad + [f"--set {p}" for p in paths if not _is_config_path(TrainConfig, p, keys)]


def test_every_documented_flag_exists() -> None:
    group, commands = _command_options()
    stale = [
        f"{p.relative_to(ROOT)} {hit}" for p in PAGES for hit in unknown_flags(p.read_text(), group, commands)
    ]
    assert not stale, "flags the commands lack (see docs/cli.md):\n" + "\n".join(stale)


def test_the_flag_check_reads_commands_in_code_and_prose() -> None:
    group, commands = _command_options()
    text = (
        "```bash\nspikenerf --threads 1 train ds --iters 5 \\\n    --no-such-flag 3 --out run\n```\n"
        "Pass `eval --also-not-real` or `render RUN --orbit-frames 8`; `spikenerf info --quiet`\n"
        "(`--bogus` alone is no command's).\n"
    )
    assert unknown_flags(text, group, commands) == [
        "line 2: train --no-such-flag",
        "line 5: eval --also-not-real",
    ]
    assert len(_COMMAND.findall((ROOT / "docs" / "getting-started.md").read_text())) > 10


def test_every_documented_benchmark_flag_exists() -> None:
    stale = [f"{p.relative_to(ROOT)} {hit}" for p in PAGES for hit in unknown_script_flags(p.read_text())]
    assert not stale, "flags the benchmark scripts lack (see their --help):\n" + "\n".join(stale)


def test_the_script_check_follows_imports_and_sees_a_missing_flag() -> None:
    assert "--threads" in _declared_flags("benchmarks.tools.bench_march")  # from benchmarks._table
    text = (
        "python -m benchmarks.tools.bench_march --rays 9 --no-such 1\n"
        "`python -m benchmarks.tools.not_a_script --x`\n"
    )
    assert unknown_script_flags(text) == [
        "line 1: benchmarks.tools.bench_march --no-such",
        "line 2: benchmarks.tools.not_a_script (no such script)",
    ]


def test_every_documented_config_key_exists() -> None:
    stale = [f"{p.relative_to(ROOT)} {hit}" for p in PAGES for hit in unknown_keys(p.read_text())]
    assert not stale, "keys no config has (docs/cli.md lists the field options):\n" + "\n".join(stale)


def test_the_key_check_sees_a_missing_key() -> None:
    text = (
        "--field-option lookup=gather --field-option no_such_key=1 --set integral.prior=0.1 "
        "--set integral.nope=1 --set field_config.tv_app=0 --set field_config.nope=2 --set batch=8"
    )
    assert unknown_keys(text) == [
        "--field-option no_such_key",
        "--set integral.nope",
        "--set field_config.nope",
    ]
