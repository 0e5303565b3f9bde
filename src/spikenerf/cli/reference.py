"""Generate ``docs/cli.md`` from the commands' own ``--help`` (``python -m spikenerf.cli.reference``).

A test checks that the committed page matches, so the docs never drift from the code.
"""

from __future__ import annotations

import dataclasses
import inspect
import re
import typing
from typing import Any

import click

from spikenerf.cli import SUBCOMMANDS, cli
from spikenerf.fields.registry import FIELD_REGISTRY

INTRO = """# Command-line reference

Generated from the commands' `--help` by `python -m spikenerf.cli.reference > docs/cli.md`; a test keeps it
current. Every command reports bad input as one line on stderr (`spikenerf: error: FILE: problem`) and exits
with code 2, leaving nothing half-written.
"""


def cli_reference() -> str:
    """Markdown: the group's help, then each subcommand's help in a code block."""
    parts = [INTRO]
    with click.Context(cli, info_name="spikenerf", terminal_width=110, **cli.context_settings) as ctx:
        parts.append(f"## spikenerf\n\n```\n{cli.get_help(ctx)}\n```\n")
        for name in SUBCOMMANDS:
            command = cli.get_command(ctx, name)
            assert command is not None
            with click.Context(command, info_name=name, parent=ctx, terminal_width=110) as sub:
                parts.append(f"## spikenerf {name}\n\n```\n{command.get_help(sub)}\n```\n")
    return "\n".join([*parts, field_options()])


def field_options() -> str:
    """Markdown: a table per field kind of the ``--field-option`` keys, their defaults, values and meaning
    (the first sentence of the config class's ``Attributes`` entry; keys that share an entry share a row)."""
    parts = ["## Field options\n\n`train --field-option KEY=VALUE` (or `--set field_config.KEY=VALUE`) sets "
             "one entry of the field's config; a value of the wrong type or out of range is refused in one "
             "line. The grid's step values (`upsample_steps`, `occupancy_start`, `occupancy_every`), yours "
             "too, are written for its `iterations` and scaled to `train --iters` (5000 by default: the "
             "defaults below become 833, 1667, …), unless `iterations` is given as well.\n"]  # fmt: skip
    for kind, entry in FIELD_REGISTRY.items():
        cls = entry.config
        hints, bounds = typing.get_type_hints(cls), getattr(cls, "BOUNDS", {})
        defaults = {f.name: f.default for f in dataclasses.fields(cls)}
        groups = _attributes(cls, list(defaults))
        rows = ["| option | default | values | meaning |", "|---|---|---|---|"]
        done: set[str] = set()
        for name in defaults:
            if name in done:
                continue
            keys, meaning = next(((k, m) for k, m in groups if name in k), ([name], ""))
            done.update(keys)
            cells = [" / ".join(f"`{_yaml(defaults[k])}`" for k in keys)]
            values = [_values(hints[k], bounds.get(k)) for k in keys]
            cells += [values[0] if len(set(values)) == 1 else " / ".join(values), meaning]
            rows.append(f"| {' / '.join(f'`{k}`' for k in keys)} | " + " | ".join(cells) + " |")
        parts.append(f"### `--field {kind}` ({cls.__name__})\n\n" + "\n".join(rows) + "\n")
    return "\n".join(parts)


def _yaml(value: Any) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, tuple):
        return "[" + ", ".join(map(str, value)) + "]"
    return str(value)


def _values(hint: Any, bound: Any) -> str:
    if typing.get_origin(hint) is typing.Literal:
        return ", ".join(f"`{v}`" for v in typing.get_args(hint))
    if hint is bool:
        return "`true`, `false`"
    kind = {int: "integer", float: "number"}.get(hint, "list of integers")
    return f"{kind} {bound.describe()}" if bound is not None else kind


def _attributes(cls: type, names: list[str]) -> list[tuple[list[str], str]]:
    """The entries of the class docstring's ``Attributes:`` block: the keys each names (``name:``,
    ``a / b:``, ``prefix_*``) and its first sentence, markup reduced to backticks."""
    doc = inspect.getdoc(cls) or ""
    block = " ".join(doc.split("Attributes:", 1)[-1].split())
    name = "(?:" + "|".join(sorted(names, key=len, reverse=True)) + r"|\w+_\*)"
    heads = list(re.finditer(rf"(?:^|(?<=[.)] ))({name}(?: / {name})*): ", block))
    out = []
    for head, nxt in zip(heads, [*heads[1:], None], strict=True):
        text = block[head.end() : nxt.start() if nxt else len(block)].strip()
        text = re.sub(r" \(:data:`\w+`\)", "", text)
        text = re.sub(r":\w+:`~?([\w.]+)`", lambda m: f"`{m.group(1).rsplit('.', 1)[-1]}`", text)
        text = re.sub(r"``([^`]+)``", r"`\1`", text)
        first = re.split(r"(?<=[A-Za-z0-9)`])\. (?=[A-Z\"`(])", text, maxsplit=1)[0].rstrip(".") + "."
        keys = [n for k in head.group(1).split(" / ") for n in names
                if n == k or (k.endswith("_*") and n.startswith(k[:-1]))]  # fmt: skip
        out.append((keys, first[0].upper() + first[1:].replace("|", "\\|")))
    return out


if __name__ == "__main__":
    print(cli_reference(), end="")
