"""Shared table printing for the benchmark scripts: every row compares ours with a reference run in the same
process, so the ratio is meaningful even on a busy machine."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from spikenerf.pipelines.benchmark.stats import t_interval


@dataclass
class Row:
    """One comparison: a throughput of ours against a reference measured in the same run."""

    name: str
    ours: float
    reference: float
    unit: str
    reference_name: str

    @property
    def ratio(self) -> float:
        return self.ours / self.reference if self.reference else float("nan")


def best_seconds(
    fn: Callable[[], object], repeats: int = 3, clock: Callable[[], float] = time.perf_counter
) -> float:
    """The best time of ``repeats`` calls of ``fn`` (seconds; wall time, or ``clock``, e.g. CPU time)."""
    best = float("inf")
    for _ in range(repeats):
        start = clock()
        fn()
        best = min(best, clock() - start)
    return best


def mean_and_interval(ratios: list[float]) -> str:
    """ ", mean R× [lo×, hi×]": the per-round ratios' mean and 95 % t interval ("" for one round)."""
    interval = t_interval(ratios)
    if interval is None:
        return ""
    return f", mean {statistics.mean(ratios):.2f}× [{interval[0]:.2f}×, {interval[1]:.2f}×] (95 % t)"


def format_table(rows: list[Row]) -> str:
    """A markdown table: name, ours, reference, unit, ratio."""
    lines = ["| benchmark | ours | reference | unit | ratio |", "|---|---:|---:|---|---:|"]
    for r in rows:
        reference = f"{r.reference:,.3g} ({r.reference_name})"
        lines.append(f"| {r.name} | {r.ours:,.3g} | {reference} | {r.unit} | {r.ratio:.2f}× |")
    return "\n".join(lines)


def interleaved_ms(
    impls: dict[str, Callable[[], object]], cuda: bool, rounds: int, repeats: int, warmup: int = 2
) -> dict[str, float]:
    """The median over ``rounds`` interleaved rounds of each function's milliseconds a call (the mean of
    ``repeats`` calls, the GPU synchronised on both sides with ``cuda``), after ``warmup`` untimed calls."""
    import torch

    sync = torch.cuda.synchronize if cuda else (lambda: None)

    def timed(fn: Callable[[], object], calls: int) -> float:
        sync()
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        sync()
        return (time.perf_counter() - start) / calls * 1e3

    for fn in impls.values():
        timed(fn, warmup)
    times: dict[str, list[float]] = {name: [] for name in impls}
    for _ in range(rounds):
        for name, fn in impls.items():
            times[name].append(timed(fn, repeats))
    return {name: statistics.median(runs) for name, runs in times.items()}


def kernel_timing_args(doc: str, extra: Callable[[Any], None]) -> Any:
    """The command line of a kernel timing (``bench_composite``, ``bench_march``): ``--device``, ``--rays``,
    ``--repeats``, ``--rounds``, ``--threads`` (applied here), and what ``extra(parser)`` adds. Returns the
    parsed arguments with ``device`` resolved to a ``torch.device``."""
    import argparse

    import torch

    from spikenerf.core.device import resolve_device

    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--device", default="auto")
    parser.add_argument("--rays", type=int, default=16384)
    extra(parser)
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--threads", type=int, default=None, help="torch threads on a CPU")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    args.device = resolve_device(args.device)
    return args
