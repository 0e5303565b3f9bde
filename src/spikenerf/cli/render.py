"""``spikenerf render``: images, depth, a video and (``--spikes``) a novel-view spike stream from a run."""

from __future__ import annotations

from pathlib import Path

import click
from click.core import ParameterSource

from spikenerf.cli.options import (
    check_orbit_frames,
    check_run_folder,
    chunk_option,
    dataset_option,
    precision_option,
)
from spikenerf.cli.types import SEED, OutPath, device_option


@click.command(help="Render images, depth, a video and novel-view spike streams from a trained run.")
@click.argument("run", type=click.Path(path_type=Path))
@click.option(
    "--trajectory", default="test", show_default=True,
    help="test (held-out views), orbit (a closed orbit like the training path), spiral (around the mean "
    "training camera, for forward-facing captures), interpolate (a smooth path through the training poses), "
    "or a FILE: a transforms.json with frames[].transform_matrix (and its own camera and near/far, where it "
    "gives them) or a nerfstudio camera_path.json.",
)  # fmt: skip
@click.option("--spikes", is_flag=True, help="Also fire a novel-view spike stream (.dat + TFP preview).")
@click.option("--fps-video", type=float, default=30.0, show_default=True, help="Frame rate of the mp4.")
@click.option(
    "--orbit-frames", type=int, default=120, show_default=True,
    help="Views of a generated path: orbit, spiral or interpolate.",
)  # fmt: skip
@click.option(
    "--spike-steps", type=int,
    help="Spike steps along orbit/spiral/interpolate [default: the dataset's]; test/FILE: one step per pose.",
)  # fmt: skip
@click.option(
    "--seed", type=SEED, default=0, show_default=True, help="Seed of the spike accumulators' start."
)
@device_option()
@dataset_option
@chunk_option
@precision_option
@click.option("--quiet", "--no-progress", "quiet", is_flag=True, help="No progress bars.")
@click.option("--out", type=OutPath(), required=True, help="Output folder.")
def command(
    run: Path,
    trajectory: str,
    spikes: bool,
    fps_video: float,
    orbit_frames: int,
    spike_steps: int | None,
    seed: int,
    device: str,
    dataset: Path | None,
    chunk: int,
    precision: str,
    quiet: bool,
    out: Path,
) -> None:
    from spikenerf.core.errors import InputError
    from spikenerf.eval.video import render_run
    from spikenerf.scenes.render_paths import GENERATED_PATHS

    generated = "/".join(GENERATED_PATHS)
    if spike_steps is not None and not (spikes and trajectory in GENERATED_PATHS):
        raise InputError(
            f"--spike-steps sets the spike stream's length along --trajectory {generated} and needs --spikes "
            "(with test or FILE the stream has one step per pose)"
        )
    check_orbit_frames(trajectory)
    given = click.get_current_context().get_parameter_source
    if not spikes and given("seed") is ParameterSource.COMMANDLINE:
        raise InputError("--seed seeds the spike stream's accumulators and needs --spikes")
    check_run_folder(run)
    render_run(
        run,
        out,
        trajectory=trajectory,
        spikes=spikes,
        fps_video=fps_video,
        orbit_frames=orbit_frames,
        spike_steps=spike_steps,
        seed=seed,
        device=device,
        dataset_root=dataset,
        chunk=chunk,
        progress=not quiet,
        log=click.echo,
        precision=precision,
    )
