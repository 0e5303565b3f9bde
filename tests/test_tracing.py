"""``core/tracing.py`` and the kernels' direct calls: importing a field and rendering without gradient do not
import Dynamo (2–3 s), and what is marked for it still reaches it before anything compiles."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest
import torch

from spikenerf.core import tracing
from spikenerf.fields.vm_kernel import usable, vm_lookup
from spikenerf.fields.vm_sample import vm_splits


def _run(code: str) -> str:
    """Run ``code`` in a fresh interpreter (one thread); its stdout."""
    done = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                          timeout=300, env={**__import__("os").environ, "OMP_NUM_THREADS": "1"})  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


def test_a_render_without_gradient_does_not_import_dynamo() -> None:
    out = _run("""
        import sys
        import torch
        from spikenerf.fields import GridFieldConfig
        from spikenerf.fields.vm_kernel import usable
        from spikenerf.render import build_model, render_image
        from spikenerf.scenes.poses import look_at
        from spikenerf.scenes.trajectory import Intrinsics
        box = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
        cfg = GridFieldConfig(n_voxels_init=16**3, n_voxels_final=16**3, occupancy=False)
        model = build_model("grid", 1, box, cfg)
        pose = torch.as_tensor(look_at([0.0, 2.5, 1.0], [0.0, 0.0, 0.0]), dtype=torch.float32)
        with torch.no_grad():
            image = render_image(model, pose, Intrinsics.from_fov(8, 8, 0.8), 2.0, 4.0)
        kernel = usable(model.field.density_planes, torch.zeros(1, 3))
        print(tuple(image.color.shape), kernel, "torch._dynamo" in sys.modules)
    """).split()
    assert out[:3] == ["(8,", "8,", "1)"]
    assert out[-1] == "False", "a render without gradient imported torch._dynamo"


def test_marked_functions_are_constants_to_a_trace(fresh_dynamo: None) -> None:
    calls: list[int] = []

    @tracing.constant_result
    def host_query() -> int:
        calls.append(1)
        return 3

    assert host_query._dynamo_marked_constant  # type: ignore[attr-defined]
    tracing.prepare_compile()
    assert not tracing._PENDING
    compiled = torch.compile(lambda x: x * host_query(), backend="eager", fullgraph=True)
    for _ in range(3):
        assert torch.equal(compiled(torch.ones(2)), torch.full((2,), 3.0))
    assert len(calls) == 1  # read once, at tracing; not called by the compiled function


def test_the_fields_host_queries_are_marked() -> None:
    assert vm_splits._dynamo_marked_constant  # type: ignore[attr-defined]
    out = _run("""
        import sys
        from spikenerf.fields import grid, vm_kernel, vm_triton
        from spikenerf.core import tracing
        pending = {f.__name__ for f in tracing._PENDING}
        print(sorted(pending), "torch._dynamo" in sys.modules)
        tracing.prepare_compile()
        print(len(tracing._PENDING), "torch._dynamo" in sys.modules)
    """).splitlines()
    assert out[0] == "['available', 'installed', 'native_bf16', 'vm_splits'] False"
    assert out[1] == "0 True"


@pytest.mark.parametrize("summed", [False, True])
def test_the_direct_kernel_call_equals_the_op(summed: bool) -> None:
    gen = torch.Generator().manual_seed(0)
    planes = torch.randn(3, 5, 7, 7, generator=gen).contiguous(memory_format=torch.channels_last)
    lines = torch.randn(3, 5, 7, 1, generator=gen).contiguous(memory_format=torch.channels_last)
    xyz = torch.rand(50, 3, generator=gen) * 2.2 - 1.1
    if not usable(planes, xyz):
        pytest.skip("the fused CPU kernel is unavailable here")
    with torch.no_grad():
        direct = vm_lookup(planes, lines, xyz, summed)
    traced = vm_lookup(planes.requires_grad_(), lines.requires_grad_(), xyz, summed)
    assert traced.grad_fn is not None and direct.grad_fn is None
    assert torch.equal(direct, traced.detach())
