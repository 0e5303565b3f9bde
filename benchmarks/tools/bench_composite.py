"""Time of the grid renderer's compositing (weights from densities, then per-ray colour, depth and opacity),
forward and backward, by implementation, against the scatter implementation in the same run.

Usage (from the repository root; on a GPU host ``PYTHONPATH=src python -m …``)::

    .venv/bin/python -m benchmarks.tools.bench_composite [--device auto] [--rays 16384] [--samples 64]
        [--repeats 10] [--rounds 3] [--threads N]

Packed samples as the march makes them: each ray gets a random count in [0, 2 × samples] (so about
``samples`` a ray, some rays empty), densities, interval lengths, distances and colours at random. Timed,
interleaved, ``--rounds`` rounds of ``--repeats`` (after 2 untimed): ``scatter``, the implementation before
per-ray sums (a float64 running sum with ``index_add`` for each ray's offset, ``index_add`` for the sums:
kept here as the reference); ``torch``, the renderer's default now (``render/volume.py``: one running sum,
``torch.segment_reduce`` for the sums on a CPU, ``index_add`` elsewhere); ``triton``, ``composite=triton``
(``render/volume_triton.py``), where its kernels run compiled (CUDA; not in Triton's CPU interpreter, whose
time means nothing). Printed: the median ms of forward + backward, its ratio to ``scatter`` (above 1:
faster) and the largest difference of colour, depth, opacity and gradients from ``scatter``'s.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from benchmarks._table import interleaved_ms, kernel_timing_args
from spikenerf.fields.vm_triton import why_not
from spikenerf.render import volume_triton
from spikenerf.render.volume import MAX_TAU, packed_composite, packed_weights, ray_offsets

Inputs = tuple[Tensor, Tensor, Tensor, Tensor, Tensor, int]
Composite = Callable[[Inputs], tuple[Tensor, Tensor, Tensor]]


def packed_inputs(rays: int, samples: int, device: torch.device, seed: int = 0) -> Inputs:
    """sigma (M,), deltas (M,), t (M,), rgb (M, 3) (sigma and rgb with gradients), ray (M,) and N."""
    gen = torch.Generator().manual_seed(seed)
    counts = torch.randint(0, 2 * samples + 1, (rays,), generator=gen)
    ray = torch.repeat_interleave(torch.arange(rays), counts)
    m = len(ray)
    sigma = (torch.rand(m, generator=gen) ** 2 * 40).to(device).requires_grad_(True)
    deltas = (torch.rand(m, generator=gen) * 0.02).to(device)
    t = torch.rand(m, generator=gen).to(device) + 2
    rgb = torch.rand(m, 3, generator=gen).to(device).requires_grad_(True)
    return sigma, deltas, t, rgb, ray.to(device), rays


def scatter(inputs: Inputs) -> tuple[Tensor, Tensor, Tensor]:
    """The compositing before per-ray sums (the reference): ``index_add`` wherever a ray's sum is needed."""
    sigma, deltas, t, rgb, ray, n = inputs
    tau = sigma * deltas
    wide = tau.to(torch.float64)
    wide = torch.where(wide.isnan(), MAX_TAU, wide.clamp(max=MAX_TAU))
    per_ray = wide.new_zeros(n).index_add(0, ray, wide)
    before = torch.cumsum(wide, 0) - wide - (torch.cumsum(per_ray, 0) - per_ray).index_select(0, ray)
    weights = torch.exp(-before).to(tau.dtype) * (1.0 - torch.exp(-tau))
    opacity = weights.new_zeros(n).index_add(0, ray, weights)
    depth = weights.new_zeros(n).index_add(0, ray, weights * t) / opacity.clamp_min(1e-10)
    color = weights.new_zeros(n, 3).index_add(0, ray, weights[:, None] * rgb)
    return color + (1.0 - opacity)[:, None], depth, opacity


def renderer(fused: bool) -> Composite:
    """The renderer's compositing (``render/volume.py``), with the Triton kernels or without."""

    def run(inputs: Inputs) -> tuple[Tensor, Tensor, Tensor]:
        sigma, deltas, t, rgb, ray, n = inputs
        offsets = ray_offsets(ray, n)
        weights = packed_weights(sigma, deltas, ray, n, offsets, fused)
        return packed_composite(weights, ray, n, t, rgb, None, offsets=offsets, fused=fused)

    return run


def step(composite: Composite, inputs: Inputs, grads: tuple[Tensor, ...]) -> tuple[Tensor, ...]:
    """Forward and backward: the outputs and the gradients of sigma and rgb."""
    outputs = composite(inputs)
    loss = sum((o * g).sum() for o, g in zip(outputs, grads, strict=True))
    return (*(o.detach() for o in outputs), *torch.autograd.grad(loss, (inputs[0], inputs[3])))


def main() -> None:
    args = kernel_timing_args(
        __doc__, lambda p: p.add_argument("--samples", type=int, default=64, help="mean samples a ray")
    )
    device = args.device
    inputs = packed_inputs(args.rays, args.samples, device)
    grads = (torch.randn(args.rays, 3, device=device), torch.randn(args.rays, device=device),
             torch.randn(args.rays, device=device))  # fmt: skip
    impls: dict[str, Composite] = {"scatter": scatter, "torch": renderer(False)}
    if device.type != "cpu" and volume_triton.applies(inputs[0]):  # compiled kernels only
        impls["triton"] = renderer(True)
    reference = step(scatter, inputs, grads)
    diffs = {
        name: max(float((a - b).abs().max()) for a, b in zip(step(f, inputs, grads), reference, strict=True))
        for name, f in impls.items()
    }
    calls = {name: (lambda f=f: step(f, inputs, grads)) for name, f in impls.items()}
    times = interleaved_ms(calls, device.type == "cuda", args.rounds, args.repeats)
    base = times["scatter"]
    samples = f"{len(inputs[4])} samples (about {args.samples} a ray)"
    print(f"device {device}, {args.rays} rays, {samples}, threads {torch.get_num_threads()}; forward + "
          f"backward, median of {args.rounds} rounds")  # fmt: skip
    print("| compositing | ms | speed vs scatter | largest difference |")
    print("|---|---:|---:|---:|")
    for name, ms in times.items():
        print(f"| {name} | {ms:.3f} | {base / ms:.2f}× | {diffs[name]:.2e} |")
    if "triton" not in impls:
        print(f"triton: not timed here ({why_not(device) or 'only in the CPU interpreter'})")


if __name__ == "__main__":
    main()
