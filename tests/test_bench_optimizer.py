"""``benchmarks/tools/bench_optimizer.py``: a CPU smoke run at a tiny grid; the compiled Adam update ends
where train's eager one does (the timings it prints are measurements, docs/performance.md)."""

from __future__ import annotations

import re

import pytest
import torch

from helpers import load_benchmark

TOOL = load_benchmark("tools/bench_optimizer")


def test_the_compiled_update_is_timed_against_the_eager_one_and_agrees(
    capsys: pytest.CaptureFixture[str],
) -> None:
    torch._dynamo.reset()
    TOOL.main(["--device", "cpu", "--resolution", "10", "--steps", "2", "--rounds", "1", "--threads", "1"])
    out = capsys.readouterr().out
    assert "failed" not in out and "grid R 10: 11 tensors" in out, out
    assert re.search(
        r"^eager \(train's fused Adam\): [\d.]+ ms an update   compiled: [\d.]+ ms$", out, re.M
    ), out
    diff = re.search(r"largest parameter difference (\S+)$", out, re.M)
    assert diff is not None and float(diff.group(1)) < 1e-5, out
