"""The benchmark followed by its HTML report (kept apart so that ``report`` may import the ``benchmark``
package and not the other way round: no import cycle)."""

from __future__ import annotations

from collections.abc import Callable

from spikenerf.pipelines.benchmark.cells import BenchmarkConfig
from spikenerf.pipelines.benchmark.run import run_benchmark
from spikenerf.pipelines.benchmark.tables import Cell
from spikenerf.pipelines.report import build_report


def benchmark_with_report(cfg: BenchmarkConfig, on_cell: Callable[[Cell], None] | None = None) -> list[Cell]:
    """:func:`run_benchmark`, then ``cfg.out/report.html``; returns the cells."""
    cells = run_benchmark(cfg, on_cell)
    build_report(cfg, cells)
    return cells
