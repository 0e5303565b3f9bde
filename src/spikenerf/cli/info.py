"""``spikenerf info PATH``: summarise a ``.dat`` spike file, or a dataset/run folder (``spikenerf.data``)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import click

from spikenerf.cli.types import frame_size_options
from spikenerf.core.errors import InputError

#: file types that are never a spike recording (a dataset's or run's other files)
NOT_SPIKES = (".yaml", ".yml", ".json", ".pt", ".png", ".jpg", ".exr", ".npy", ".npz", ".csv", ".html")


def dat_recording(path: Path, height: int | None, width: int | None, raw_width: int | None) -> Any:
    """The recording's config (``camera.spikecv.recording_config``) with ``raw_width`` where it is given;
    one warning line when the file also reads as a raw sps10 recording (``camera.io.raw_width_guess``)."""
    from spikenerf.camera.io import raw_width_guess
    from spikenerf.camera.spikecv import recording_config

    if path.suffix.lower() in NOT_SPIKES:
        raise InputError(f"is a {path.suffix} file, not a .dat spike recording", path=path)
    config = recording_config(path, height, width)
    config = config if raw_width is None else dataclasses.replace(config, raw_width=raw_width)
    if config.raw_width is None and (raw := raw_width_guess(path, config.height, config.width)) is not None:
        click.echo(
            f"spikenerf: warning: {path} also reads as raw sps10 rows of {raw} columns whose last "
            f"{raw - config.width} stay silent: if it is a raw recording, pass --raw-width {raw}",
            err=True,
        )
    return config


def describe_dat(
    path: Path, height: int, width: int, layout: str, raw_width: int | None, fps: float
) -> list[str]:
    """The summary lines of a ``.dat`` file: frames, duration, mean rate and per-pixel rate percentiles."""
    from spikenerf.camera.io import count_frames, frame_bytes
    from spikenerf.camera.stats import dat_rate_summary

    frames = count_frames(path, height, width, raw_width)
    stored = "" if raw_width is None else f" (stored rows {raw_width} wide, {raw_width - width} stripped)"
    lines = [
        f"file: {path}",
        f"frame: {height}×{width} pixels{stored}, {frame_bytes(height, width, raw_width)} bytes, "
        f"layout {layout}",
        f"frames: {frames}",
        f"duration: {frames / fps * 1e3:.4g} ms at {fps:g} Hz",
    ]
    if frames == 0:
        return [*lines, "spike rate: (no frames)"]
    summary = dat_rate_summary(path, height, width, layout, raw_width)
    rate = summary["mean_rate"]
    lines.append(
        f"mean spike rate: {rate:.4g} spikes/pixel/step ({rate * fps:.4g} Hz), {summary['spikes']} spikes"
    )
    pct = ", ".join(f"p{q} {v:.4g}" for q, v in summary["rate_percentiles"].items())
    lines.append(f"per-pixel firing rate (spikes/step): {pct}")
    lines.append(f"silent pixels: {summary['silent_fraction'] * 100:.3g}%")
    return lines


@click.command(
    help="Summarise a dataset folder, a run folder or a .dat spike file (needs --height/--width, or a "
    "SpikeCV config.yaml beside it)."
)
@click.argument("path", type=click.Path(path_type=Path))
@frame_size_options
@click.option("--layout", type=click.Choice(["spikecv", "topdown"]), default="spikecv", show_default=True)
@click.option("--raw-width", type=int, help="Stored row width, e.g. 416 for raw 250×400 camera files.")
@click.option(
    "--fps",
    type=float,
    help="Readout rate in Hz [default: fps of the config.yaml beside the file, else 40000].",
)
def command(
    path: Path, height: int | None, width: int | None, layout: str, raw_width: int | None, fps: float | None
) -> None:
    if not path.exists():
        raise InputError("no such file or folder", path=path)
    from spikenerf.core.marker import folder_kind

    if path.is_dir() and folder_kind(path) == "run":  # a run's missing file is named as such
        from spikenerf.train.run import describe_run

        click.echo(describe_run(path))
        return
    if path.is_dir():
        from spikenerf.data.summary import describe

        click.echo(describe(path))
        return
    config = dat_recording(path, height, width, raw_width)
    height, width, raw_width = config.height, config.width, config.raw_width
    fps = fps if fps is not None else config.fps or 40000.0
    if not 0 < fps < math.inf:
        raise InputError(f"--fps must be a finite number > 0, found {fps}")
    click.echo("\n".join(describe_dat(path, height, width, layout, raw_width, fps)))
