"""An occupancy update of the grid field, point by point (the earlier way) against the lattice way, in the
same run (``fields/vm_lattice.py``, ``fields/occupancy.py: dilate``).

Usage (from the repository root)::

    .venv/bin/python -m benchmarks.tools.bench_occupancy [--resolution 200] [--cells 128] [--rounds 5]
        [--threads 2] [--device cpu]

A default grid field with random factors at ``--resolution`` texels a side and an occupancy grid of
``--cells`` a side (the defaults: the grid's last resolution and the occupancy grid's largest). Timed,
interleaved, ``--rounds`` rounds after one untimed round:

- ``points``: the density at all G³ cell centres by lookups (``GridField.density_norm``: the fused kernel on
  a CPU) and the dilation by ``F.max_pool3d``, as every update did before (only these two parts are timed);
- ``lattice``: a whole ``GridField.update_occupancy`` (separable interpolation on the lattice, ``dilate``,
  the threshold and the bounds).

Both grids are checked equal. Printed: the median ms of each part and of each way, and the ratio points /
lattice (above 1: the lattice is faster; the points way leaves out its threshold and bounds, so the ratio
is a lower bound).
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import torch
import torch.nn.functional as F

from spikenerf.fields.grid import GridField
from spikenerf.fields.grid_config import GridFieldConfig
from spikenerf.fields.occupancy import dilate


def timed(fn: Callable[[], object], device: torch.device) -> tuple[float, object]:
    """(seconds, result) of ``fn()``, the device synchronised on both sides."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    start = time.perf_counter()
    out = fn()
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    return time.perf_counter() - start, out


@torch.no_grad()
def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=200, help="texels a side of the factors")
    parser.add_argument("--cells", type=int, default=128, help="cells a side of the occupancy grid")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    device = torch.device(args.device)
    r, g = args.resolution, args.cells
    cfg = GridFieldConfig(n_voxels_init=r**3, n_voxels_final=r**3, occupancy_max_resolution=g)
    field = GridField(1, torch.tensor([[-1.0] * 3, [1.0] * 3]), cfg).to(device)
    field.density_planes.mul_(20.0)  # a field with empty and occupied cells (random factors: mostly empty)
    step, threshold = field.step_size, cfg.occupancy_threshold
    parts: dict[str, list[float]] = {
        k: [] for k in ("point density", "max_pool3d", "lattice density", "dilate")
    }
    whole: dict[str, list[float]] = {"points": [], "lattice": []}
    for rnd in range(args.rounds + 1):
        t1, sigma = timed(lambda: field.density_norm(field.occupancy.cell_centres()).reshape(g, g, g), device)
        occupied = (1.0 - torch.exp(-sigma * step)).gt(threshold)
        t2, pooled = timed(lambda occ=occupied: F.max_pool3d(occ[None, None].float(), 3, 1, 1), device)
        t3, _ = timed(lambda: field.density_lattice(field.occupancy.axis_centres()), device)
        t4, _ = timed(lambda occ=occupied: dilate(occ, 1), device)
        t6, _ = timed(field.update_occupancy, device)
        if not torch.equal(pooled[0, 0] > 0.5, field.occupancy.grid):
            raise SystemExit("bench_occupancy: the two ways built different grids")
        if rnd:  # the first round warms up
            for key, t in zip(parts, (t1, t2, t3, t4), strict=True):
                parts[key].append(t)
            whole["points"].append(t1 + t2)  # the rest of an update is the same both ways
            whole["lattice"].append(t6)
    occupied_share = field.occupancy.occupied_fraction()
    print(f"R {r}, G {g}, {args.threads} thread(s), {args.device}, occupied {occupied_share:.3f}")
    for key, ts in parts.items():
        print(f"  {key:16s} {1000 * statistics.median(ts):8.1f} ms")
    pts, lat = (statistics.median(whole[k]) for k in ("points", "lattice"))
    print(f"  update, points  {1000 * pts:8.1f} ms (density and max_pool3d only)")
    print(f"  update, lattice {1000 * lat:8.1f} ms (all of it)\npoints / lattice: {pts / lat:.1f}x")


if __name__ == "__main__":
    main()
