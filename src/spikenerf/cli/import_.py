"""``spikenerf import``: a raw ``.dat`` recording (+ poses) → a dataset folder that ``train`` reads."""

from __future__ import annotations

import math
from dataclasses import fields
from pathlib import Path
from typing import Any

import click

from spikenerf.camera.modes import LAYOUTS
from spikenerf.cli import command_line
from spikenerf.cli.types import COUNT, OutPath
from spikenerf.core.errors import parse_range
from spikenerf.importing.orientation import ORIENTS

#: lower-layer parameters named unlike their flag (see ``spikenerf.cli.flag_of``)
PARAM_FLAGS = {"fov_deg": "--fov"}


@click.command(
    help="Import a raw .dat spike recording (SpikeCV config.yaml beside it) into a dataset folder."
)
@click.argument("recording", type=click.Path(path_type=Path))
@click.option("--out", type=OutPath(), required=True, help="The dataset folder to write.")
@click.option(
    "--poses",
    default="colmap",
    show_default=True,
    help="colmap (estimate with pycolmap), orbit (with --orbit), or a transforms.json, a COLMAP model "
    "folder or an LLFF poses_bounds.npy.",
)
@click.option("--orbit", help="RADIUS,ELEVATION_DEG[,TURNS[,START_AZIMUTH_DEG]] of a known orbit.")
@click.option("--height", type=int, help="Frame height [default: spike_h of config.yaml].")
@click.option("--width", type=int, help="Frame width [default: spike_w of config.yaml].")
@click.option(
    "--config", type=click.Path(path_type=Path), help="SpikeCV config.yaml [default: beside the file]."
)
@click.option("--raw-width", type=int, help="Stored row width of raw files (416 for 250×400 sps10).")
@click.option("--fps", type=float, help="Readout rate in Hz [default: config.yaml, else 40000].")
@click.option("--threshold", type=float, help="Spike threshold φ [default: config.yaml, else 1].")
@click.option(
    "--layout", type=click.Choice(LAYOUTS),
    help="Row order of the .dat file [default: config.yaml's layout, else spikecv].",
)  # fmt: skip
@click.option("--range", "frame_range", help="A:B, the steps of the recording to import.")
@click.option("--keyframe-every", type=COUNT, default=20, show_default=True, help="Steps between keyframes.")
@click.option(
    "--window", type=int, default=21, show_default=True, help="TFP window of the keyframes (odd frames)."
)
@click.option(
    "--test-every", type=int, default=8, show_default=True, help="Hold out every n-th keyframe (0 = none)."
)
@click.option(
    "--fov",
    type=float,
    help="Horizontal field of view in degrees [default: the pose source's intrinsics; needed where it has "
    "none].",
)
@click.option(
    "--overlap", type=int, default=10, show_default=True, help="COLMAP sequential matching overlap."
)
@click.option(
    "--loop-pairs/--no-loop-pairs",
    default=True,
    show_default=True,
    help="COLMAP also matches every pair of keyframes (closes an orbit); off: sequential only.",
)
@click.option(
    "--min-registered",
    type=float,
    default=0.5,
    show_default=True,
    help="Fraction of keyframes COLMAP must register.",
)
@click.option(
    "--keyframe-images",
    type=click.Choice(["tfp", "learned"]),
    default="tfp",
    show_default=True,
    help="Keyframe reconstruction, for COLMAP's input and the test views (with any --poses): TFP (--window) "
    "or the shipped learned reconstructor (at its trained window).",
)
@click.option(
    "--max-features", type=int, default=8192, show_default=True, help="COLMAP SIFT features per keyframe."
)
@click.option(
    "--sift-peak",
    type=float,
    default=round(0.02 / 3, 6),
    show_default=True,
    help="COLMAP SIFT peak (contrast) threshold; lower finds more features in low-contrast keyframes.",
)
@click.option("--affine-sift", is_flag=True, help="COLMAP affine-shape SIFT with domain-size pooling.")
@click.option(
    "--final-ba/--no-final-ba",
    default=True,
    show_default=True,
    help="A last global bundle adjustment of the COLMAP model with a robust (Cauchy) loss.",
)
@click.option(
    "--contrast",
    type=float,
    default=0.0,
    show_default=True,
    help="Local contrast normalisation of the keyframes, Gaussian sigma in pixels (0 = off).",
)
@click.option(
    "--smooth",
    type=int,
    default=0,
    show_default=True,
    help="COLMAP: smooth the keyframe poses over this many steps (local quadratic fit; 0 = off).",
)
@click.option(
    "--orient",
    type=click.Choice(ORIENTS),
    default="up",
    show_default=True,
    help="Turn the scene upright (the cameras' up to +Z), then about +Z so that its vertical planes (walls, "
    "box sides in the sparse points) lie along the axes, or for the smallest box where there are none; "
    "up-box: always the smallest box; none: keep the source's axes. Then the unit box is fitted (to the "
    "sparse points, or around the cameras' focus). A scene_box or LLFF bounds always keep their axes.",
)
@click.option("--overwrite", is_flag=True, help="Replace an existing output folder.")
@click.option("--verbose", is_flag=True, help="Show COLMAP's log.")
def command(**kw: Any) -> None:
    from spikenerf.importing.importer import import_recording
    from spikenerf.importing.options import ImportOptions

    frame_range = None if kw["frame_range"] is None else parse_range(kw["frame_range"], "frame_range")
    flag = {"fov_deg": "fov"}  # ImportOptions field → click parameter, where the names differ
    given = {f.name: kw[flag.get(f.name, f.name)] for f in fields(ImportOptions) if f.name != "command"}
    opts = ImportOptions(**given | {"frame_range": frame_range, "command": command_line()})
    if kw["fov"] is not None and 0 < kw["fov"] < NARROW_FOV:  # (transforms.json keeps its angle in radians)
        click.echo(
            f"spikenerf: warning: --fov is in degrees: {kw['fov']:g}° is a very narrow lens (in radians "
            f"{kw['fov']:g} would be {math.degrees(kw['fov']):.3g}°)",
            err=True,
        )
    out = import_recording(kw["recording"], kw["out"], opts)
    from spikenerf.data.dataset import load_dataset

    ds = load_dataset(out)
    imported = ds.config["imported"]
    click.echo(
        f"wrote {out}: {len(ds.trajectory)} steps, {ds.intrinsics.width}×{ds.intrinsics.height}, poses from "
        f"{imported['poses']} ({imported['poses_known']} poses, {imported['keyframes']} keyframes), "
        f"{len(ds.test)} test view{'' if len(ds.test) == 1 else 's'}"
        + (f"; {imported['pose_note']}" if imported.get("pose_note") else "")
    )
    if problem := held_pose_warning(imported, len(ds.trajectory)):
        click.echo(f"spikenerf: warning: {problem}", err=True)
    if (left := imported["keyframes"] - len(imported.get("test_keyframes") or [])) < 2:
        click.echo(
            f"spikenerf: warning: {left} keyframe{'' if left == 1 else 's'} left after the test views: "
            "`train` refines poses between 2 or more, so train with --no-refine-poses (and --no-holdout "
            "where its guard bands leave too few steps), or import more steps (or with --test-every 0)",
            err=True,
        )


