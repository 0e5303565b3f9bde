"""The paper's comparison (Table I), ablation (Table II) and paired differences, resumable cell by cell.

Every step is one ``spikenerf`` command run in a subprocess, so the exact commands are recorded in
``results.json`` and a user can re-run any cell by hand. A cell (scene, colour, method variant, training seed)
is finished when its run folder holds ``metrics.json``; finished cells are reused when the benchmark is
restarted. :func:`cell_keys` says which cells there are; ``run_benchmark`` says how they are run.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import TypeVar

from tqdm import tqdm

from spikenerf.core.atomic import clean_stale_temps
from spikenerf.core.errors import InputError
from spikenerf.core.lock import output_lock
from spikenerf.core.marker import check_output, mark
from spikenerf.data.summary import view_counts
from spikenerf.pipelines.cells import (  # re-exported: the benchmark's public API
    BenchmarkConfig,
    CellKey,
    cell_commands,
    cell_keys,
    cell_name,
    cpu_name,
    dataset_command,
    environment,
    parse_seeds,
    read_cell,
    resolve_scenes,
    resolve_variants,
    run_dir,
    training_seeds,
)
from spikenerf.pipelines.results import write_all
from spikenerf.pipelines.settings import check_settings, write_settings
from spikenerf.pipelines.steps import run_step as _run
from spikenerf.pipelines.tables import Cell
from spikenerf.pipelines.variants import TABLE1_VARIANTS, VARIANTS  # re-exported

T = TypeVar("T")
__all__ = [
    "TABLE1_VARIANTS",
    "VARIANTS",
    "BenchmarkConfig",
    "CellKey",
    "cell_commands",
    "cell_keys",
    "cpu_name",
    "dataset_command",
    "environment",
    "parse_seeds",
    "read_cell",
    "resolve_scenes",
    "resolve_variants",
    "run_benchmark",
    "run_dir",
    "training_seeds",
    "write_results",
]


def _parallel(tasks: list[Callable[[], T]], jobs: int, desc: str, unit: str) -> list[T]:
    """Run ``tasks`` ``jobs`` at a time with a progress bar; results in task order. The first failure
    cancels the tasks not yet started, lets the running ones finish, and is raised."""
    results: dict[int, T] = {}
    with ThreadPoolExecutor(max_workers=jobs) as pool, tqdm(total=len(tasks), desc=desc, unit=unit) as bar:
        futures = {pool.submit(task): i for i, task in enumerate(tasks)}
        try:
            for future in as_completed(futures):
                results[futures[future]] = future.result()
                bar.update()
        except BaseException:
            for future in futures:
                future.cancel()
            raise
    return [results[i] for i in range(len(tasks))]


def _step_output(cfg: BenchmarkConfig, name: str) -> tuple[Path | None, int | None]:
    """Where a step's output goes and its thread count (the terminal and torch's default for one job)."""
    if cfg.jobs <= 1:
        return None, None
    threads = None if os.environ.get("OMP_NUM_THREADS") else max(1, (os.cpu_count() or 1) // cfg.jobs)
    return cfg.out / "logs" / f"{name}.log", threads


def _simulate_scene(cfg: BenchmarkConfig, scene: str, log: list[dict]) -> None:
    root = cfg.out / "datasets" / scene
    if not (root / "transforms.json").is_file():
        _run(dataset_command(cfg, scene), log, *_step_output(cfg, f"simulate-{scene}"))
        return
    have = str(view_counts(root)["blur_views"])
    if have != cfg.blur_views:
        raise InputError(
            f"blur_views: the dataset was simulated with {have} blur views, but the benchmark asks for "
            f"{cfg.blur_views}; pass {have} or delete the dataset to re-simulate it",
            path=root,
            param="blur_views",
        )


def _run_cell(cfg: BenchmarkConfig, key: CellKey, log: list[dict]) -> Cell:
    """The cell's metrics, training and evaluating it first unless it has finished before."""
    run = run_dir(cfg, *key)
    cell = read_cell(run, *key[:3], seed=key.seed)
    if cell is None:
        for command in cell_commands(cfg, *key):
            _run(command, log, *_step_output(cfg, cell_name(cfg, key)))
        cell = read_cell(run, *key[:3], seed=key.seed)
        if cell is None:
            raise InputError("eval finished without writing metrics.json", path=run)
    return cell


