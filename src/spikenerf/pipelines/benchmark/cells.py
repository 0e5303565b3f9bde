"""The benchmark's cells and the commands behind them: which (scene, colour, method variant, training seed)
cells a :class:`BenchmarkConfig` asks for (:func:`cell_keys`), where their run folders are, the exact
``spikenerf`` commands of a dataset and a cell, a finished cell's metrics, and the recorded environment.
How they run is ``run.py`` and its executors (``executor.py``: local processes or Ray tasks).
"""

from __future__ import annotations

import json
import os
import platform
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import torch

from spikenerf import __version__
from spikenerf.core.errors import InputError, comma_list, is_finite, parse_int
from spikenerf.eval.metrics import SSIMConfig
from spikenerf.pipelines.benchmark.executor import get_executor
from spikenerf.pipelines.benchmark.tables import Cell
from spikenerf.pipelines.benchmark.variants import ABLATION_VARIANTS, TABLE1_VARIANTS, VARIANTS
from spikenerf.scenes.registry import blender_available, list_scenes


def check_size(size: int) -> None:
    """InputError (naming ``size``) unless the benchmark's image side ``size`` is a multiple of 4 (width ×
    height a multiple of 8, as a ``.dat`` file packs 8 pixels a byte) and fits SSIM's window (11 px,
    ``eval.metrics.SSIMConfig``): smaller images get no SSIM, and no cell could be tabulated."""
    window = SSIMConfig().window
    smallest = window + (-window) % 4
    if size < smallest or size % 4:
        raise InputError(
            f"size must be a multiple of 4 (width × height a multiple of 8, for the .dat file) and at least "
            f"{smallest} (SSIM's {window}-pixel window), found {size}",
            param="size",
        )


@dataclass
class BenchmarkConfig:
    """What to run; ``size``/``frames``/``iters`` scale from a CPU smoke test up to the paper's setting.

    ``jobs`` > 1 runs that many steps at once, each with its output in ``out/logs/`` and, unless
    ``OMP_NUM_THREADS`` is set, ``cpu_count // jobs`` CPU threads. ``seed`` seeds the simulated datasets;
    ``seeds`` are the training seeds, each cell trained once per seed (None = ``[seed]``). ``blur_views`` is
    ``simulate --blur-views`` (``all`` = the paper's blur baseline: one exposure centred on every step);
    ``noise`` its ``--noise`` (``ideal`` or ``realistic``: the spike camera's noise model, camera.md) and
    ``noise_params`` its ``--noise-param``s (realistic parameters that replace the preset's; empty: none).
    ``executor`` names an entry of :data:`~spikenerf.pipelines.benchmark.executor.EXECUTORS`: ``"ray"`` runs
    the steps as Ray tasks instead (:mod:`spikenerf.pipelines.benchmark.ray_executor`, which uses the
    ``address`` … ``ray_cpus`` fields). ``keep_going``: the local executor runs every job even when one
    fails and lists the failures at the end (the Ray executor always does). ``out`` is kept absolute (a
    relative one is taken from the current folder): the commands that ``results.json``, the datasets'
    ``config.yaml`` and the report record name their paths under it, and must name the same folders when
    read from another one.
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
    seeds: list[int] | None = None
    blur_views: str = "all"
    noise: str = "ideal"
    noise_params: dict = field(default_factory=dict)
    executor: str = "local"
    address: str | None = None
    retries: int = 2
    ship_results: bool = False
    ray_cpus: float = 1.0
    keep_going: bool = False

    def __post_init__(self) -> None:
        self.out = Path(os.path.abspath(self.out))


class CellKey(NamedTuple):
    """What identifies a benchmark cell."""

    scene: str
    color: str
    variant: str
    seed: int


def training_seeds(cfg: BenchmarkConfig) -> list[int]:
    """The training seeds of the benchmark (``cfg.seeds``, or the dataset seed alone)."""
    return list(cfg.seeds) if cfg.seeds else [cfg.seed]


def cell_keys(cfg: BenchmarkConfig) -> list[CellKey]:
    """Every cell of the benchmark, in the order they are run and tabulated."""
    seeds = training_seeds(cfg)
    return [CellKey(s, c, v, k) for s in cfg.scenes for c in cfg.colors for v in cfg.variants for k in seeds]


def parse_seeds(spec: str) -> list[int]:
    """``"0,1,2"`` → ``[0, 1, 2]``; InputError on a non-integer, a negative or a repeated seed."""
    seeds = []
    for part in spec.split(","):
        seed = parse_int(part.strip(), "seeds", "comma-separated integers")
        if seed < 0:
            raise InputError(f"seeds: expected non-negative integers, found {seed}", param="seeds")
        if seed in seeds:
            raise InputError(f"seeds: seed {seed} is given twice", param="seeds")
        seeds.append(seed)
    return seeds


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
    return comma_list(
        spec,
        known,
        lambda bad: (
            (f"scenes: unknown scene(s) {', '.join(bad)}" if bad else "scenes: none given")
            + f"; expected 'all' or names from: {', '.join(known)}"
        ),
        param="scenes",
    )


def resolve_variants(spec: str) -> list[str]:
    """``all`` → every variant; ``table1``/``table2`` → those tables' rows; else a comma list."""
    presets = {"all": list(VARIANTS), "table1": list(TABLE1_VARIANTS), "table2": list(ABLATION_VARIANTS)}
    if spec in presets:
        return presets[spec]
    return comma_list(
        spec,
        VARIANTS,
        lambda bad: f"methods: unknown method(s) {bad}; expected all, table1, table2 or {list(VARIANTS)}",
        param="methods",
    )


