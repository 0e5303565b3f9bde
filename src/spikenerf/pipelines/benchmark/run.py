"""The paper's comparison (Table I), ablation (Table II) and paired differences, resumable cell by cell.

Every step is one ``spikenerf`` command run in a subprocess, so the exact commands are recorded in
``results.json`` and a user can re-run any cell by hand. A cell (scene, colour, method variant, training seed)
is finished when its run folder holds ``render/render.json`` (``metrics.json`` with renders off); finished
cells are reused when the benchmark is restarted, and a cell killed during its render only renders again.
:func:`~spikenerf.pipelines.benchmark.cells.cell_keys` says which cells there are; :func:`run_benchmark`
lists each scene's dataset and each cell as a job and hands them to the executor that ``cfg.executor``
names (:mod:`spikenerf.pipelines.benchmark.executor`).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from dataclasses import replace
from functools import partial
from pathlib import Path

from spikenerf.core.atomic import clean_stale_temps
from spikenerf.core.errors import InputError
from spikenerf.core.lock import output_lock
from spikenerf.core.marker import check_output, folder_kind, mark, owned
from spikenerf.core.yamlio import load_yaml
from spikenerf.data.summary import view_counts
from spikenerf.pipelines.benchmark.cells import (
    BenchmarkConfig,
    CellKey,
    cell_commands,
    cell_keys,
    cell_name,
    dataset_command,
    read_cell,
    run_dir,
)
from spikenerf.pipelines.benchmark.executor import Executor, get_executor
from spikenerf.pipelines.benchmark.resources import check_benchmark_resources
from spikenerf.pipelines.benchmark.results import write_all
from spikenerf.pipelines.benchmark.settings import adopt_integral_defaults, check_settings, write_settings
from spikenerf.pipelines.benchmark.steps import Job
from spikenerf.pipelines.benchmark.tables import Cell


def run_benchmark(cfg: BenchmarkConfig, on_cell: Callable[[Cell], None] | None = None) -> list[Cell]:
    """Simulate each scene once, then train/eval every missing cell; write the tables (the HTML report:
    :func:`spikenerf.pipelines.suite.benchmark_with_report`). ``on_cell`` is called with each cell once it
    has finished (now or before)."""
    executor = get_executor(cfg.executor)
    executor.check(cfg)  # e.g. without Ray: one line, before anything is written
    if not pre_simulated(cfg.out):  # that one is adopted (marked below)
        check_output(cfg.out, "benchmark", overwrite=True)  # a folder it wrote before is resumed
    check_settings(cfg)  # … with the settings it was started with
    _check_datasets(cfg)  # … and datasets simulated with them
    check_benchmark_resources(cfg)
    with output_lock(cfg.out):
        nonce = check_settings(cfg)
        mark(cfg.out, "benchmark")
        if nonce is None:
            nonce = write_settings(cfg, None)
        adopt_integral_defaults(cfg)
        if owned(cfg.out):  # a folder of ours (one recognised by its files alone may be a user's)
            clean_stale_temps(cfg.out)
        return _run_benchmark_locked(cfg, executor, on_cell, nonce)


def pre_simulated(out: Path) -> bool:
    """Whether ``out`` is an unmarked folder that holds only ``datasets/SCENE`` dataset folders, simulated
    first as docs/cluster.md describes (e.g. on a Blender node): the benchmark adopts it and reuses them."""
    datasets = out / "datasets"
    if folder_kind(out) is not None or not datasets.is_dir():
        return False
    if [p.name for p in out.iterdir()] != ["datasets"]:
        return False
    scenes = list(datasets.iterdir())
    return bool(scenes) and all(folder_kind(scene) == "dataset" for scene in scenes)


def _run_benchmark_locked(
    cfg: BenchmarkConfig, executor: Executor, on_cell: Callable[[Cell], None] | None, nonce: str
) -> list[Cell]:
    cfg.out.mkdir(parents=True, exist_ok=True)
    log: list[dict] = []
    keys = cell_keys(cfg)
    _check_datasets(cfg)
    forget_unscored(cfg, keys)
    jobs = _jobs(cfg, keys)
    key_of = {cell_name(cfg, key): key for key in keys}

    def finished(job: Job) -> None:
        key = key_of.get(job.name)
        if key is None:
            return  # a dataset
        run = run_dir(cfg, *key)
        cell = read_cell(run, *key[:3], seed=key.seed)
        if cell is None:
            raise InputError("eval finished without writing metrics.json", path=run)
        if on_cell:
            on_cell(cell)

    executor.run(cfg, jobs, log, nonce, finished)
    cells = [read_cell(run_dir(cfg, *key), *key[:3], seed=key.seed) for key in keys]
    if None in cells:
        raise InputError("a cell finished without metrics.json; run the benchmark again", path=cfg.out)
    write_results(cfg, cells, log)  # type: ignore[arg-type]
    if others := other_finished_cells(cfg, keys):
        print(
            f"spikenerf: warning: the tables hold this call's {len(keys)} cells; {len(others)} other "
            f"finished cells in {cfg.out / 'runs'} (other methods, scenes, colours or seeds) are left out: "
            "give those too to include them",
            file=sys.stderr,
            flush=True,
        )
    return cells  # type: ignore[return-value]


def other_finished_cells(cfg: BenchmarkConfig, keys: Sequence[CellKey]) -> list[Path]:
    """The run folders under ``OUT/runs`` with a ``metrics.json`` that are not cells of ``keys`` (an earlier
    call's with other methods, scenes, colours or seeds): the written tables leave them out."""
    mine = {run_dir(cfg, *key) for key in keys}
    return sorted(p.parent for p in (cfg.out / "runs").glob("*/*/*/metrics.json") if p.parent not in mine)


def _check_datasets(cfg: BenchmarkConfig) -> None:
    """Refuse a dataset simulated before (by an interrupted benchmark, or by hand into OUT/datasets) with
    other settings than the benchmark asks for: its size, steps, seed, test views, colours, blur views."""
    for scene in cfg.scenes:
        if (problem := dataset_mismatch(cfg, scene)) is not None:
            raise problem


def dataset_mismatch(cfg: BenchmarkConfig, scene: str) -> InputError | None:
    """The refusal (an InputError to raise) where ``OUT/datasets/SCENE`` was simulated with other settings
    than ``cfg`` asks for (its size, steps, seed, test views, blur views, noise, replaced noise parameters,
    or lacking a colour); None
    where it fits or does not exist yet. ``benchmark`` refuses to resume on it, ``report`` to draw figures
    from it."""
    root = cfg.out / "datasets" / scene
    if not (root / "transforms.json").is_file():
        return None
    have = dataset_settings(root)
    want = {"size": [cfg.size, cfg.size], "frames": cfg.frames, "seed": cfg.seed,
            "test_views": cfg.test_views, "blur_views": cfg.blur_views, "noise": cfg.noise}  # fmt: skip
    for param, value in want.items():
        if have[param] is not None and have[param] != value:
            return InputError(
                f"{param}: the dataset was simulated with {param} {have[param]}, but the benchmark asks "
                f"for {value}; pass that or delete the dataset to re-simulate it",
                path=root,
                param=param,
            )
    if (have["noise_params"] or {}) != cfg.noise_params:  # (simulate / benchmark --noise-param)

        def said(params: dict | None) -> str:
            return ", ".join(f"{key}={value}" for key, value in (params or {}).items()) or "none"

        return InputError(
            f"noise_params: the dataset was simulated with replaced noise parameters "
            f"{said(have['noise_params'])}, but the benchmark asks for {said(cfg.noise_params)}; pass those "
            "or delete the dataset to re-simulate it",
            path=root,
            param="noise_params",
        )
    if have["colors"] is not None and (lacking := [c for c in cfg.colors if c not in have["colors"]]):
        return InputError(
            f"color: the dataset has no {', '.join(lacking)} stream; delete it to re-simulate it",
            path=root,
            param="color",
        )
    return None


def forget_unscored(cfg: BenchmarkConfig, keys: Sequence[CellKey]) -> None:
    """Let a cell whose ``metrics.json`` is gone (deleted, e.g. a malformed one, as the refusal advises) be
    evaluated again: its ``render/render.json``, which marks a finished cell, is removed (the render then
    resumes from its cache)."""
    for key in keys:
        run = run_dir(cfg, *key)
        if cfg.render and not (run / "metrics.json").is_file():
            (run / "render" / "render.json").unlink(missing_ok=True)


def dataset_settings(root: Path) -> dict:
    """What a dataset folder was simulated with, from its ``config.yaml`` (None where it does not say):
    ``size`` [W, H], ``frames``, ``seed``, ``test_views``, ``noise``, ``noise_params`` (those ``simulate
    --noise-param`` replaced), ``colors`` and ``blur_views``."""
    import yaml

    try:
        config = load_yaml((root / "config.yaml").read_text(encoding="utf-8")) or {}
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        config = {}
    config = config if isinstance(config, dict) else {}
    size = [config.get("spike_w"), config.get("spike_h")]
    return {
        "size": None if None in size else size,
        "frames": config.get("steps"),
        "seed": config.get("seed"),
        "test_views": config.get("test_views"),
        "noise": config.get("noise"),
        "noise_params": params if isinstance(params := config.get("noise_params"), dict) else None,
        "colors": colors if isinstance(colors := config.get("colors"), list) else None,  # (a list or unsaid)
        "blur_views": str(view_counts(root)["blur_views"]),
    }


def _commands_at(cfg: BenchmarkConfig, key: tuple, root: Path) -> list[list[str]]:
    """A job's commands for the benchmark folder at ``root``: a dataset's for ``(scene,)``, else a cell's."""
    here = replace(cfg, out=root)
    return [dataset_command(here, key[0])] if len(key) == 1 else cell_commands(here, *key)


def _jobs(cfg: BenchmarkConfig, keys: list[CellKey]) -> list[Job]:
    """Each scene's dataset, then each cell (``keys``, in order) after its scene's dataset."""
    jobs = [Job(f"simulate-{s}", partial(_commands_at, cfg, (s,)), f"datasets/{s}",
                f"datasets/{s}/transforms.json") for s in cfg.scenes]  # fmt: skip
    for key in keys:
        run = run_dir(cfg, *key).relative_to(cfg.out).as_posix()
        # a cell is done when its last command is: a render killed after eval is run again (it resumes)
        done = f"{run}/render/render.json" if cfg.render else f"{run}/metrics.json"
        jobs.append(Job(cell_name(cfg, key), partial(_commands_at, cfg, key), run, done,
                        needs=f"simulate-{key[0]}"))  # fmt: skip
    return jobs


def write_results(cfg: BenchmarkConfig, cells: Sequence[Cell], log: list[dict]) -> None:
    """table1.md, table2.md, differences.md, results.csv and results.json (see results.py)."""
    write_all(cfg, cells, log)