def run_benchmark(cfg: BenchmarkConfig, on_cell: Callable[[Cell], None] | None = None) -> list[Cell]:
    """Simulate each scene once, then train/eval every missing cell; write the tables (the HTML report:
    :func:`spikenerf.pipelines.suite.benchmark_with_report`)."""
    if cfg.executor == "ray":
        from spikenerf.pipelines.ray_executor import require_ray

        require_ray()  # without Ray: one line, before anything is written
    from spikenerf.pipelines.resources import check_benchmark_resources

    check_output(cfg.out, "benchmark", overwrite=True)  # a folder it wrote before is resumed
    check_settings(cfg)  # … with the settings it was started with
    check_benchmark_resources(cfg)
    with output_lock(cfg.out):
        nonce = check_settings(cfg)
        mark(cfg.out, "benchmark")
        if nonce is None:
            nonce = write_settings(cfg, None)
        clean_stale_temps(cfg.out)
        return _run_benchmark_locked(cfg, on_cell, nonce)


def _run_benchmark_locked(
    cfg: BenchmarkConfig, on_cell: Callable[[Cell], None] | None, nonce: str
) -> list[Cell]:
    cfg.out.mkdir(parents=True, exist_ok=True)
    log: list[dict] = []
    keys = cell_keys(cfg)
    if cfg.executor == "ray":
        cells = _run_on_ray(cfg, keys, log, nonce)
        write_results(cfg, cells, log)
        return cells
    jobs = max(1, cfg.jobs)
    simulations = [partial(_simulate_scene, cfg, s, log) for s in cfg.scenes]
    _parallel(simulations, jobs, "benchmark datasets", "scene")

    def cell_task(key: CellKey) -> Callable[[], Cell]:
        def task() -> Cell:
            cell = _run_cell(cfg, key, log)
            if on_cell:
                on_cell(cell)
            return cell

        return task

    cells = _parallel([cell_task(key) for key in keys], jobs, "benchmark cells", "cell")
    write_results(cfg, cells, log)
    return cells


def _commands_at(cfg: BenchmarkConfig, key: tuple, root: Path) -> list[list[str]]:
    """A job's commands for the benchmark folder at ``root``: a dataset's for ``(scene,)``, else a cell's."""
    here = replace(cfg, out=root)
    return [dataset_command(here, key[0])] if len(key) == 1 else cell_commands(here, *key)


def _run_on_ray(cfg: BenchmarkConfig, keys: list[CellKey], log: list[dict], nonce: str) -> list[Cell]:
    """Each scene's dataset and each cell (``keys``, scene first) as a Ray task; cells in ``keys`` order."""
    from spikenerf.pipelines.ray_executor import Job, run_jobs

    jobs = [Job(f"simulate-{s}", partial(_commands_at, cfg, (s,)), f"datasets/{s}",
                f"datasets/{s}/transforms.json") for s in cfg.scenes]  # fmt: skip
    for key in keys:
        run = run_dir(cfg, *key).relative_to(cfg.out).as_posix()
        jobs.append(Job(cell_name(cfg, key), partial(_commands_at, cfg, key), run, f"{run}/metrics.json",
                        needs=f"simulate-{key[0]}"))  # fmt: skip
    run_jobs(cfg, jobs, log, nonce)
    cells = [read_cell(run_dir(cfg, *key), *key[:3], seed=key.seed) for key in keys]
    if None in cells:
        raise InputError("a cell finished without metrics.json; run the benchmark again", path=cfg.out)
    return cells  # type: ignore[return-value]


def write_results(cfg: BenchmarkConfig, cells: Sequence[Cell], log: list[dict]) -> None:
    """table1.md, table2.md, differences.md, results.csv and results.json (see results.py)."""
    write_all(cfg, cells, log)
