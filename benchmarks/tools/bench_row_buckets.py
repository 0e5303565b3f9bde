"""The grid decoder's products on a CPU with row counts that change at every call, bucketed or not, against
the same products at a fixed row count, in the same run (``fields/row_buckets.py``).

Usage (from the repository root)::

    .venv/bin/python -m benchmarks.tools.bench_row_buckets [--rows 69836] [--calls 40] [--rounds 3]
        [--threads 2] [--dtype bf16]

Each call runs the colour decoder of a default grid field (``GridField``'s own appearance basis and
three layers) forward and backward on ``rows`` + a different small offset of rows each call (as the
sample count of a render changes), as training does it (``GridField.color_norm``'s products under CPU
autocast for ``bf16``). Three ways, interleaved, ``--rounds`` rounds of ``--calls`` calls (the first
call of a way in a round untimed): ``changing`` (the rows as they come), ``bucketed`` (padded by
:func:`pad_to_bucket`) and ``fixed`` (always ``rows``: the floor, no kernel ever built twice). Printed:
median ms a call of each, and the ratio of ``changing`` to ``bucketed`` (above 1: the buckets are faster).
"""

from __future__ import annotations

import argparse
import statistics
import time
from contextlib import nullcontext

import torch
from torch import Tensor, nn

from spikenerf.fields.encoding import encoded_size
from spikenerf.fields.grid import GridField
from spikenerf.fields.grid_config import GridFieldConfig
from spikenerf.fields.row_buckets import pad_to_bucket

WAYS = ("changing", "bucketed", "fixed")


def decoder(channels: int = 1) -> tuple[nn.Module, nn.Module, int]:
    """A default grid field's appearance basis and decoder, and its view encoding's width."""
    field = GridField(channels, torch.tensor([[-1.0] * 3, [1.0] * 3]), GridFieldConfig())
    return field.basis, field.decoder, encoded_size(3, field.config.view_freqs)


def one_call(
    basis: nn.Module, layers: nn.Module, feats: Tensor, view: Tensor, bucket: bool, low: bool
) -> None:
    """Forward and backward of the decoder on ``feats`` (M, 3C) and the view encoding ``view`` (M, V)."""
    m = feats.shape[0]
    with torch.autocast("cpu", torch.bfloat16) if low else nullcontext():
        if bucket:
            feats, view = pad_to_bucket((feats, view), torch.bfloat16 if low else feats.dtype)
        logit = layers(torch.cat([basis(feats), view.to(feats.dtype)], dim=-1))
    logit[:m].float().sum().backward()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=69836, help="rows a call, before the changing offset")
    parser.add_argument("--calls", type=int, default=40)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--dtype", choices=("bf16", "fp32"), default="bf16")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    cfg = GridFieldConfig()
    basis, layers, width = decoder()
    low = args.dtype == "bf16"
    top = args.rows + 7 * (args.calls + 1) * args.rounds * len(WAYS)
    feats = torch.randn(top, 3 * cfg.app_components, requires_grad=True)
    view = torch.randn(top, width)
    times: dict[str, list[float]] = {way: [] for way in WAYS}
    offset = 0
    for _ in range(args.rounds):
        for way in WAYS:
            spent = []
            for call in range(args.calls + 1):
                offset += 7  # a new row count at every call, never seen before in this process
                m = args.rows if way == "fixed" else args.rows + offset
                start = time.perf_counter()
                one_call(basis, layers, feats[:m], view[:m], way == "bucketed", low)
                if call:
                    spent.append(time.perf_counter() - start)
            times[way].append(1000 * statistics.median(spent))
    print(
        f"{args.rows} rows and more, {args.dtype}, {args.threads} thread(s), {args.calls} calls × "
        f"{args.rounds} rounds; ms a call (forward and backward), median of the round medians:"
    )
    print("| rows | ms a call |\n|---|---:|")
    med = {way: statistics.median(times[way]) for way in WAYS}
    for way in WAYS:
        print(f"| {way} | {med[way]:.2f} |")
    print(f"changing / bucketed: {med['changing'] / med['bucketed']:.2f}×")


if __name__ == "__main__":
    main()
