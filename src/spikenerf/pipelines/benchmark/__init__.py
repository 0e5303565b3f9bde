"""The benchmark: the paper's Table I and Table II and the paired differences, resumable cell by cell.

``variants`` (the method variants, defined once), ``cells`` (what a cell is: its key, run folder and
``spikenerf`` commands), ``run`` (:func:`run_benchmark`: the jobs, their executor, the written results),
``executor`` (the :class:`Executor` protocol and its registry; ``local_executor``, ``ray_executor``),
``steps`` (a job, and one recorded command run as a subprocess), ``settings`` (``OUT/benchmark.json``),
``resources`` (the memory and disk check), ``stats``, ``tables`` and ``results`` (the seeds' statistics, the
tables, the files written).

The names below are imported on first use (PEP 562), so that importing a light module of this package (the
CLI reads ``variants`` for its help) does not import torch. Code in ``spikenerf`` imports the defining
modules, so that ``tests/test_layers.py`` sees its import edges.
"""

from __future__ import annotations

import importlib
from typing import Any

#: defining module (under this package) → the names it exports here
_EXPORTS = {
    "cells": "BenchmarkConfig CellKey cell_commands cell_keys cell_name cpu_name dataset_command environment "
    "parse_seeds read_cell render_processes resolve_scenes resolve_variants run_dir training_seeds",
    "executor": "EXECUTORS Executor get_executor",
    "run": "run_benchmark write_results",
    "stats": "Difference differences summarize t_interval",
    "tables": "Cell Table",
    "variants": "ABLATION_VARIANTS COMPARISONS TABLE1_VARIANTS VARIANTS Variant label",
}
_MODULE = {name: module for module, names in _EXPORTS.items() for name in names.split()}
__all__ = sorted(_MODULE)


def __getattr__(name: str) -> Any:
    if name not in _MODULE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_MODULE[name]}"), name)


def __dir__() -> list[str]:
    return __all__
