"""``train/dense_adam.py``: Adam stepped through row-major views equals torch's Adam, without copies."""

from __future__ import annotations

import pytest
import torch
from torch.profiler import profile

from spikenerf.train.dense_adam import DenseAdam, dense_order, inverse


def test_dense_order_views_a_channels_last_tensor_row_major() -> None:
    t = torch.randn(3, 5, 7, 2).contiguous(memory_format=torch.channels_last)
    order = dense_order(t)
    assert order == [0, 2, 3, 1] and t.permute(order).is_contiguous()
    assert t.permute(order).permute(inverse(order)).stride() == t.stride()
    assert dense_order(torch.randn(3, 4)) is None  # row-major already
    assert dense_order(torch.randn(4, 6)[:, ::2]) is None  # not dense: no permutation helps
    assert dense_order(torch.randn(5)) is None


def _pair() -> tuple[list[torch.nn.Parameter], list[torch.nn.Parameter]]:
    """Two identical parameter lists: a channels-last plane and line factor, and a row-major matrix."""
    gen = torch.Generator().manual_seed(0)
    values = [
        torch.randn(3, 6, 9, 9, generator=gen).contiguous(memory_format=torch.channels_last),
        torch.randn(3, 6, 9, 1, generator=gen).contiguous(memory_format=torch.channels_last),
        torch.randn(7, 5, generator=gen),
    ]
    return [torch.nn.Parameter(v.clone()) for v in values], [torch.nn.Parameter(v.clone()) for v in values]


@pytest.mark.parametrize("fused", [True, False])
def test_dense_adam_steps_like_adam_and_keeps_the_layout(fused: bool) -> None:
    ours, theirs = _pair()
    a = DenseAdam(ours, lr=0.01, betas=(0.9, 0.99), fused=fused)
    b = torch.optim.Adam(theirs, lr=0.01, betas=(0.9, 0.99), fused=fused)
    gen = torch.Generator().manual_seed(1)
    for _ in range(4):
        for p, q in zip(ours, theirs, strict=True):
            g = torch.randn(p.shape, generator=gen)
            p.grad = g.contiguous(memory_format=torch.channels_last) if p.dim() == 4 else g.clone()
            q.grad = g.contiguous(memory_format=torch.channels_last) if q.dim() == 4 else g.clone()
        a.step()
        b.step()
    for p, q in zip(ours, theirs, strict=True):
        assert p.shape == q.shape and p.stride() == q.stride() and p.grad.stride() == p.stride()
        assert torch.allclose(p, q, rtol=1e-6, atol=1e-7)
        for key in ("exp_avg", "exp_avg_sq"):
            assert a.state[p][key].shape == p.shape and a.state[p][key].stride() == p.stride()
            assert torch.allclose(a.state[p][key], b.state[q][key], rtol=1e-6, atol=1e-8)
    # the state dict is Adam's: it loads into torch's Adam and back
    fresh = torch.optim.Adam(theirs, lr=0.01, betas=(0.9, 0.99), fused=fused)
    fresh.load_state_dict(a.state_dict())
    DenseAdam(ours, lr=0.01, fused=fused).load_state_dict(b.state_dict())


@pytest.mark.parametrize("shape", [(3, 8, 32, 32), (3, 8, 32, 1)])
def test_the_fused_cpu_step_copies_no_channels_last_factor(shape: tuple[int, ...]) -> None:
    p = torch.nn.Parameter(torch.randn(shape).contiguous(memory_format=torch.channels_last))
    # the fused VM kernel's gradient: (3, R, R, C) or, for a line, (3, R, C) row-major, permuted back; a
    # line's size-1 dimension then has another stride than the parameter's (autograd keeps it as it comes)
    rows = (
        torch.randn(3, shape[2], shape[3], shape[1]) if shape[3] > 1 else torch.randn(3, shape[2], shape[1])
    )
    p.grad = rows.permute(0, 3, 1, 2) if shape[3] > 1 else rows.permute(0, 2, 1)[..., None]
    layout = p.stride()
    for adam, copies in ((torch.optim.Adam, True), (DenseAdam, False)):
        opt = adam([p], lr=0.01, fused=True)
        opt.step()
        with profile(record_shapes=True) as prof:
            opt.step()
        names = ("aten::copy_", "aten::clone", "aten::contiguous")
        big = [e for e in prof.events() if e.name in names and any(s and s[0] == 3 for s in e.input_shapes)]
        assert bool(big) == copies, [(e.name, e.input_shapes) for e in big]
        assert p.stride() == layout and p.grad.shape == p.shape
