"""``spikenerf export``: a trained run's point cloud or mesh as a PLY file."""

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
from spikenerf.cli.types import BoundedInt, OutPath, device_option
from spikenerf.eval.choices import (
    DEFAULT_DENSITY_LEVEL,
    DEFAULT_MIN_OPACITY,
    DEFAULT_RESOLUTION,
    EXPORT_KINDS,
)

#: the options that shape one kind only (refused with the other, as render refuses --orbit-frames off orbit)
KIND_OPTIONS = {
    "pointcloud": ("trajectory", "orbit_frames", "min_opacity", "max_points", "precision"),
    "mesh": ("resolution", "density_level"),
}


@click.command(help="Export a trained run's geometry as a coloured point cloud or mesh (binary PLY).")
@click.argument("run", type=click.Path(path_type=Path))
@click.option(
    "--kind", type=click.Choice(EXPORT_KINDS), default="pointcloud", show_default=True,
    help="pointcloud: the rendered views' opaque pixels put back at their depth; mesh: marching cubes of the "
    "density (needs scikit-image: pip install 'spikenerf[mesh]').",
)  # fmt: skip
@click.option(
    "--trajectory", default="test", show_default=True,
    help="pointcloud: the views rendered: test (held-out views), orbit, spiral, interpolate or a FILE, a "
    "transforms.json or a nerfstudio camera_path.json (as render).",
)  # fmt: skip
@click.option("--orbit-frames", type=BoundedInt(1), default=120, show_default=True,
              help="pointcloud: views of a generated path: orbit, spiral or interpolate.")  # fmt: skip
@click.option(
    "--min-opacity", type=click.FloatRange(0, 1, max_open=True), default=DEFAULT_MIN_OPACITY,
    show_default=True, help="pointcloud: keep pixels whose accumulated opacity exceeds this.",
)  # fmt: skip
@click.option("--max-points", type=BoundedInt(1),
              help="pointcloud: keep this many points, drawn with a fixed seed [default: all].")  # fmt: skip
@click.option(
    "--resolution", type=click.IntRange(2, 1024), default=DEFAULT_RESOLUTION, show_default=True,
    help="mesh: density samples a side over the scene box.",
)  # fmt: skip
@click.option(
    "--density-level", type=click.FloatRange(0, min_open=True), default=DEFAULT_DENSITY_LEVEL,
    show_default=True,
    help="mesh: the surface's density per world unit; raise it against fog and floaters, lower it against "
    "holes (docs/export.md).",
)  # fmt: skip
@device_option()
@dataset_option
@chunk_option
@precision_option
@click.option("--overwrite", is_flag=True, help="Replace --out if it exists.")
@click.option("--quiet", "--no-progress", "quiet", is_flag=True, help="No progress bars.")
@click.option("--out", type=OutPath(), required=True, help="Output .ply file.")
def command(
    run: Path,
    kind: str,
    trajectory: str,
    orbit_frames: int,
    min_opacity: float,
    max_points: int | None,
    resolution: int,
    density_level: float,
    device: str,
    dataset: Path | None,
    chunk: int,
    precision: str,
    overwrite: bool,
    quiet: bool,
    out: Path,
) -> None:
    from spikenerf.core.errors import InputError
    from spikenerf.eval.export import export_run

    given = click.get_current_context().get_parameter_source
    for other, names in KIND_OPTIONS.items():
        for name in names if other != kind else ():
            if given(name) is ParameterSource.COMMANDLINE:
                flag = "--" + name.replace("_", "-")
                raise InputError(f"{flag} applies to --kind {other}, not to --kind {kind}")
    check_orbit_frames(trajectory)
    if out.suffix.lower() != ".ply":
        raise InputError("expected a .ply file name (export writes one PLY file)", path=out)
    check_run_folder(run)
    export_run(
        run,
        out,
        kind=kind,
        trajectory=trajectory,
        orbit_frames=orbit_frames,
        min_opacity=min_opacity,
        max_points=max_points,
        resolution=resolution,
        density_level=density_level,
        device=device,
        dataset_root=dataset,
        chunk=chunk,
        precision=precision,
        overwrite=overwrite,
        progress=not quiet,
        log=click.echo,
    )
