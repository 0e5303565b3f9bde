"""How a benchmark's jobs run: the :class:`Executor` protocol and its registry, :data:`EXECUTORS`.

:func:`~spikenerf.pipelines.benchmark.run.run_benchmark` lists the jobs (:class:`~.steps.Job`: one scene's
dataset or one cell, with its recorded ``spikenerf`` commands) and hands them to the executor that
``BenchmarkConfig.executor`` names: ``local`` (subprocesses on this machine, ``--jobs`` at once;
:mod:`.local_executor`) or ``ray`` (Ray tasks on this machine or a cluster; :mod:`.ray_executor`). An executor
knows jobs and commands, not cells. To add one: a class with these three methods in its own module, and its
entry here (the CLI's ``--executor`` choices come from :data:`EXECUTORS`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

from spikenerf.core.errors import InputError
from spikenerf.pipelines.benchmark.local_executor import LocalExecutor
from spikenerf.pipelines.benchmark.ray_executor import RayExecutor
from spikenerf.pipelines.benchmark.steps import Job


class Executor(Protocol):
    """Runs a benchmark's jobs; ``cfg`` is its ``BenchmarkConfig``."""

    def check(self, cfg: Any) -> None:
        """Refuse, with one line and before anything is written, a benchmark it cannot run."""
        ...

    def processes(self, cfg: Any) -> int:
        """Render processes of one dataset's ``simulate`` (its ``--jobs``): the CPUs a dataset job has."""
        ...

    def run(self, cfg: Any, jobs: list[Job], log: list[dict], nonce: str,
            finished: Callable[[Job], None]) -> None:  # fmt: skip
        """Run the unfinished ``jobs`` (a cell after the dataset it ``needs``), appending the steps run to
        ``log``, and call ``finished(job)`` for every job once it has finished (now or before)."""
        ...


#: ``--executor`` name → implementation
EXECUTORS: dict[str, Executor] = {"local": LocalExecutor(), "ray": RayExecutor()}


def get_executor(name: str) -> Executor:
    """The executor called ``name``; InputError naming ``executor`` for an unknown one."""
    try:
        return EXECUTORS[name]
    except KeyError:
        raise InputError(
            f"executor: unknown executor {name!r}; expected one of {', '.join(EXECUTORS)}", param="executor"
        ) from None
