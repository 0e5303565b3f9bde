"""The paper's comparison (Table I) and ablation (Table II), resumable cell by cell.

Every step is one ``spikenerf`` command run in a subprocess, so the exact commands are recorded in
``results.json`` and a user can re-run any cell by hand. A cell (scene, method variant, colour) is finished
when its run folder holds ``metrics.json``; finished cells are reused when the benchmark is restarted.
"""

from __future__ import annotations

import json
import os
import platform
import sys
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import TypeVar

import torch
from tqdm import tqdm

from spikenerf import __version__
from spikenerf.core.atomic import write_text_atomic
from spikenerf.core.errors import InputError
from spikenerf.pipelines.steps import run_step as _run
from spikenerf.pipelines.tables import (
    ABLATION_VARIANTS,
    Cell,
    cells_csv,
    table1_markdown,
    table2_markdown,
)
from spikenerf.scenes.registry import blender_available, list_scenes

T = TypeVar("T")

#: method variant -> the ``spikenerf train`` flags that select it
VARIANT_FLAGS: dict[str, list[str]] = {
    "nerf-gt": ["--method", "nerf-gt"],
    "nerf-blur": ["--method", "nerf-blur"],
    "nerf-blur-aware": ["--method", "nerf-blur-aware"],
    "nerf-recon": ["--method", "nerf-recon"],
    "spike-nerf": ["--method", "spike-nerf"],
    "nerf-recon-learned": ["--method", "nerf-recon", "--recon", "learned"],
    "spike-nerf-learned": ["--method", "spike-nerf", "--recon", "learned"],
    "spike-nerf-no-mask": ["--method", "spike-nerf", "--no-mask"],
    "spike-nerf-no-spike-loss": ["--method", "spike-nerf", "--no-spike-loss"],
}
TABLE1_VARIANTS = (
    "nerf-gt",
    "nerf-blur",
    "nerf-blur-aware",
    "nerf-recon",
    "nerf-recon-learned",
    "spike-nerf",
    "spike-nerf-learned",
)


@dataclass
class BenchmarkConfig:
    """What to run; ``size``/``frames``/``iters`` scale from a CPU smoke test up to the paper's setting.

    ``jobs`` > 1 runs that many steps at once, each with its output in ``out/logs/`` and, unless
    ``OMP_NUM_THREADS`` is set, ``cpu_count // jobs`` CPU threads. ``executor="ray"`` runs the steps as Ray
    tasks instead (:mod:`spikenerf.pipelines.ray_executor`, which uses the ``address`` … ``ray_cpus`` fields).
    """

    scenes: list[str]
    variants: list[str]
    colors: list[str]
    out: Path
    size: int = 100
    frames: int = 1000
    iters: int | None = None
    field_kind: str = "grid"
    device: str = "auto"
    seed: int = 0
    test_views: int = 8
    render: bool = True
    extra_train_args: list[str] = field(default_factory=list)
    jobs: int = 1
    executor: str = "local"
    address: str | None = None
    retries: int = 2
    ship_results: bool = False
    ray_cpus: float = 1.0


def resolve_scenes(spec: str) -> list[str]:
    """``all`` → the Blender suite (analytic scenes when Blender is absent); else a comma list."""
    known = {s.name: s for s in list_scenes()}
    if spec == "all":
        blender = [s.name for s in known.values() if s.needs_blender]
        return (
            blender
            if blender and blender_available()
            else [s.name for s in known.values() if not s.needs_blender]
        )
    names = [n.strip() for n in spec.split(",") if n.strip()]
    unknown = [n for n in names if n not in known]
    if unknown or not names:
        raise InputError(
            f"--scenes: unknown scene(s) {unknown}; expected 'all' or names from: {', '.join(known)}"
        )
    return names


def resolve_variants(spec: str) -> list[str]:
    """``all`` → every variant; ``table1``/``table2`` → those tables' rows; else a comma list."""
    presets = {"all": list(VARIANT_FLAGS), "table1": list(TABLE1_VARIANTS), "table2": list(ABLATION_VARIANTS)}
    if spec in presets:
        return presets[spec]
    names = [n.strip() for n in spec.split(",") if n.strip()]
    unknown = [n for n in names if n not in VARIANT_FLAGS]
    if unknown or not names:
        raise InputError(
            f"--methods: unknown method(s) {unknown}; expected all, table1, table2 or {list(VARIANT_FLAGS)}"
        )
    return names


