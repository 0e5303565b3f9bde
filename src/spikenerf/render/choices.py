"""The render precisions as a typed choice, defined once, without importing torch (the CLI's
``--precision``; what each means: :mod:`spikenerf.render.inference`)."""

from __future__ import annotations

from typing import Literal, get_args

Precision = Literal["auto", "fp32", "fp16", "bf16"]
PRECISIONS: tuple[str, ...] = get_args(Precision)
