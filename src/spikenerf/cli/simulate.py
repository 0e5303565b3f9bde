"""``spikenerf simulate``: render a scene along a fast path, simulate spike cameras, write a dataset."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import click
from click.core import ParameterSource

from spikenerf.camera.modes import COLORS, NOISE_RANGES, NOISES
from spikenerf.cli import command_line
from spikenerf.cli.options import noise_param_option, parse_noise_params
from spikenerf.cli.types import COUNT, SEED, BoundedInt, OutPath
from spikenerf.core.errors import InputError

DEFAULT_SIZE = 200
DEFAULT_STEPS = 1000
DEFAULT_TEST_VIEWS = 8
ORBIT_OPTIONS = ("frames", "duration", "radius", "elevation", "elevation_sweep", "turns")
FLOAT_OPTIONS = (
    "fps", "threshold", "radius", "elevation", "elevation_sweep", "turns", "duration", "blur_fps"
)  # fmt: skip


#: the camera's colour modes (``camera/modes.py``: no torch import, so `simulate --help` stays quick)
CAMERA_COLORS = COLORS
#: lower-layer parameters named unlike their flag (see ``spikenerf.cli.flag_of``)
PARAM_FLAGS = {
    "colors": "--color",
    "elevation_deg": "--elevation",
    "frame_range": "--sequence-range",
    **{name: f"--noise-param {name}" for name in NOISE_RANGES},
}


def _colors(color: str) -> tuple[str, ...]:
    return CAMERA_COLORS if color == "all" else (color,)


def _orbit_steps(frames: int | None, duration: float | None, fps: float) -> int:
    """Number of spike steps from ``--frames`` / ``--duration`` (default 1000 steps)."""
    from spikenerf.scenes.trajectory import MAX_STEPS, path_steps

    if not 0 < fps < math.inf:
        raise InputError(f"--fps must be a finite number > 0, found {fps:g}")
    if duration is not None:
        n = path_steps(duration, fps)  # (a finite duration giving 1 to MAX_STEPS steps that memory holds)
        if frames is not None and frames != n:
            raise InputError(
                f"--frames {frames} and --duration {duration:g} s at {fps:g} Hz ({n} steps) disagree"
            )
        frames = n
    frames = DEFAULT_STEPS if frames is None else frames
    if not 1 <= frames < MAX_STEPS:
        raise InputError(f"--frames must lie within [1, {MAX_STEPS:.3g}), found {frames}")
    if not math.isfinite(frames / fps):  # (a tiny --fps: the path would last for ever)
        raise InputError(f"--fps {fps:g} makes the path of {frames} steps last longer than any duration")
    return frames


@click.command(help="Render a scene along a fast path and simulate a spike camera into a dataset folder.")
@click.option("--scene", help="A named scene (see --list-scenes), e.g. analytic-orbs.")
@click.option("--blend", type=click.Path(path_type=Path), help="A user .blend file (needs Blender).")
@click.option(
    "--sequence", type=click.Path(path_type=Path), help="transforms.json of an image sequence + poses."
)
@click.option("--sequence-range", help="A:B, a slice of the sequence's listed frames.")
@click.option("--out", type=OutPath(), help="The dataset folder to write.")
@click.option(
    "--width", type=int, help=f"Frame width in pixels [default: {DEFAULT_SIZE}; sequences: native]."
)
@click.option(
    "--height", type=int, help=f"Frame height in pixels [default: {DEFAULT_SIZE}; sequences: native]."
)
@click.option("--frames", type=int, help=f"Spike steps on the orbit [default: {DEFAULT_STEPS}].")
@click.option("--fps", type=float, default=40000.0, show_default=True, help="Spike readout rate (Hz).")
@click.option("--color", type=click.Choice([*CAMERA_COLORS, "all"]), default="gray", show_default=True)
@click.option("--threshold", type=float, default=1.0, show_default=True, help="Spike threshold φ.")
@click.option("--noise", type=click.Choice(NOISES), default="ideal", show_default=True)
@noise_param_option
@click.option("--seed", type=SEED, default=0, show_default=True, help="Camera (and render) seed.")
@click.option(
    "--warmup",
    type=BoundedInt(0),
    default=0,
    show_default=True,
    help="Camera warm-up steps on the first frame.",
)
@click.option(
    "--spp", type=int, help="Samples per pixel [default: Blender 16, analytic 4 (2×2 supersampling)]."
)
@click.option("--test-views", type=int, help=f"Held-out views off the orbit [default: {DEFAULT_TEST_VIEWS}].")
@click.option("--eval-views", type=click.Path(path_type=Path), help="transforms.json of held-out test poses.")
@click.option(
    "--radius", type=float, help="Orbit radius [default: analytic 4; Blender: the scene fits the view]."
)
@click.option("--elevation", type=float, help="Orbit elevation in degrees, within (−90, 90) [default: 30].")
@click.option(
    "--elevation-sweep", type=float,
    help="Peak-to-peak elevation change in degrees, one sine period over the path (30 at --elevation 30: "
    "15°–45°; the test views then lie at 0° and 60°) [default: 0].",
)  # fmt: skip
@click.option("--turns", type=float, help="Full turns over the path [default: 1].")
@click.option("--duration", type=float, help="Path duration in seconds [default: frames / fps = 0.025].")
@click.option("--steps-per-frame", type=COUNT, help="Sequences: spike steps per source image [default: 1].")
@click.option(
    "--interpolate", is_flag=True, help="Sequences: blend between source images instead of holding."
)
@click.option(
    "--gt-every", type=int, default=10, show_default=True, help="Store the sharp render every k steps."
)
@click.option(
    "--blur-fps", type=float, default=400.0, show_default=True, help="Conventional camera fps (0 = none)."
)
@click.option(
    "--blur-views", default="frames", show_default=True,
    help="Blur exposures: 'frames' = consecutive non-overlapping frames (PNGs; 10 for 1000 steps, 400 fps), "
    "'all' = one exposure centred on every step (the paper's baseline, 1000 views), or N evenly spaced "
    "centres; 'all' and N are stored as one float16 array blur/views.npy.",
)  # fmt: skip
@click.option(
    "--raw-width", type=int,
    help="Also write the gray stream as a camera would record it: DATASET/raw/recording.dat with this many "
    "columns per row (416 for a 400-wide raw sps10 file; the extra ones zero) and a SpikeCV config.yaml, "
    "no poses (try `spikenerf import` on it, docs/real-data.md).",
)  # fmt: skip
@click.option("--list-scenes", is_flag=True, help="List the named scenes and exit.")
@click.option("--overwrite", is_flag=True, help="Replace an existing output folder.")
@click.option(
    "--jobs", type=click.IntRange(min=1), default=1, show_default=True,
    help="Processes rendering frames at once (analytic scenes; Blender and sequences render in one).",
)  # fmt: skip
@click.option("--no-progress", "--quiet", "no_progress", is_flag=True, help="Hide the progress bars.")
def command(**kw: Any) -> None:
    from spikenerf.scenes import registry

    if kw["list_scenes"]:
        click.echo(registry.format_scene_list())
        return
    chosen = [name for name in ("scene", "blend", "sequence") if kw[name] is not None]
    if len(chosen) != 1:
        raise InputError(f"give exactly one of --scene, --blend, --sequence (found {len(chosen)})")
    if kw["out"] is None:
        raise InputError("--out DIR is required (the dataset folder to write)")
    if kw["test_views"] is not None and kw["eval_views"] is not None:
        raise InputError("give either --test-views N or --eval-views transforms.json, not both")
    for name in ("width", "height", "spp", "test_views"):
        if kw[name] is not None and (kw[name] < 1 if name != "test_views" else kw[name] < 0):
            raise InputError(
                f"--{name.replace('_', '-')} must be ≥ {0 if name == 'test_views' else 1}, found {kw[name]}"
            )
    for name in FLOAT_OPTIONS:  # nan/inf would write NaN poses or hang the camera
        if kw[name] is not None and not math.isfinite(kw[name]):
            raise InputError(f"--{name.replace('_', '-')}: expected a finite number, found {kw[name]}")
    source_of = click.get_current_context().get_parameter_source
    if kw["blur_fps"] == 0 and source_of("blur_views") != ParameterSource.DEFAULT:
        raise InputError("--blur-views: there is no blur camera with --blur-fps 0")
    from spikenerf.core.marker import check_inputs_outside, check_output

    check_output(kw["out"], "dataset", overwrite=bool(kw["overwrite"]), replace=True)
    inputs = [kw["sequence"], kw["eval_views"], kw["blend"]]
    check_inputs_outside(kw["out"], inputs)  # replacing --out whole would delete them
    source, extra = _sequence_source(kw) if kw["sequence"] is not None else _scene_source(kw, registry)
    steps, threshold = len(source.trajectory), float(kw["threshold"])
    if threshold > steps:  # (said before the renders, not after)
        click.echo(
            f"spikenerf: warning: --threshold {threshold:g}: a white pixel fires once every {threshold:g} "
            f"steps, more than the {steps}-step path: the stream holds few spikes, if any",
            err=True,
        )
    from spikenerf.capture.blur import exposure_length, parse_blur_views
    from spikenerf.capture.options import SimulateOptions
    from spikenerf.capture.simulate import simulate_dataset

    options = SimulateOptions(
        colors=_colors(str(kw["color"])),
        threshold=float(kw["threshold"]),
        noise=str(kw["noise"]),
        noise_params=parse_noise_params(kw["noise_params"]),
        seed=int(kw["seed"]),
        warmup=int(kw["warmup"]),
        gt_every=int(kw["gt_every"]),
        blur_fps=float(kw["blur_fps"]),
        blur_views=parse_blur_views(kw["blur_views"]),
        overwrite=bool(kw["overwrite"]),
        command=command_line(),
        extra=extra,
        raw_width=kw["raw_width"],
    )
    out = simulate_dataset(source, Path(kw["out"]), options, progress=not kw["no_progress"], jobs=kw["jobs"])
    k, traj = source.intrinsics, source.trajectory
    click.echo(
        f"wrote {out}: {len(traj)} step{'' if len(traj) == 1 else 's'} at {traj.fps:g} Hz, "
        f"{k.width}×{k.height}, " + ", ".join(options.colors)
    )
    if options.blur_fps > 0 and (size := exposure_length(traj.fps, options.blur_fps)) > len(traj):
        click.echo(
            f"spikenerf: warning: one --blur-fps {options.blur_fps:g} exposure spans {size:.6g} steps, more "
            f"than the {len(traj)}-step path: every blur view is the mean of the whole path",
            err=True,
        )


def _scene_source(kw: dict, registry: Any) -> tuple[Any, dict]:
    """A named scene or .blend on an orbit (with its novel test views) and the config entries it adds."""
    import numpy as np

    from spikenerf.scenes.trajectory import held_out_elevations, novel_views, orbit

    if kw["sequence_range"] is not None or kw["steps_per_frame"] is not None or kw["interpolate"]:
        raise InputError("--sequence-range, --steps-per-frame and --interpolate apply to --sequence only")
    fps = float(kw["fps"])
    steps = _orbit_steps(kw["frames"], kw["duration"], fps)
    if kw["blend"] is not None and Path(kw["blend"]).suffix.lower() != ".blend":
        raise InputError("--blend: expected a Blender .blend file", path=kw["blend"])
    scene = kw["scene"] if kw["scene"] is not None else kw["blend"]
    default_radius, center = registry.default_orbit(scene, int(kw["seed"]))
    radius = default_radius if kw["radius"] is None else float(kw["radius"])
    elevation = registry.DEFAULT_ELEVATION if kw["elevation"] is None else float(kw["elevation"])
    turns = 1.0 if kw["turns"] is None else float(kw["turns"])
    sweep = 0.0 if kw["elevation_sweep"] is None else float(kw["elevation_sweep"])
    if not abs(elevation) < 90:  # at ±90° every step of the orbit would be the same pose
        raise InputError(f"--elevation must lie strictly between −90 and 90 degrees, found {elevation:g}")
    if sweep and (sweep < 0 or abs(elevation) + sweep / 2 >= 90):
        raise InputError(
            f"--elevation-sweep must be ≥ 0 and keep the elevation inside (−90°, 90°), found {sweep:g} "
            f"at --elevation {elevation:g}"
        )
    width = DEFAULT_SIZE if kw["width"] is None else int(kw["width"])
    height = DEFAULT_SIZE if kw["height"] is None else int(kw["height"])
    views = DEFAULT_TEST_VIEWS if kw["test_views"] is None else int(kw["test_views"])
    if kw["eval_views"] is not None:  # read first: its poses are the test views the estimate counts
        from spikenerf.data.camera_path import read_pose_file

        test_poses = read_pose_file(kw["eval_views"], (width, height))
        views = len(test_poses)
    _check_resources(kw, _size_params(kw), width, height, steps, views)
    trajectory = orbit(radius, elevation, turns, steps / fps, fps, center=center, elevation_sweep_deg=sweep)
    if turns == 0 and not sweep and steps > 1:
        click.echo(
            "spikenerf: warning: --turns 0 without --elevation-sweep: every step has the same pose (a "
            "radiance field cannot be trained from one viewpoint)",
            err=True,
        )
    if kw["eval_views"] is None:
        test_poses = np.zeros((0, 4, 4))
        if views:
            try:
                below_above = held_out_elevations(elevation, sweep)
            except InputError as err:
                raise InputError(f"{err.message}; give --eval-views or --test-views 0") from None
            test_poses = novel_views(radius, views, below_above, center)
    source = registry.make_scene_source(
        scene, width, height, trajectory, test_poses, kw["spp"], int(kw["seed"])
    )
    extra = {
        "trajectory": {
            "kind": "orbit",
            "radius": radius,
            "center": list(center),
            "elevation_deg": elevation,
            **({"elevation_sweep_deg": sweep} if sweep else {}),
            "turns": turns,
            "duration_s": steps / fps,
        }
    }
    settings = getattr(source, "settings", None)  # the Blender backend keeps spp in its render settings
    spp = getattr(settings, "spp", None) or getattr(source, "supersample", 0) ** 2 or kw["spp"]
    extra["spp"] = spp if spp is None else int(spp)
    if kw["spp"] is not None and spp is not None and int(spp) != int(kw["spp"]):
        got = f"{int(spp)} sample{'' if int(spp) == 1 else 's'}"
        click.echo(f"spikenerf: warning: --spp {kw['spp']} renders {got} per pixel (a k × k grid)", err=True)
    box = np.asarray(source.scene_box, dtype=np.float64)
    views_from = "--eval-views" if kw["eval_views"] is not None else f"--radius {radius:g}"
    for what, poses, flag in (("the orbit", trajectory.poses, f"--radius {radius:g}"),
                              ("a test view", test_poses, views_from)):  # fmt: skip
        centres = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)[:, :3, 3]
        inside = np.all((centres > box[0]) & (centres < box[1]), axis=1)
        if inside.any():
            where = "lies inside" if inside.all() or what == "a test view" else "passes inside"
            click.echo(
                f"spikenerf: warning: {what} {where} the scene box {box[0].tolist()} to "
                f"{box[1].tolist()} ({flag}): a camera inside the scene sees little of it",
                err=True,
            )
    return source, extra


#: the options that set a simulation's memory and disk, as ``kw`` names them
SIZE_OPTIONS = ("width", "height", "frames", "duration", "fps", "spp", "test_views", "eval_views", "color",
                "blur_views", "blur_fps", "gt_every")  # fmt: skip


def _size_params(kw: dict, always: tuple[str, ...] = ("width", "height", "frames")) -> str:
    """The size options the command line gave (a refusal names them, not options the user did not give),
    else ``always``; joined with ``/`` for :func:`_check_resources`."""
    given = [name for name in SIZE_OPTIONS if kw.get(name) not in (None, 0) and _given(name)]
    return "/".join(given or always)


def _given(name: str) -> bool:
    context = click.get_current_context(silent=True)
    source = context.get_parameter_source(name) if context is not None else None
    return source is ParameterSource.COMMANDLINE


def _check_resources(kw: dict, params: str, width: int, height: int, steps: int, views: int) -> None:
    """Refuse (InputError naming ``params``, shown as their flags) a run larger than this machine's memory
    or free disk."""
    from spikenerf.capture.blur import blur_window_count
    from spikenerf.capture.simulate import check_simulate_resources

    blur = blur_window_count(steps, kw["fps"], kw["blur_fps"] or 0.0, kw["blur_views"])  # --blur-views too
    check_simulate_resources(
        Path(kw["out"]), params, width=width, height=height, steps=steps, colors=_colors(str(kw["color"])),
        test_views=views, spp=kw["spp"] or 16, gt_every=max(1, int(kw["gt_every"])), blur_frames=blur,
    )  # fmt: skip


def _sequence_source(kw: dict) -> tuple[Any, dict]:
    """An image sequence with poses (its own trajectory and optional eval views)."""
    named = (*ORBIT_OPTIONS, "test_views", "spp")
    given = [f"--{name.replace('_', '-')}" for name in named if kw[name] is not None]
    if given:
        raise InputError(
            f"{', '.join(given)}: not used with --sequence (its poses come from the file; "
            "use --sequence-range, --steps-per-frame and --eval-views)"
        )
    from spikenerf.core.errors import parse_range
    from spikenerf.scenes.sequence import SequenceSource

    given_range = kw["sequence_range"]
    frame_range = None if given_range is None else parse_range(given_range, "sequence_range")
    source = SequenceSource(
        Path(kw["sequence"]),
        width=kw["width"],
        height=kw["height"],
        frame_range=frame_range,
        steps_per_frame=1 if kw["steps_per_frame"] is None else int(kw["steps_per_frame"]),
        interpolate=bool(kw["interpolate"]),
        eval_views=kw["eval_views"],
        fps=float(kw["fps"]),
    )
    k = source.intrinsics
    _warn_stretch(source.native_size, kw["width"], kw["height"])
    steps = len(source.trajectory)
    params = "width/height/sequence_range/steps_per_frame/eval_views"
    _check_resources(kw, params, k.width, k.height, steps, source.test_view_count)
    extra = {
        "trajectory": {
            "kind": "sequence",
            "transforms": str(kw["sequence"]),
            "range": kw["sequence_range"],
            "steps_per_frame": kw["steps_per_frame"] or 1,
            "interpolate": bool(kw["interpolate"]),
        }
    }
    return source, extra


def _warn_stretch(native: tuple[int, int], width: int | None, height: int | None) -> None:
    """One warning line when --width and --height together change the images' aspect ratio by more than
    1 % and more than rounding either one alone would (16×100 from 32×24 images stretches them)."""
    if width is None or height is None:
        return
    w0, h0 = native
    want_h, want_w = h0 * width / w0, w0 * height / h0  # what --width alone, --height alone would give
    if abs(height - want_h) > max(0.5, 0.01 * want_h) and abs(width - want_w) > max(0.5, 0.01 * want_w):
        click.echo(
            f"spikenerf: warning: --width {width} --height {height} stretches the {w0}×{h0} images (aspect "
            f"{w0 / h0:.3g} → {width / height:.3g}); give only one of them to keep the aspect ratio",
            err=True,
        )