def _spikenerf(*args: str) -> list[str]:
    return [sys.executable, "-m", "spikenerf", *args]


def render_processes(cfg: BenchmarkConfig) -> int:
    """Render processes per dataset: what the executor gives one dataset job (a Ray task's CPUs; locally
    ``OMP_NUM_THREADS`` or the cores shared by the datasets simulated at once)."""
    return get_executor(cfg.executor).processes(cfg)


def dataset_command(cfg: BenchmarkConfig, scene: str) -> list[str]:
    """The ``simulate`` command of one scene's dataset (gray and RGB streams when both are asked); analytic
    scenes render in :func:`render_processes` processes."""
    color = cfg.colors[0] if len(cfg.colors) == 1 else "all"
    jobs = render_processes(cfg)
    return _spikenerf(
        "simulate", "--scene", scene, "--width", str(cfg.size), "--height", str(cfg.size),
        "--frames", str(cfg.frames), "--color", color, "--seed", str(cfg.seed),
        "--test-views", str(cfg.test_views), "--blur-views", cfg.blur_views, "--noise", cfg.noise,
        *[arg for key, v in cfg.noise_params.items() for arg in ("--noise-param", f"{key}={float(v)!r}")],
        "--jobs", str(jobs),
        "--out", str(cfg.out / "datasets" / scene),
    )  # fmt: skip


def run_dir(cfg: BenchmarkConfig, scene: str, color: str, variant: str, seed: int | None = None) -> Path:
    """Where one cell's run folder lives: ``runs/SCENE/COLOR/VARIANT`` for the dataset seed (``cfg.seed``,
    the layout of single-seed benchmarks), ``runs/SCENE/COLOR/VARIANT-seedK`` for another training seed K."""
    seed = cfg.seed if seed is None else seed
    return cfg.out / "runs" / scene / color / (variant if seed == cfg.seed else f"{variant}-seed{seed}")


def cell_name(cfg: BenchmarkConfig, key: CellKey) -> str:
    """The cell's name in logs and progress: ``SCENE-COLOR-VARIANT``, ``-seedK`` added for another seed."""
    return "-".join(key[:3]) + ("" if key.seed == cfg.seed else f"-seed{key.seed}")


