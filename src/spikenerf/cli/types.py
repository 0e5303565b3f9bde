"""Click parameter types and light options shared by the subcommands: integers bounded so that no value
overflows later; a recording's frame size (no torch import, so ``info`` stays quick)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import click

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


def frame_size_options(function: Callable[..., Any]) -> Callable[..., Any]:
    """``--height``/``--width`` of a ``.dat`` recording (default: the SpikeCV config.yaml beside it)."""
    for name, key in (("width", "spike_w"), ("height", "spike_h")):
        function = click.option(
            f"--{name}", type=int,
            help=f"Frame {name} in pixels [default: {key} of the config.yaml beside the file, or one "
            "folder up].",
        )(function)  # fmt: skip
    return function
