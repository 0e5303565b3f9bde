"""Click parameter types, light options and helpers shared by the subcommands: integers bounded so that no
value overflows later; the device names; a recording's frame size and config (no torch import, so ``info``
stays quick)."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from spikenerf.core.device import DEVICE_CHOICES, DEVICE_NAME
from spikenerf.core.errors import InputError

#: the largest integer any option takes: torch and numpy hold seeds and counts in 64 bits
INT64_MAX = 2**63 - 1


class BoundedInt(click.ParamType):
    """An ``INTEGER`` from ``low`` to 2⁶³ − 1: a bigger one would overflow in torch or numpy, and one below
    ``low`` is meaningless to the command; either is refused in one line naming the flag and the range."""

    name = "integer"

    def __init__(self, low: int = 0) -> None:
        self.low = low

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> int:
        number = click.INT.convert(value, param, ctx)
        if not self.low <= number <= INT64_MAX:
            self.fail(f"{number} is out of range: expected {self.low} to 2^63 - 1", param, ctx)
        return number


#: a seed: 0 … 2⁶³ − 1 (numpy refuses negative seeds, torch ones of 2⁶⁴ and more)
SEED = BoundedInt(0)
#: a count of steps or iterations: 1 … 2⁶³ − 1 (every command using it needs at least one)
COUNT = BoundedInt(1)


class DeviceName(click.ParamType):
    """A device name (``core.device.DEVICE_NAME``: auto, cpu, cuda, cuda:N, mps), checked as it is parsed;
    whether the machine has that device is checked when the command resolves it."""

    name = "device"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> str:
        if not DEVICE_NAME.fullmatch(str(value)):
            self.fail(f"{value!r} is not one of {DEVICE_CHOICES}", param, ctx)
        return str(value)


def device_option(default: str = "auto", help: str = "") -> Callable[..., Any]:
    """``--device``, the same for every command: ``auto`` (CUDA when present, else the CPU), ``cpu``,
    ``cuda``, ``cuda:N`` or ``mps`` (Apple GPUs)."""
    text = f"{DEVICE_CHOICES}; auto: CUDA when present, else the CPU." + (f" {help}" if help else "")
    return click.option("--device", type=DeviceName(), default=default, show_default=True, help=text)


class OutPath(click.Path):
    """``--out``: a path (``Path``), refused when empty (an empty string read as ``.``, the current folder,
    and was reported as such). ``.`` or a path ending in ``..`` becomes the real path of the folder it
    names: what is made beside an output (``OUT.partial``, ``.OUT.old``, ``.OUT.lock``) is named after the
    folder's own name, and ``..``'s would land inside it."""

    def __init__(self) -> None:
        super().__init__(path_type=Path)

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, str) and not value.strip():
            self.fail("the path is empty: give a folder or file name", param, ctx)
        path = super().convert(value, param, ctx)
        if isinstance(path, Path) and path.name in ("", ".."):
            path = Path(os.path.realpath(path))
        return path


def frame_size_options(function: Callable[..., Any]) -> Callable[..., Any]:
    """``--height``/``--width`` of a ``.dat`` recording (default: the SpikeCV config.yaml beside it)."""
    for name, key in (("width", "spike_w"), ("height", "spike_h")):
        function = click.option(
            f"--{name}", type=int,
            help=f"Frame {name} in pixels [default: {key} of the config.yaml beside the file, or one "
            "folder up].",
        )(function)  # fmt: skip
    return function


#: file types that are never a spike recording (a dataset's or run's other files, export's .ply, an .mp4)
NOT_SPIKES = (".yaml", ".yml", ".json", ".pt", ".png", ".jpg", ".jpeg", ".exr", ".npy", ".npz", ".csv",
              ".html", ".ply", ".mp4", ".md")  # fmt: skip


def given_layout(path: Path, layout: str | None, recording: Any, warn: bool = True) -> str:
    """The row order to read ``path`` in: ``--layout`` where given (one warning line, with ``warn``, where it
    differs from the layout its ``config.yaml`` records), else the recorded one, else ``spikecv``."""
    recorded = getattr(recording, "layout", None)
    if warn and layout is not None and recorded is not None and layout != recorded:
        click.echo(
            f"spikenerf: warning: {path}: --layout {layout} differs from layout {recorded} in "
            f"{recording.path}; using --layout {layout}",
            err=True,
        )
    return layout or recorded or "spikecv"


def dat_recording(
    path: Path, height: int | None, width: int | None, raw_width: int | None, refuse: bool = False
) -> Any:
    """The recording's config (``camera.spikecv.recording_config``) with ``raw_width`` where it is given.
    With ``refuse`` (a command that writes what it reads) an InputError where ``width``/``height``/
    ``raw_width`` differs from the ``config.yaml`` beside the file (``camera.spikecv.refuse_size_conflicts``);
    else one warning line for each (when the given size fits the file), and one when the
    file also reads as a raw sps10 recording (``camera.io.raw_width_guess``), or when the columns that
    ``raw_width`` strips fire (``camera.io.stripped_columns_fire``)."""
    from spikenerf.camera.dat_codec import frame_bytes
    from spikenerf.camera.io import count_frames, raw_width_guess, stripped_columns_fire
    from spikenerf.camera.spikecv import recording_config, refuse_size_conflicts, size_conflicts

    if path.suffix.lower() in NOT_SPIKES:
        raise InputError(f"is a {path.suffix} file, not a .dat spike recording", path=path)
    config = recording_config(path, height, width)
    if refuse:  # (a size that is no size at all is named as such first)
        frame_bytes(config.height, config.width, None, path)
        refuse_size_conflicts(config.path, height, width, raw_width)
    differs = []  # flags win over the file, but a mismatch is more often a typo
    for param, given, key, value in size_conflicts(config.path, height, width, raw_width):
        flag = "--" + param.replace("_", "-")
        differs.append(f"{flag} {given} differs from {key} {value} in {config.path}; using {flag} {given}")
    config = config if raw_width is None else dataclasses.replace(config, raw_width=raw_width)
    if differs:
        try:  # said only where the size fits the file: a size that does not is the command's one error
            count_frames(path, config.height, config.width, config.raw_width)
        except InputError:
            differs = []
    for line in differs:
        click.echo(f"spikenerf: warning: {path}: {line}", err=True)
    if config.raw_width is not None and stripped_columns_fire(
        path, config.height, config.width, config.raw_width
    ):
        given = f"--raw-width {raw_width}" if raw_width is not None else f"raw_width {config.raw_width} in "
        given += "" if raw_width is not None else str(config.path)
        click.echo(
            f"spikenerf: warning: {path}: the {config.raw_width - config.width} columns that {given} strips "
            "from each row fire (a raw sps10 recording's padding stays silent): a plain recording has no "
            "raw width",
            err=True,
        )
    if config.raw_width is None and (raw := raw_width_guess(path, config.height, config.width)) is not None:
        click.echo(
            f"spikenerf: warning: {path} also reads as raw sps10 rows of {raw} columns whose last "
            f"{raw - config.width} stay silent: if it is a raw recording, pass --raw-width {raw}",
            err=True,
        )
    return config