def cell_commands(
    cfg: BenchmarkConfig, scene: str, color: str, variant: str, seed: int | None = None, todo: bool = True
) -> list[list[str]]:
    """train (resuming an interrupted run), eval, and optionally render, for one cell (only the render where
    ``metrics.json`` is there: the cell was killed in its render, which resumes). ``todo=False``: the
    cell's whole commands as a fresh run gives them, whatever is on disk (what the results and the report
    record). The cell's batch is the method's CPU default unless the extra train arguments name one, so
    that a cell trains the same rays on any device (``train`` alone takes more on CUDA)."""
    seed = cfg.seed if seed is None else seed
    run = run_dir(cfg, scene, color, variant, seed)
    rays = VARIANTS[variant].config().rays_per_step()
    batch = [] if "--batch" in cfg.extra_train_args else ["--batch", str(rays)]
    train = _spikenerf(
        "train", str(cfg.out / "datasets" / scene), *VARIANTS[variant].train_args(), "--color", color,
        "--field", cfg.field_kind, "--device", cfg.device, "--seed", str(seed), "--out", str(run),
        *(["--iters", str(cfg.iters)] if cfg.iters else []), *batch, *cfg.extra_train_args,
        *(["--ignore-unused"] if cfg.extra_train_args else []),  # one set of flags for every method
    )  # fmt: skip
    if todo and (run / "checkpoint.pt").exists():
        train.append("--resume")
    commands = [train, _spikenerf("eval", str(run), "--device", cfg.device)]
    if cfg.render:
        render = _spikenerf("render", str(run), "--out", str(run / "render"), "--device", cfg.device)
        if todo and (run / "metrics.json").is_file():  # scored before a kill in its render: render only
            return [render]
        commands.append(render)
    return commands


def read_cell(run: Path, scene: str, color: str, variant: str, seed: int = 0) -> Cell | None:
    """The cell's metrics from ``run/metrics.json`` (None when the cell has not finished)."""
    path = run / "metrics.json"
    if not path.is_file():
        return None
    try:
        metrics = json.loads(path.read_text())
        mean = metrics["mean"]
        if isinstance(mean, dict) and "psnr" in mean and mean["psnr"] is None:  # eval's null: not finite
            raise InputError(
                f"the cell scored no PSNR (its renders were not finite: a diverged run?); delete {run} to "
                "train it again",
                path=path,
            )
        lpips = None if mean.get("lpips") is None else _finite(mean["lpips"], "mean.lpips")
        psnr, ssim = _finite(mean["psnr"], "mean.psnr"), _finite(mean["ssim"], "mean.ssim")
        seconds = metrics.get("seconds")
        if seconds is not None and _finite(seconds, "seconds") < 0:
            raise ValueError(f"seconds is {json.dumps(seconds)}, not a number ≥ 0")
    except InputError:
        raise
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError, RecursionError) as err:
        raise InputError(f"malformed metrics ({err}); delete it to re-run the cell", path=path) from err
    return Cell(scene, variant, color, psnr, ssim, lpips, seconds, seed, _train_seconds(run))


def _finite(value: object, name: str) -> float:
    """``value`` as a float; ValueError naming ``name`` unless it is a finite JSON number (eval writes strict
    JSON: a value it cannot compute is null, never NaN or Infinity, so one of those was edited in)."""
    if not isinstance(value, int | float) or not is_finite(value):  # (10**400: no float)
        raise ValueError(f"{name} is {json.dumps(value)}, not a finite number")
    return float(value)


def _train_seconds(run: Path) -> float | None:
    """The run's training time from its ``summary.json`` (None where it is missing or unreadable)."""
    try:
        seconds = json.loads((run / "summary.json").read_text()).get("seconds")
    except (OSError, ValueError, AttributeError, RecursionError):
        return None
    finite = isinstance(seconds, int | float) and is_finite(seconds)
    return float(seconds) if finite and seconds >= 0 else None


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
