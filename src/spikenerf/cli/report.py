"""``spikenerf report``: rebuild a finished benchmark's ``report.html``, with other calls' cells merged in."""

from __future__ import annotations

from pathlib import Path

import click


@click.command(
    help="Rebuild OUT/report.html of a finished benchmark folder OUT (from its results.json; the folder may "
    "have moved). RESULTS: the results.json of the same benchmark's other calls (e.g. one per --seeds K), "
    "whose cells join the tables and paired differences (same scenes, size, frames, iterations and train "
    "arguments; a cell held twice is refused); the figures show OUT's own runs."
)
@click.argument("out", type=click.Path(path_type=Path))
@click.argument("results", nargs=-1, type=click.Path(path_type=Path))
@click.option("--no-progress", "--quiet", "no_progress", is_flag=True, help="Hide the progress bar.")
def command(out: Path, results: tuple[Path, ...], no_progress: bool) -> None:
    from spikenerf.pipelines.suite import report_from_folder

    path = report_from_folder(out, results, progress=not no_progress)
    click.echo(f"wrote {path}")
