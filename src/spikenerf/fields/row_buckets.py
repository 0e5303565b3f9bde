"""Row buckets for bfloat16 matrix products on a CPU: a decoder's rows padded to a few repeating sizes.

On a CPU torch multiplies bfloat16 matrices with oneDNN, which builds (JIT-compiles) a kernel for each new
shape and keeps it in a cache keyed by that shape. A field's decoder sees a different number of samples at
every render call, so without buckets each of its products paid that build: on a 2-core Intel Xeon with AMX
the grid decoder's forward and backward at 69 836+ rows took 105.7 ms with the row count changing at every
call, 43.4 ms bucketed and 43.5 ms at a fixed count (``benchmarks/tools/bench_row_buckets.py``). float32
products (MKL) and CUDA (cuBLAS) build nothing per shape, so rows are padded only where the products run in
bfloat16 on a CPU, outside ``torch.compile`` (whose graphs have fixed shapes or their own kernels).

Padded rows are zero inputs whose outputs are dropped: they add exact zeros to the weight gradients.
"""

from __future__ import annotations

import torch
from torch import Tensor

#: buckets per octave of row counts: at most 1/16 more rows (6.25 %), 3 % on average; 16 sizes an octave
#: keep a run's kernels within oneDNN's default cache of 1024 (a few octaves × 16 sizes × ~12 products)
PER_OCTAVE = 16


def bucket_rows(rows: int) -> int:
    """``rows`` rounded up to the next of :data:`PER_OCTAVE` sizes per octave (``rows`` itself below 2·16)."""
    if rows < 2 * PER_OCTAVE:
        return rows
    step = 1 << (rows.bit_length() - PER_OCTAVE.bit_length())
    return -(-rows // step) * step


def bucketing(device: torch.device) -> bool:
    """Whether products on ``device`` should get bucketed rows: bfloat16 autocast on a CPU, eager."""
    return (
        device.type == "cpu"
        and torch.is_autocast_enabled("cpu")
        and torch.get_autocast_dtype("cpu") == torch.bfloat16
        and not torch.compiler.is_compiling()
    )


def pad_rows(x: Tensor, rows: int, dtype: torch.dtype) -> Tensor:
    """``x`` (M, K) as a (rows, K) tensor of ``dtype``: its rows first, then zero rows (``rows`` ≥ M).

    One conversion copy (autocast would make it anyway); the gradient for ``x`` is the first M rows'."""
    m = x.shape[0]
    if rows < m:
        raise ValueError(f"rows: {rows} is fewer than the {m} rows of x")
    out = x.new_empty((rows, x.shape[1]), dtype=dtype)
    out[m:].zero_()
    out[:m] = x
    return out


def pad_to_bucket(tensors: tuple[Tensor, ...], dtype: torch.dtype) -> tuple[Tensor, ...]:
    """Each (M, K_i) tensor of ``tensors`` (one M) padded by :func:`pad_rows` to :func:`bucket_rows` (M)."""
    rows = bucket_rows(tensors[0].shape[0])
    return tuple(pad_rows(t, rows, dtype) for t in tensors)
