"""``fields/row_buckets.py``: bucketed row counts for the grid decoder's bfloat16 products on a CPU, and the
``bench_row_buckets`` tool at a tiny size (its timings are measurements, docs/performance.md)."""

from __future__ import annotations

import itertools
import re
import sys
from dataclasses import replace

import pytest
import torch
from torch.utils._python_dispatch import TorchDispatchMode

from helpers import load_benchmark
from spikenerf.fields import grid
from spikenerf.fields.row_buckets import PER_OCTAVE, bucket_rows, bucketing, pad_rows
from test_fields import CFG, smooth_field

TOOL = load_benchmark("tools/bench_row_buckets")


def test_buckets_cover_each_count_with_little_padding() -> None:
    got = [bucket_rows(m) for m in range(1, 9000)]
    assert got[: 2 * PER_OCTAVE - 1] == list(range(1, 2 * PER_OCTAVE))  # small counts as they are
    for m, b in enumerate(got, start=1):
        assert m <= b <= m * (1 + 1 / PER_OCTAVE) and bucket_rows(b) == b
    assert all(a <= b for a, b in itertools.pairwise(got))  # monotone
    assert {bucket_rows(m) for m in range(1025, 2049)} == set(range(1088, 2049, 64))  # 16 an octave
    assert len({bucket_rows(m) for m in range(65537, 131073)}) == PER_OCTAVE
    assert bucket_rows(69836) == 69632 + 4096  # 4096 a step in that octave


def test_padded_rows_are_zero_and_the_gradient_is_the_first_rows() -> None:
    x = torch.randn(5, 3, requires_grad=True)
    out = pad_rows(x, 8, torch.bfloat16)
    assert out.shape == (8, 3) and out.dtype == torch.bfloat16
    assert torch.equal(out[:5], x.detach().to(torch.bfloat16)) and not out[5:].any()
    weights = torch.randn(8, 3)
    (out.float() * weights).sum().backward()
    assert x.grad is not None and x.grad.dtype == torch.float32
    assert torch.equal(x.grad, weights[:5].to(torch.bfloat16).float())
    same = pad_rows(x, 5, torch.float32)
    assert torch.equal(same, x)
    with pytest.raises(ValueError, match="rows: 4 is fewer than the 5 rows"):
        pad_rows(x, 4, torch.float32)


def test_only_bfloat16_autocast_on_a_cpu_buckets() -> None:
    cpu = torch.device("cpu")
    assert not bucketing(cpu)
    with torch.autocast("cpu", torch.bfloat16):
        assert bucketing(cpu) and not bucketing(torch.device("cuda"))
    with torch.autocast("cpu", torch.float16):
        assert not bucketing(cpu)


class _Rows(TorchDispatchMode):
    """The first dimensions of every matrix operand of ``mm``/``addmm``."""

    def __init__(self) -> None:
        super().__init__()
        self.seen: set[int] = set()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):  # type: ignore[no-untyped-def]
        if func in (torch.ops.aten.mm.default, torch.ops.aten.addmm.default):
            self.seen |= {d for a in args if isinstance(a, torch.Tensor) and a.dim() == 2 for d in a.shape}
        return func(*args, **(kwargs or {}))


def _colour_and_grads(field, xyz: torch.Tensor, dirs: torch.Tensor):  # type: ignore[no-untyped-def]
    field.zero_grad()
    rgb = field.color_norm(xyz, dirs)
    (rgb * torch.linspace(0, 1, rgb.numel()).view_as(rgb)).sum().backward()
    return rgb.detach(), field.app_planes.grad.clone(), field.decoder[0].weight.grad.clone()


def test_the_bf16_decoder_multiplies_bucketed_rows_with_the_same_results(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Forward and backward products see 1024 rows for 1000 samples (a bucket), not 1000; the colours and
    gradients are those of the unpadded products. Emulated bf16 where the CPU lacks it (as test_fields)."""
    monkeypatch.setattr(grid, "cpu_has", lambda *flags: True)
    torch.manual_seed(0)
    field = smooth_field(replace(CFG, hidden=32, decoder_bf16=True))
    xyz, dirs = torch.rand(1000, 3) * 2 - 1, torch.nn.functional.normalize(torch.randn(1000, 3), dim=-1)
    rows = _Rows()
    with rows:
        bucketed = _colour_and_grads(field, xyz, dirs)
    assert 1024 in rows.seen and 1000 not in rows.seen, sorted(rows.seen)
    assert bucketed[0].shape == (1000, 3)
    monkeypatch.setattr(grid, "bucketing", lambda device: False)
    plain = _colour_and_grads(field, xyz, dirs)
    torch.testing.assert_close(bucketed[0], plain[0], atol=1e-3, rtol=0)
    for a, b in zip(bucketed[1:], plain[1:], strict=True):
        assert ((a - b).norm() / b.norm()).item() < 1e-2


def test_a_float32_decoder_is_not_padded() -> None:
    field = smooth_field(replace(CFG, hidden=32, decoder_bf16=False))
    xyz, dirs = torch.rand(1000, 3) * 2 - 1, torch.nn.functional.normalize(torch.randn(1000, 3), dim=-1)
    rows = _Rows()
    with rows:
        _colour_and_grads(field, xyz, dirs)
    assert 1000 in rows.seen and 1024 not in rows.seen


def test_the_tool_times_the_three_ways_and_prints_the_ratio(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    argv = ["bench_row_buckets", "--rows", "300", "--calls", "2", "--rounds", "1", "--threads", "1"]
    monkeypatch.setattr(sys, "argv", argv)
    TOOL.main()
    out = capsys.readouterr().out
    for way in TOOL.WAYS:
        assert re.search(rf"^\| {way} \| [\d.]+ \|$", out, flags=re.M), out
    assert re.search(r"^changing / bucketed: [\d.]+×$", out, flags=re.M), out
