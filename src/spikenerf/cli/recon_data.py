"""``spikenerf recon-data --out DIR``: training pairs (spike window → sharp frame) for the reconstructor."""

from __future__ import annotations

import math
import shlex
import sys
from pathlib import Path

import click
from click.core import ParameterSource

from spikenerf.camera.modes import COLORS, NOISES
from spikenerf.camera.reconstruct import DEFAULT_WINDOW
from spikenerf.cli.types import SEED, OutPath
from spikenerf.core.errors import InputError, comma_list

#: parameters named otherwise than their flags (the CLI maps an error's parameter to its flag)
PARAM_FLAGS = {"scene": "--scene", "gt_every": "--gt-every"}  # (the latter: simulate's, in a hint)


@click.command(
    help="Write (spike window of K steps, sharp frame at its middle step) pairs for `spikenerf recon-train`: "
    "random procedural scenes for training (plus --scene Blender/analytic scenes and --sequence image "
    "sequences, --natural photographs), held-out analytic scenes (and photographs) for validation; gray, "
    "per-channel RGB and Bayer planes; ideal and "
    "realistic noise; still, orbiting and panning cameras; a log-uniform brightness range. Resumable: "
    "re-running the same command finishes an interrupted folder."
)
@click.option("--out", required=True, type=OutPath(), help="Pair folder to write.")
@click.option(
    "--train-draws",
    type=click.IntRange(min=1),
    default=1400,
    show_default=True,
    help="Random draws for the train split (a draw gives 1 gray, 3 RGB or 4 Bayer samples).",
)
@click.option(
    "--val-draws",
    type=click.IntRange(min=2),
    default=96,
    show_default=True,
    help="Random draws for the held-out val split.",
)
@click.option("--size", type=click.IntRange(min=16), default=64, show_default=True, help="Sample side P.")
@click.option(
    "--window", type=int, default=DEFAULT_WINDOW, show_default=True, help="K, steps per spike window (odd)."
)
@click.option(
    "--color",
    "modes",
    default="gray,rgb,bayer",
    show_default=True,
    help="Colour modes to draw from, comma-separated.",
)
@click.option(
    "--noise",
    "noises",
    default="ideal,realistic",
    show_default=True,
    help="Noise presets to draw from, comma-separated.",
)
@click.option(
    "--brightness",
    default="0.04:1.0",
    show_default=True,
    help="LO:HI of the log-uniform brightness scale of the radiance (0 < LO ≤ HI ≤ 1e6).",
)
@click.option(
    "--max-speed",
    type=float,
    default=1.5,
    show_default=True,
    help="Largest camera angular speed, degrees per step (the paper's orbit: 0.36).",
)
@click.option("--threshold", type=float, default=1.0, show_default=True, help="Camera threshold φ.")
@click.option(
    "--scene",
    "scenes",
    multiple=True,
    help="Also draw train pairs along this scene's default orbit (a Blender scene name or "
    ".blend file; needs bpy). Repeatable.",
)
@click.option(
    "--sequence",
    "sequences",
    multiple=True,
    type=click.Path(path_type=Path),
    help="Also draw train pairs from this image sequence (transforms.json). Repeatable.",
)
@click.option(
    "--extra-draws",
    type=click.IntRange(min=0),
    default=48,
    show_default=True,
    help="Draws per --scene / --sequence source.",
)
@click.option(
    "--natural",
    "natural_draws",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    help="Also draw this many train pairs from photographs that scikit-image ships, filmed by a panning, "
    "rolling or zooming camera (held-out photographs join the val split; needs scikit-image).",
)
@click.option("--seed", type=SEED, default=0, show_default=True)
def command(
    out: Path,
    train_draws: int,
    val_draws: int,
    size: int,
    window: int,
    modes: str,
    noises: str,
    brightness: str,
    max_speed: float,
    threshold: float,
    scenes: tuple[str, ...],
    sequences: tuple[Path, ...],
    extra_draws: int,
    natural_draws: int,
    seed: int,
) -> None:
    from spikenerf.recon.generate import VAL_SCENES, write_pairs
    from spikenerf.recon.pairs import PairConfig

    cfg = PairConfig(
        size=size,
        window=_window(window),
        modes=_choices("--color", modes, COLORS),
        noises=_choices("--noise", noises, NOISES),
        brightness=_range(brightness),
        max_speed=max_speed,
        threshold=threshold,
    )
    if not (math.isfinite(max_speed) and math.isfinite(threshold) and max_speed >= 0 and threshold > 0):
        raise InputError(
            f"--max-speed must be finite ≥ 0 and --threshold finite > 0, found {max_speed}, {threshold}"
        )
    if set(scenes) & set(VAL_SCENES):
        raise InputError(f"--scene: {', '.join(VAL_SCENES)} are held out for validation")
    given = click.get_current_context().get_parameter_source("extra_draws") is ParameterSource.COMMANDLINE
    if given and not (scenes or sequences):
        raise InputError("--extra-draws sets the draws of each --scene or --sequence source; none is given")
    extra = _sources(scenes, sequences, size, window, seed)
    command_line = "spikenerf " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    write_pairs(out, cfg, train_draws, val_draws, seed, extra, extra_draws, command_line,
                natural_draws=natural_draws)  # fmt: skip
    click.echo(f"wrote {out}")


def _window(window: int) -> int:
    from spikenerf.camera.reconstruct import check_window

    return check_window(window, "window", least=3)


def _choices(flag: str, text: str, allowed: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(
        comma_list(
            text,
            allowed,
            lambda _: f"{flag} must be a comma-separated subset of {','.join(allowed)}, found {text!r}",
            param=flag,
        )
    )


def _range(text: str) -> tuple[float, float]:
    from spikenerf.recon.generate import MAX_BRIGHTNESS, check_brightness

    try:
        lo, hi = (float(v) for v in text.split(":"))
    except ValueError:
        raise InputError(
            f"--brightness must be LO:HI with 0 < LO ≤ HI ≤ {MAX_BRIGHTNESS:g}, found {text!r}"
        ) from None
    return check_brightness((lo, hi))  # (bounds, the flag named)


def _sources(scenes, sequences, size: int, window: int, seed: int) -> dict:
    """FrameSources of the extra --scene / --sequence inputs, at 2·size pixels (room for Bayer crops)."""
    from spikenerf.scenes.registry import default_orbit, make_scene_source
    from spikenerf.scenes.sequence import SequenceSource
    from spikenerf.scenes.trajectory import orbit

    extra = {}
    for name in scenes:
        radius, center = default_orbit(name, seed)
        traj = orbit(radius, 30.0, duration=max(window, 200) / 40000.0, center=center)
        extra[f"scene:{name}"] = make_scene_source(
            name, 2 * size, 2 * size, traj, __import__("numpy").zeros((0, 4, 4)), seed=seed
        )
    for path in sequences:
        extra[f"sequence:{path}"] = SequenceSource(Path(path))
    return extra