def _spikenerf(*args: str) -> list[str]:
    return [sys.executable, "-m", "spikenerf", *args]


def dataset_command(cfg: BenchmarkConfig, scene: str) -> list[str]:
    """The ``simulate`` command of one scene's dataset (gray and RGB streams when both are asked)."""
    color = cfg.colors[0] if len(cfg.colors) == 1 else "all"
    return _spikenerf(
        "simulate", "--scene", scene, "--width", str(cfg.size), "--height", str(cfg.size),
        "--frames", str(cfg.frames), "--color", color, "--seed", str(cfg.seed),
        "--test-views", str(cfg.test_views), "--out", str(cfg.out / "datasets" / scene),
    )  # fmt: skip


def run_dir(cfg: BenchmarkConfig, scene: str, color: str, variant: str) -> Path:
    """Where one cell's run folder lives."""
    return cfg.out / "runs" / scene / color / variant


def cell_commands(cfg: BenchmarkConfig, scene: str, color: str, variant: str) -> list[list[str]]:
    """train (resuming an interrupted run), eval, and optionally render, for one cell."""
    run = run_dir(cfg, scene, color, variant)
    train = _spikenerf(
        "train", str(cfg.out / "datasets" / scene), *VARIANT_FLAGS[variant], "--color", color,
        "--field", cfg.field_kind, "--device", cfg.device, "--seed", str(cfg.seed), "--out", str(run),
        *(["--iters", str(cfg.iters)] if cfg.iters else []), *cfg.extra_train_args,
    )  # fmt: skip
    if (run / "checkpoint.pt").exists():
        train.append("--resume")
    commands = [train, _spikenerf("eval", str(run), "--device", cfg.device)]
    if cfg.render:
        commands.append(_spikenerf("render", str(run), "--out", str(run / "render"), "--device", cfg.device))
    return commands


def read_cell(run: Path, scene: str, color: str, variant: str) -> Cell | None:
    """The cell's metrics from ``run/metrics.json`` (None when the cell has not finished)."""
    path = run / "metrics.json"
    if not path.is_file():
        return None
    try:
        metrics = json.loads(path.read_text())
        mean = metrics["mean"]
        lpips = None if mean.get("lpips") is None else float(mean["lpips"])
        psnr, ssim = float(mean["psnr"]), float(mean["ssim"])
        return Cell(scene, variant, color, psnr, ssim, lpips, metrics.get("seconds"))
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as err:
        raise InputError(f"malformed metrics ({err}); delete it to re-run the cell", path=path) from err


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
    if not (cfg.out / "datasets" / scene / "transforms.json").is_file():
        _run(dataset_command(cfg, scene), log, *_step_output(cfg, f"simulate-{scene}"))


def _run_cell(cfg: BenchmarkConfig, scene: str, color: str, variant: str, log: list[dict]) -> Cell:
    """The cell's metrics, training and evaluating it first unless it has finished before."""
    run = run_dir(cfg, scene, color, variant)
    cell = read_cell(run, scene, color, variant)
    if cell is None:
        for command in cell_commands(cfg, scene, color, variant):
            _run(command, log, *_step_output(cfg, f"{scene}-{color}-{variant}"))
        cell = read_cell(run, scene, color, variant)
        if cell is None:
            raise InputError("eval finished without writing metrics.json", path=run)
    return cell


def run_benchmark(cfg: BenchmarkConfig, on_cell: Callable[[Cell], None] | None = None) -> list[Cell]:
    """Simulate each scene once, then train/eval every missing cell; write the tables (the HTML report:
    :func:`spikenerf.pipelines.suite.benchmark_with_report`)."""
    if cfg.executor == "ray":
        from spikenerf.pipelines.ray_executor import require_ray

        require_ray()  # without Ray: one line, before anything is written
    cfg.out.mkdir(parents=True, exist_ok=True)
    log: list[dict] = []
    keys = [(s, c, v) for s in cfg.scenes for c in cfg.colors for v in cfg.variants]
    if cfg.executor == "ray":
        cells = _run_on_ray(cfg, keys, log)
        write_results(cfg, cells, log)
        return cells
    jobs = max(1, cfg.jobs)
    simulations = [partial(_simulate_scene, cfg, s, log) for s in cfg.scenes]
    _parallel(simulations, jobs, "benchmark datasets", "scene")

    def cell_task(scene: str, color: str, variant: str) -> Callable[[], Cell]:
        def task() -> Cell:
            cell = _run_cell(cfg, scene, color, variant, log)
            if on_cell:
                on_cell(cell)
            return cell

        return task

    cells = _parallel([cell_task(*key) for key in keys], jobs, "benchmark cells", "cell")
    write_results(cfg, cells, log)
    return cells


