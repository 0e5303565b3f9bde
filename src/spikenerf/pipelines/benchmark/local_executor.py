"""``benchmark --executor local`` (the default): the jobs as ``spikenerf`` subprocesses on this machine.

Every dataset first, then every cell, ``cfg.jobs`` at a time, each with a progress bar. With one job at a
time a step's output goes to the terminal; with more, to ``OUT/logs/<job>.log``, each step with
``cpu_count // jobs`` threads unless ``OMP_NUM_THREADS`` is set.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, as_completed
from functools import partial
from pathlib import Path
from typing import Any, TypeVar

from spikenerf.core.progress import bar as progress_bar
from spikenerf.pipelines.benchmark.steps import Job, run_step, stop_running

T = TypeVar("T")


class LocalExecutor:
    """Subprocesses on this machine, ``cfg.jobs`` at once (see the module docstring)."""

    def check(self, cfg: Any) -> None:
        """Nothing to check: it needs nothing optional."""

    def processes(self, cfg: Any) -> int:
        """``OMP_NUM_THREADS`` (``--threads``) when it is a plain count, else the cores shared by the
        datasets simulated at once (before any cell trains)."""
        threads = os.environ.get("OMP_NUM_THREADS", "")
        if threads.isdigit() and int(threads) > 0:
            return int(threads)
        return max(1, (os.cpu_count() or 1) // max(1, min(cfg.jobs, len(cfg.scenes))))

    def run(self, cfg: Any, jobs: list[Job], log: list[dict], nonce: str,
            finished: Callable[[Job], None]) -> None:  # fmt: skip
        """The datasets, then the cells (the jobs that need one), ``cfg.jobs`` at a time."""
        n = max(1, cfg.jobs)
        datasets = [partial(_run_job, cfg, job, log, finished) for job in jobs if job.needs is None]
        _parallel(datasets, n, "benchmark datasets", "scene")
        cells = [partial(_run_job, cfg, job, log, finished) for job in jobs if job.needs is not None]
        _parallel(cells, n, "benchmark cells", "cell")


def _run_job(cfg: Any, job: Job, log: list[dict], finished: Callable[[Job], None]) -> None:
    """Run the job's commands unless it has finished before; then ``finished(job)``."""
    if not (cfg.out / job.done).is_file():
        for command in job.commands(cfg.out):
            run_step(command, log, *_step_output(cfg, job.name))
    finished(job)


def _parallel(tasks: list[Callable[[], T]], jobs: int, desc: str, unit: str) -> list[T]:
    """Run ``tasks`` ``jobs`` at a time with a progress bar; results in task order. The first failure
    cancels the tasks not yet started, lets the running ones finish, and is raised; an interruption
    (Ctrl-C, SIGTERM) also stops the steps running now (:func:`stop_running`)."""
    results: dict[int, T] = {}
    with (
        ThreadPoolExecutor(max_workers=jobs) as pool,
        progress_bar(total=len(tasks), desc=desc, unit=unit) as bar,
    ):
        futures = {pool.submit(task): i for i, task in enumerate(tasks)}
        try:
            for future in as_completed(futures):
                results[futures[future]] = future.result()
                bar.update()
        except BaseException as err:
            for future in futures:
                future.cancel()
            if not isinstance(err, Exception):  # interrupted: the running steps too, not at their end
                stop_running()
            raise
    return [results[i] for i in range(len(tasks))]


def _step_output(cfg: Any, name: str) -> tuple[Path | None, int | None]:
    """Where a step's output goes and its thread count (the terminal and torch's default for one job)."""
    if cfg.jobs <= 1:
        return None, None
    threads = None if os.environ.get("OMP_NUM_THREADS") else max(1, (os.cpu_count() or 1) // cfg.jobs)
    return cfg.out / "logs" / f"{name}.log", threads
