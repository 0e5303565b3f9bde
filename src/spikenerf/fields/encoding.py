"""Frequency (positional) encoding of NeRF."""

from __future__ import annotations

import torch
from torch import Tensor

from spikenerf.core.errors import InputError, is_integer


def encoded_size(dim: int, n_freqs: int, include_input: bool = True) -> int:
    """Width of :func:`positional_encoding` for a ``dim``-vector."""
    return dim * (2 * n_freqs + int(include_input))


def positional_encoding(x: Tensor, n_freqs: int, include_input: bool = True) -> Tensor:
    """``[x, sin(2^0 x), cos(2^0 x), …, sin(2^(L−1) x), cos(2^(L−1) x)]`` (NeRF, without the π factor).

    Args:
        x: (..., D). n_freqs: L, the number of octaves. include_input: ``x`` itself first.
    Returns:
        (..., D · (2L + include_input)).
    Raises:
        InputError: ``x`` without a last axis (0-d), or ``n_freqs`` not an integer ≥ 0 (2.5 made three
            octaves, wider than :func:`encoded_size` said).
    """
    if x.dim() == 0:
        raise InputError("x must be (..., D), found a 0-d tensor", param="x")
    if not is_integer(n_freqs) or n_freqs < 0:
        raise InputError(f"n_freqs must be an integer ≥ 0, found {n_freqs!r}", param="n_freqs")
    if n_freqs == 0:
        return x if include_input else x[..., :0]
    freqs = 2.0 ** torch.arange(n_freqs, device=x.device, dtype=x.dtype)
    scaled = (x[..., None, :] * freqs[:, None]).flatten(-2)  # (..., L·D)
    parts = [x] if include_input else []
    parts += [torch.sin(scaled), torch.cos(scaled)]
    return torch.cat(parts, dim=-1)