#: a --fov below this many degrees is warned about: a value in radians, as transforms.json holds it?
NARROW_FOV = 3.0


def held_pose_warning(imported: dict, n: int) -> str | None:
    """What to warn when steps of an import (``imported``: its config.yaml's, ``n`` steps) lie beyond its
    poses' steps by more than the one interval that is extrapolated, so that their pose is held still
    (:func:`spikenerf.importing.interpolation.held_steps`); None when no step does."""
    from spikenerf.importing.interpolation import held_steps

    keys, first = imported.get("pose_steps") or [], int(imported["range"][0])
    if len(keys) < 2:
        return None
    before, after = held_steps(keys, n)
    if not before + after:
        return None
    spans = [f"{first}..{first + before - 1}"] if before else []
    spans += [f"{first + n - after}..{first + n - 1}"] if after else []
    lo, hi = first + min(keys), first + max(keys)
    none = "" if imported.get("test_keyframes") else " (none remains anywhere)"
    return (
        f"steps {' and '.join(spans)} ({before + after} of the {n} imported) lie beyond the poses' steps "
        f"{lo}..{hi} and the one interval extrapolated: they keep a held pose, as if the camera stood "
        f"still, and hold no test view{none}; --range {lo}:{hi + 1} imports only the posed steps"
    )
