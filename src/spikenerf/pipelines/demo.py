"""``spikenerf demo``: the whole pipeline on the embedded default scene, as a one-scene benchmark.

simulate → train ``spike-integral`` (``train``'s default), ``spike-nerf`` and the main baselines
(``nerf-recon``, ``nerf-blur``, ``nerf-gt``) → eval →
render → report, all through :func:`spikenerf.pipelines.suite.benchmark_with_report`, so an interrupted demo
resumes where it stopped. The default scene is the analytic ``analytic-orbs`` (no Blender needed, ms per
frame); see docs/report.md for the choice and measured timings.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from spikenerf.core.errors import InputError
from spikenerf.pipelines.benchmark.cells import BenchmarkConfig, check_size
from spikenerf.pipelines.benchmark.tables import Cell, table1_markdown
from spikenerf.pipelines.suite import benchmark_with_report

DEFAULT_SCENE = "analytic-orbs"
DEMO_METHODS = ("nerf-gt", "nerf-blur", "nerf-recon", "spike-nerf", "spike-integral")


@dataclass(frozen=True)
class Preset:
    """Sizes of one demo preset: image side (px), spike steps, iterations, test views, rays per batch,
    spike-loss window (steps) and pixels per window."""

    size: int
    frames: int
    iters: int
    test_views: int
    batch: int
    spike_window: int
    spike_pixels: int


#: measured on 2 CPU cores (docs/report.md): default 187 s quiet (five methods; four on earlier builds: 281 s
#: quiet, 993 s under load; quick 255 s quiet). Runs
#: under ~200 iterations stop learning (the grid's first occupancy update empties it), hence quick's 200.
PRESETS = {
    "default": Preset(size=64, frames=1000, iters=300, test_views=4, batch=512, spike_window=16,
                      spike_pixels=16),
    "quick": Preset(size=32, frames=200, iters=200, test_views=2, batch=512, spike_window=8, spike_pixels=16),
}  # fmt: skip


@dataclass
class DemoConfig:
    """What ``spikenerf demo`` runs; None = the preset's value (``quick`` selects the quick preset)."""

    out: Path = Path("demo_out")
    quick: bool = False
    device: str = "auto"
    size: int | None = None
    iters: int | None = None
    frames: int | None = None
    test_views: int | None = None
    scene: str = DEFAULT_SCENE
    colors: list[str] = field(default_factory=lambda: ["gray"])
    methods: list[str] = field(default_factory=lambda: list(DEMO_METHODS))

    def preset(self) -> Preset:
        """The preset with this config's explicit sizes applied (validated)."""
        p = PRESETS["quick" if self.quick else "default"]
        size = p.size if self.size is None else self.size  # an explicit 0 is refused, not the default
        iters = p.iters if self.iters is None else self.iters
        frames = p.frames if self.frames is None else self.frames
        views = p.test_views if self.test_views is None else self.test_views
        check_size(size)
        if iters < 1 or frames < 2 or views < 1:
            raise InputError(
                f"demo sizes: expected iters ≥ 1, frames ≥ 2, test views ≥ 1; found {iters}, {frames}, "
                f"{views}",
                param=("iters", "frames"),
            )
        window = min(p.spike_window, frames)
        return Preset(size, frames, iters, views, p.batch, window, p.spike_pixels)


def train_args(p: Preset) -> list[str]:
    """Extra ``spikenerf train`` flags of the demo: schedules scaled to its short runs.

    Six evaluations on one view give the training curve; the spike warm-up (a fifth of the run, the
    trainer's default too) is spelled out so that the recorded commands state it.
    """
    return [
        "--batch", str(p.batch), "--eval-every", str(max(p.iters // 6, 1)), "--eval-views", "1",
        "--ckpt-every", str(max(p.iters // 3, 1)), "--spike-warmup", str(p.iters // 5),
        "--spike-window", str(p.spike_window), "--spike-pixels", str(p.spike_pixels),
    ]  # fmt: skip


def benchmark_config(cfg: DemoConfig) -> BenchmarkConfig:
    """The one-scene benchmark the demo runs (its blur baseline: the 10 consecutive 400 fps frames, cheap and
    what the README's demo table measured; the benchmark's default is the paper's 1000 exposures)."""
    p = cfg.preset()
    return BenchmarkConfig(
        scenes=[cfg.scene], variants=list(cfg.methods), colors=list(cfg.colors), out=Path(cfg.out),
        size=p.size, frames=p.frames, iters=p.iters, device=cfg.device, test_views=p.test_views,
        extra_train_args=train_args(p), blur_views="frames",
    )  # fmt: skip


def cpu_seconds() -> float:
    """CPU time (user + system, s) of this process and its finished subprocesses (0 where unsupported)."""
    try:
        import resource
    except ImportError:  # not on Unix
        return 0.0
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


@dataclass
class DemoResult:
    """The demo's cells, its Table I (Markdown), the report's path and the measured wall and CPU time (s)."""

    cells: list[Cell]
    table: str
    report: Path
    wall_seconds: float
    cpu_seconds: float


#: fewer iterations than this tell the methods apart poorly (run_demo says so before it starts)
SHORTEST_ITERS = 150


def run_demo(cfg: DemoConfig, echo: Callable[[str], None] = print) -> DemoResult:
    """Run (or resume) the demo into ``cfg.out`` and print its table and where the report is."""
    bcfg = benchmark_config(cfg)
    echo(
        f"spikenerf demo: scene {cfg.scene}, {bcfg.size}×{bcfg.size} px, {bcfg.frames} spike steps, "
        f"{bcfg.iters} iterations per method ({', '.join(bcfg.variants)}), {', '.join(bcfg.colors)}, "
        f"device {cfg.device} → {bcfg.out}"
    )
    if bcfg.iters < SHORTEST_ITERS:
        echo(
            f"note: {bcfg.iters} iterations leave the fields nearly empty: expect every method to score "
            f"about the same (the demo's default is 300; docs/report.md)"
        )
    t0, c0 = time.perf_counter(), cpu_seconds()
    cells = benchmark_with_report(bcfg)
    wall, cpu = time.perf_counter() - t0, cpu_seconds() - c0
    from spikenerf.pipelines.benchmark.results import trained_on

    views = trained_on(bcfg)
    table = "\n\n".join(table1_markdown(cells, bcfg.variants, bcfg.scenes, c, views) for c in bcfg.colors)
    report = bcfg.out / "report.html"
    echo(f"\n{table}\n\nreport: {report.resolve()}")
    echo(f"demo finished in {wall:.0f} s wall, {cpu:.0f} s CPU (this process and its subprocesses)")
    return DemoResult(cells, table, report, wall, cpu)
