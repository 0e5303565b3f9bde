"""``benchmark --executor local`` (the default): the jobs as ``spikenerf`` subprocesses on this machine.

Every dataset first, then every cell, ``cfg.jobs`` at a time, each with a progress bar. With one job at a
time a step's output goes to the terminal; with more, to ``OUT/logs/<job>.log``, each step with
``cpu_count // jobs`` threads unless ``OMP_NUM_THREADS`` is set. The first failure stops the benchmark, or,
with ``cfg.keep_going``, is noted in one warning line while the other jobs run (the cells of a failed
dataset are skipped), and all are listed in one error at the end.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor, as_completed
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from typing import Any, TypeVar

from spikenerf.core.errors import InputError
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
        """The datasets, then the cells (the jobs that need one), ``cfg.jobs`` at a time; with
        ``cfg.keep_going`` every job that can run, then one InputError listing the failed ones."""
        n = max(1, cfg.jobs)
        failed: dict[str, str] | None = {} if getattr(cfg, "keep_going", False) else None
        datasets = {job.name: partial(_run_job, cfg, job, log, finished) for job in jobs if job.needs is None}
        _parallel(list(datasets.values()), n, "benchmark datasets", "scene", list(datasets), failed)
        cells, skipped = {}, []
        for job in (j for j in jobs if j.needs is not None):
            if failed is not None and job.needs in failed:
                skipped.append(job.name)
            else:
                cells[job.name] = partial(_run_job, cfg, job, log, finished)
        _parallel(list(cells.values()), n, "benchmark cells", "cell", list(cells), failed)
        if failed:
            names = ", ".join(list(failed)[:4]) + (f" and {len(failed) - 4} more" if len(failed) > 4 else "")
            but = f", {len(skipped)} skipped (their dataset failed)" if skipped else ""
            where = f" (logs in {cfg.out / 'logs'})" if cfg.jobs > 1 else " (their errors are above)"
            earlier = " (those in the folder now are an earlier call's)" if _tables_exist(cfg.out) else ""
            raise InputError(
                f"{len(failed)} of {len(jobs)} jobs failed: {names}{where}{but}; the others finished. The "
                f"tables are written once every cell has{earlier}: fix the cause and run the benchmark again "
                "to retry only these"
            )


def _tables_exist(out: Path) -> bool:
    """Whether ``out`` holds tables that an earlier call of the benchmark wrote."""
    return any((out / name).is_file() for name in ("results.json", "results.csv", "table1.md"))


def _run_job(cfg: Any, job: Job, log: list[dict], finished: Callable[[Job], None]) -> None:
    """Run the job's commands unless it has finished before; then ``finished(job)``."""
    if not (cfg.out / job.done).is_file():
        output, threads = _step_output(cfg, job.name)
        for command in job.commands(cfg.out):
            with _bars_cleared(output is None):
                run_step(command, log, output, threads)
    finished(job)


@contextmanager
def _bars_cleared(clear: bool) -> Iterator[None]:
    """With ``clear``, this process's progress bars off the terminal while a step writes there (its own
    bars, its error line); they are drawn again below the step's output when it ends."""
    if not clear:
        yield
        return
    from tqdm import tqdm

    with tqdm.external_write_mode(file=sys.stderr, nolock=True):  # nolock: Ctrl-C can close the bars
        yield


def _parallel(
    tasks: list[Callable[[], T]], jobs: int, desc: str, unit: str, names: list[str] | None = None,
    failed: dict[str, str] | None = None,
) -> list[T | None]:  # fmt: skip
    """Run ``tasks`` ``jobs`` at a time with a progress bar; results in task order. The first failure
    cancels the tasks not yet started, lets the running ones finish, and is raised; with ``failed`` (a
    dict, and ``names`` of the tasks) a failing task's error is put there under its name, said in a warning
    line, and the others go on (its result is None). An interruption (Ctrl-C, SIGTERM) also stops the steps
    running now (:func:`stop_running`)."""
    results: dict[int, T | None] = {}
    with (
        ThreadPoolExecutor(max_workers=jobs) as pool,
        progress_bar(total=len(tasks), desc=desc, unit=unit) as bar,
    ):
        futures = {pool.submit(task): i for i, task in enumerate(tasks)}
        try:
            for future in as_completed(futures):
                i = futures[future]
                try:
                    results[i] = future.result()
                except (InputError, OSError) as err:  # a step that failed (a bug is no job's failure)
                    if failed is None or names is None:
                        raise
                    failed[names[i]] = str(err)
                    results[i] = None
                    warning = f"spikenerf: warning: {names[i]} failed ({err}); going on with the others"
                    bar.write(warning, file=sys.stderr)
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
