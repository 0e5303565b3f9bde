"""The benchmark followed by its HTML report (kept apart so that ``report`` may import ``benchmark`` and
not the other way round: no import cycle)."""

from __future__ import annotations

from collections.abc import Callable

from spikenerf.pipelines.benchmark import BenchmarkConfig, run_benchmark
from spikenerf.pipelines.report import build_report
from spikenerf.pipelines.tables import Cell


def benchmark_with_report(cfg: BenchmarkConfig, on_cell: Callable[[Cell], None] | None = None) -> list[Cell]:
    """:func:`run_benchmark`, then ``cfg.out/report.html``; returns the cells."""
    cells = run_benchmark(cfg, on_cell)
    build_report(cfg, cells)
    return cells
