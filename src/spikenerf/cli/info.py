"""``spikenerf info PATH``: summarise a ``.dat`` spike file, or a dataset, run or render folder."""

from __future__ import annotations

import math
from pathlib import Path

import click

from spikenerf.cli.types import dat_recording, frame_size_options
from spikenerf.core.errors import InputError


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


def describe_render(folder: Path) -> list[str]:
    """The summary lines of a ``render`` output folder: its ``render.json`` (what was rendered, from which
    run) and each novel-view spike stream it holds (:func:`describe_dat`); an unfinished render says so."""
    import json

    manifest = folder / "render.json"
    if not manifest.is_file():
        return [f"render folder: {folder}", "unfinished (no render.json): run its command again to resume"]
    try:
        info = json.loads(manifest.read_text(encoding="utf-8"))
        width, height = (int(v) for v in info["size"])
        files = info.get("files") or {}
    except (OSError, ValueError, TypeError, KeyError) as err:
        raise InputError(f"cannot read it ({type(err).__name__}: {err})", path=manifest) from None
    lines = [
        f"render folder: {folder}",
        f"run: {info.get('run')}",
        f"trajectory: {info.get('trajectory')}, {info.get('views')} views of {width}×{height}, "
        f"video {files.get('video')}",
    ]
    streams = [name for name in files.get("spikes") or [] if str(name).endswith(".dat")]
    if streams:
        lines.append(f"novel spike stream: {info.get('spike_steps')} steps, φ {info.get('threshold')}")
    for name in streams:
        config = dat_recording(folder / name, height, width, width)  # plain frames: no raw-layout guess
        lines += ["", *describe_dat(folder / name, height, width, "spikecv", None, config.fps or 40000.0)]
    return lines


@click.command(
    help="Summarise a dataset, run or render folder, or a .dat spike file (needs --height/--width, or a "
    "SpikeCV config.yaml beside it)."
)
@click.argument("path", type=click.Path(path_type=Path))
@frame_size_options
@click.option(
    "--layout", type=click.Choice(["spikecv", "topdown"]), help="Row order of a .dat file [default: spikecv]."
)
@click.option("--raw-width", type=int, help="Stored row width, e.g. 416 for raw 250×400 camera files.")
@click.option(
    "--fps",
    type=float,
    help="Readout rate in Hz [default: fps of the config.yaml beside the file, else 40000].",
)
def command(
    path: Path,
    height: int | None,
    width: int | None,
    layout: str | None,
    raw_width: int | None,
    fps: float | None,
) -> None:
    if not path.exists():
        raise InputError("no such file or folder", path=path)
    from spikenerf.core.marker import folder_kind

    if path.is_dir():
        dat_options = {"--height": height, "--width": width, "--layout": layout, "--raw-width": raw_width}
        given = [flag for flag, value in {**dat_options, "--fps": fps}.items() if value is not None]
        if given:
            raise InputError(
                f"{', '.join(given)}: for a .dat file only (a folder's own files give its size and rate)",
                path=path,
            )
    layout = layout or "spikecv"

    if path.is_dir() and folder_kind(path) == "run":  # a run's missing file is named as such
        from spikenerf.train.run import describe_run

        click.echo(describe_run(path))
        return
    if path.is_dir() and folder_kind(path) == "render":
        click.echo("\n".join(describe_render(path)))
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
