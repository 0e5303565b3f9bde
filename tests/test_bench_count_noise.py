"""``benchmarks/experiments/bench_count_noise.py``: the oracle's targets with an L-step spike count's
quantisation noise are unbiased, on the 1/L lattice, and fresh at every draw."""

from __future__ import annotations

import torch

from helpers import load_benchmark

BENCH = load_benchmark("experiments/bench_count_noise")


def test_count_noise_is_unbiased_on_the_count_lattice() -> None:
    value = torch.tensor([[0.0], [0.1], [0.45], [0.8], [1.0]]).repeat(1, 20000)
    gather = lambda index, pixels: value  # noqa: E731
    for length in (1, 3):
        noisy = BENCH.count_noise(gather, length, seed=0)
        first, second = noisy(None, None), noisy(None, None)
        assert torch.equal(first * length, torch.round(first * length))  # counts over L steps, divided by L
        assert not torch.equal(first, second)  # a new accumulator start at every draw
        torch.testing.assert_close(first.mean(dim=1), value[:, 0], atol=0.01, rtol=0)
        assert torch.all((first - value).abs() < 1 / length + 1e-6)  # within one count of L v
    assert BENCH.count_noise(gather, 0, seed=0)(None, None) is value