def _commands_at(cfg: BenchmarkConfig, key: tuple, root: Path) -> list[list[str]]:
    """A job's commands for the benchmark folder at ``root``: a dataset's for ``(scene,)``, else a cell's."""
    here = replace(cfg, out=root)
    return [dataset_command(here, key[0])] if len(key) == 1 else cell_commands(here, *key)


def _run_on_ray(cfg: BenchmarkConfig, keys: list[tuple], log: list[dict]) -> list[Cell]:
    """Each scene's dataset and each cell (``keys``, scene first) as a Ray task; cells in ``keys`` order."""
    from spikenerf.pipelines.ray_executor import Job, run_jobs

    jobs = [Job(f"simulate-{s}", partial(_commands_at, cfg, (s,)), f"datasets/{s}",
                f"datasets/{s}/transforms.json") for s in cfg.scenes]  # fmt: skip
    for key in keys:
        run = run_dir(cfg, *key).relative_to(cfg.out).as_posix()
        jobs.append(Job("-".join(map(str, key)), partial(_commands_at, cfg, key), run, f"{run}/metrics.json",
                        needs=f"simulate-{key[0]}"))  # fmt: skip
    run_jobs(cfg, jobs, log)
    cells = [read_cell(run_dir(cfg, *key), *key) for key in keys]
    if None in cells:
        raise InputError("a cell finished without metrics.json; run the benchmark again", path=cfg.out)
    return cells  # type: ignore[return-value]


def cpu_name() -> str:
    """The CPU model (``/proc/cpuinfo`` on Linux, where ``platform.processor()`` is often empty)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def environment() -> dict:
    """Versions and hardware recorded beside the results."""
    return {
        "spikenerf": __version__,
        "python": platform.python_version(),
        "torch": torch.__version__,
        "device": torch.cuda.get_device_name(0) if torch.cuda.is_available() else "cpu",
        "cpu": f"{cpu_name()}, {os.cpu_count()} logical cores, {torch.get_num_threads()} torch threads",
        "platform": platform.platform(),
    }


def write_results(cfg: BenchmarkConfig, cells: Sequence[Cell], log: list[dict]) -> None:
    """table1.md, table2.md, results.csv and results.json."""
    t1 = "\n\n".join(table1_markdown(cells, [v for v in cfg.variants if v in TABLE1_VARIANTS] or cfg.variants,
                                     cfg.scenes, c) for c in cfg.colors)  # fmt: skip
    write_text_atomic(cfg.out / "table1.md", "# Table I: comparison (test views)\n\n" + t1 + "\n")
    if any(v in ABLATION_VARIANTS for v in cfg.variants):
        t2 = "\n\n".join(table2_markdown(cells, c) for c in cfg.colors)
        write_text_atomic(cfg.out / "table2.md", "# Table II: ablation (mean over scenes)\n\n" + t2 + "\n")
    write_text_atomic(cfg.out / "results.csv", cells_csv(cells))
    config = {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(cfg).items()}
    results = {
        "config": config,
        "environment": environment(),
        "cells": [asdict(c) for c in cells],
        "commands": {
            "datasets": {s: dataset_command(cfg, s)[2:] for s in cfg.scenes},
            "cells": {
                f"{s}/{c}/{v}": [cmd[2:] for cmd in cell_commands(cfg, s, c, v)]
                for s in cfg.scenes
                for c in cfg.colors
                for v in cfg.variants
            },
            "this_run": log,
        },
    }
    write_text_atomic(cfg.out / "results.json", json.dumps(results, indent=2) + "\n")
