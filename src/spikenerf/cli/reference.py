"""Generate ``docs/cli.md`` from the commands' own ``--help`` (``python -m spikenerf.cli.reference``).

A test checks that the committed page matches, so the docs never drift from the code.
"""

from __future__ import annotations

import click

from spikenerf.cli import SUBCOMMANDS, cli

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
    return "\n".join(parts)


if __name__ == "__main__":
    print(cli_reference(), end="")
