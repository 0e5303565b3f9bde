"""The benchmark followed by its HTML report, and the report rebuilt from a finished benchmark folder (kept
apart so that ``report`` may import the ``benchmark`` package and not the other way round: no import
cycle)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path

from spikenerf.core.errors import InputError
from spikenerf.data.choices import COLORS
from spikenerf.pipelines.benchmark.cells import BenchmarkConfig
from spikenerf.pipelines.benchmark.results import RESULTS, merge_calls, read_call
from spikenerf.pipelines.benchmark.run import run_benchmark
from spikenerf.pipelines.benchmark.tables import Cell
from spikenerf.pipelines.report import build_report


def benchmark_with_report(cfg: BenchmarkConfig, on_cell: Callable[[Cell], None] | None = None) -> list[Cell]:
    """:func:`run_benchmark`, then ``cfg.out/report.html``; returns the cells."""
    cells = run_benchmark(cfg, on_cell)
    build_report(cfg, cells)
    return cells


def report_from_folder(out: Path, others: Sequence[Path] = (), progress: bool = True) -> Path:
    """Rebuild ``out/report.html`` from the finished benchmark folder ``out`` (its ``results.json``; the
    folder may have moved), its tables holding also the cells of ``others``: the ``results.json`` of the
    same benchmark's other calls (e.g. one per ``--seeds K``; :func:`merge_calls` refuses other settings
    and cells held twice). The figures show ``out``'s own runs, the environment each call's recorded one.
    Returns the report's path.

    Raises:
        InputError: ``out`` has no ``results.json``, or a file cannot be read or merged.
    """
    out = Path(out)
    if not out.is_dir():
        problem = (
            "is a file, not a benchmark folder (the folder comes first)" if out.exists() else "no such folder"
        )
        raise InputError(problem, path=out)
    if not (out / RESULTS).is_file():
        raise InputError(
            f"no {RESULTS}: not a finished benchmark folder (run `spikenerf benchmark` to its end)", path=out
        )
    calls = [read_call(out / RESULTS), *(read_call(Path(p)) for p in others)]
    _, cells, _ = merge_calls(calls)
    own = config_of(calls[0].config, out)
    seeds = sorted({c.seed for c in cells})
    merged = dataclasses.replace(
        own,
        variants=list(dict.fromkeys([*own.variants, *(c.variant for c in cells)])),
        colors=[c for c in COLORS if c in own.colors or any(cell.color == c for cell in cells)],
        seeds=seeds if seeds != [own.seed] else own.seeds,
    )
    envs = [call.environment for call in calls if call.environment]
    return build_report(merged, cells, progress, own=own, recorded=envs)


def config_of(recorded: dict, out: Path) -> BenchmarkConfig:
    """The :class:`BenchmarkConfig` of a ``results.json``'s ``config``, with ``out`` as its folder (entries
    of other versions that the config lacks are left out; missing ones take their defaults)."""
    names = {f.name for f in dataclasses.fields(BenchmarkConfig)}
    try:
        return BenchmarkConfig(**{**{k: v for k, v in recorded.items() if k in names}, "out": out})
    except TypeError as err:
        raise InputError(f"not a benchmark's {RESULTS} ({err})", path=out / RESULTS) from None
