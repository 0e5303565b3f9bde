"""``spikenerf demo``: simulate, train spike-integral, Spike-NeRF and the baselines, evaluate, render, report
(resumable)."""

from __future__ import annotations

from pathlib import Path

import click

from spikenerf.cli.types import COUNT, OutPath, device_option
from spikenerf.data.choices import COLORS


def _list(value: str, allowed: tuple[str, ...], option: str) -> list[str]:
    from spikenerf.core.errors import comma_list

    return comma_list(
        value, allowed, lambda _: f"{option}: expected a comma list of {', '.join(allowed)}, found {value!r}"
    )


@click.command(
    help="Run the whole pipeline on the embedded default scene (analytic-orbs): simulate a spike camera, "
    "train spike-integral (the default), spike-nerf, nerf-recon, nerf-blur and nerf-gt, evaluate, render and "
    "write OUT/report.html. "
    "Resumable: re-running reuses finished steps. Default size: about 3 minutes on 2 idle CPU cores (187 s, "
    "docs/report.md); --quick is a smoke test, smaller but only a little faster."
)
@click.option("--out", type=OutPath(), default=Path("demo_out"), show_default=True)
@click.option("--quick", is_flag=True, help="32 px, 200 spike steps, 200 iterations (a smoke test).")
@device_option()
@click.option("--size", type=int, help="Image width = height in pixels [default 64, quick 32].")
@click.option("--iters", type=COUNT, help="Training iterations per method [default 300, quick 200].")
@click.option("--frames", type=int, help="Spike steps on the orbit [default 1000, quick 200].")
@click.option("--test-views", type=int, help="Held-out views [default 4, quick 2].")
@click.option("--scene", default=None, help="Another named scene, one (see simulate --list-scenes).")
@click.option("--color", default="gray", show_default=True, help="gray, rgb or gray,rgb.")
@click.option("--methods", default=None, help="Comma list of method variants.")
def command(
    out: Path, quick: bool, device: str, size: int | None, iters: int | None, frames: int | None,
    test_views: int | None, scene: str | None, color: str, methods: str | None,
) -> None:  # fmt: skip
    from spikenerf.core.device import resolve_device
    from spikenerf.core.errors import InputError
    from spikenerf.pipelines.benchmark.variants import VARIANTS
    from spikenerf.pipelines.demo import DEFAULT_SCENE, DEMO_METHODS, DemoConfig, run_demo
    from spikenerf.scenes.registry import list_scenes

    resolve_device(device)  # before the dataset is simulated
    names = [s.name for s in list_scenes()]
    if scene is not None and scene not in names:
        raise InputError(f"--scene: expected one scene name of {', '.join(names)}, found {scene!r}")
    cfg = DemoConfig(
        out=out, quick=quick, device=device, size=size, iters=iters, frames=frames, test_views=test_views,
        scene=scene or DEFAULT_SCENE,
        colors=_list(color, COLORS, "--color"),
        methods=_list(methods, tuple(VARIANTS), "--methods") if methods else list(DEMO_METHODS),
    )  # fmt: skip
    run_demo(cfg, echo=click.echo)
