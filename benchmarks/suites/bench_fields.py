"""Training-step throughput (rays/s, forward + backward) of the ``grid`` field against the paper's ``mlp``.

Usage (from the repository root)::

    .venv/bin/python -m benchmarks.suites.bench_fields [--batch 1024] [--repeats 2] [--device auto|cpu|cuda]
                                                [--threads N]

Every row times ``render_rays(perturb=True)`` + ``backward()`` on the same batch of rays (random pixels of a
1000-step orbit around a [−1.5, 1.5]³ box), best of ``--repeats`` after one warm-up. The reference is the
vanilla NeRF (8×256, 64 coarse + 128 fine samples) measured once in the same run. The optimiser step is left
out, so every repeat sees the same field. Grid rows:

* ``64³ / 200³, every sample``: no occupancy grid (as before the first occupancy update), colour decoded only
  where the weight > 1e-4 (the renderer's rule) — the worst case per resolution;
* ``200³ + occupancy``: a toy scene (an opaque cube of half-size 0.5; the row names the occupied share of
  cells after the update), i.e. a fitted scene whose empty space is skipped.
"""

from __future__ import annotations

import argparse
import time

import torch

from benchmarks._table import Row, best_seconds, format_table
from spikenerf.core.device import resolve_device
from spikenerf.data.rays import pixel_rays, ray_box_bounds
from spikenerf.fields import GridFieldConfig
from spikenerf.render import RadianceModel, build_model
from spikenerf.scenes.trajectory import Intrinsics, orbit

BOX = torch.tensor([[-1.5] * 3, [1.5] * 3])


def make_rays(batch: int, device: torch.device, seed: int = 0) -> tuple[torch.Tensor, ...]:
    """``batch`` rays through random pixels of random steps of an orbit (200×200, radius 4)."""
    gen = torch.Generator().manual_seed(seed)
    intr = Intrinsics.from_fov(200, 200, 0.69)
    traj = orbit(4.0, 30.0)
    step = torch.randint(0, len(traj), (batch,), generator=gen)
    pixels = torch.randint(0, 200, (batch, 2), generator=gen)
    poses = torch.as_tensor(traj.poses[step.numpy()], dtype=torch.float32)
    o, d = pixel_rays(poses, intr, pixels)
    near, far = ray_box_bounds(o, d, BOX)
    return tuple(x.to(device) for x in (o, d, near, far))


def cube_grid(resolution: int, device: torch.device) -> RadianceModel:
    """A grid model whose density is an opaque cube (|x|,|y|,|z| < 0.5), random appearance."""
    torch.manual_seed(0)
    model = build_model("grid", 3, BOX, GridFieldConfig(n_voxels_init=resolution**3))
    f = model.field
    with torch.no_grad():
        ind = (torch.linspace(-1, 1, f.resolution).abs() < 0.5 / 1.5).float()
        f.density_planes.zero_()
        f.density_lines.zero_()
        f.density_planes[:, 0] = ind[:, None] * ind[None, :]
        f.density_lines[:, 0, :, 0] = 30.0 * ind
    return model.to(device)


def train_step_seconds(model: RadianceModel, rays: tuple[torch.Tensor, ...], repeats: int) -> float:
    """Best seconds of one forward + backward over ``rays`` (after a warm-up)."""

    def step() -> None:
        out = model.render_rays(*rays, perturb=True)
        loss = (out.color - 0.5).square().mean()
        if out.coarse_color is not None:
            loss = loss + (out.coarse_color - 0.5).square().mean()
        model.zero_grad(set_to_none=True)
        loss.backward()
        if rays[0].is_cuda:
            torch.cuda.synchronize()

    step()
    return best_seconds(step, repeats)


def measure(batch: int = 1024, repeats: int = 2, device: str = "auto") -> list[Row]:
    """Grid rows against the vanilla NeRF at the same batch; rays/s of a training step."""
    dev = resolve_device(device)
    rays = make_rays(batch, dev)
    torch.manual_seed(0)
    mlp = build_model("mlp", 3, BOX).to(dev)
    reference = batch / train_step_seconds(mlp, rays, repeats)
    rows = []
    for res in (64, 200):
        model = cube_grid(res, dev)
        model.use_occupancy = False
        rows.append((f"grid {res}³, every sample", train_step_seconds(model, rays, repeats)))
    model = cube_grid(200, dev)
    occupied = model.field.update_occupancy()
    rows.append(
        (f"grid 200³ + occupancy (cube, {occupied:.1%} of cells)", train_step_seconds(model, rays, repeats))
    )
    return [Row(name, batch / seconds, reference, "rays/s", "mlp") for name, seconds in rows]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=1024)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--device", default="auto")
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0 = torch's default)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    dev = resolve_device(args.device)
    where = torch.cuda.get_device_name() if dev.type == "cuda" else f"CPU, {torch.get_num_threads()} threads"
    print(f"field training step (forward + backward), batch {args.batch}, {where}, torch {torch.__version__}")
    start = time.perf_counter()
    print(format_table(measure(args.batch, args.repeats, args.device)))
    print(f"({time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
