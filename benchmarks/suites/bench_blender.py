"""Seconds per frame of every built-in Blender scene (Cycles, CPU unless a GPU is found).

Usage (from the repository root)::

    .venv/bin/python -m benchmarks.suites.bench_blender [--size 200] [--spp 16] [--frames 6] [--long 0]

Each scene renders ``--frames`` consecutive orbit steps after one warm-up frame (the warm-up includes the
scene sync). The reference row renders the same frames of ``bricks`` with the HIGH denoiser in the same run.
``--long N`` (≤ 1000) also renders the first N steps of the 1000-step orbit of ``bricks`` and reports the
total wall time, extrapolated to 1000 steps.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from benchmarks._table import Row, format_table
from spikenerf.scenes.blender import BUILTIN_SCENES, BlenderSource, default_orbit_radius, scene_extent
from spikenerf.scenes.trajectory import orbit


def measure(
    scene: str, size: int, spp: int, frames: int, denoise: str = "FAST", progress: bool = False
) -> dict[str, float]:
    """Build + first frame, then wall and CPU seconds per frame over ``frames`` consecutive steps."""
    start = time.perf_counter()
    box = scene_extent(scene)
    radius = default_orbit_radius(box)
    traj = orbit(radius, 30.0, center=tuple(box.mean(0)))
    src = BlenderSource(scene, size, size, traj, spp=spp, denoise=denoise, progress=progress)
    steps = iter(src.frames(range(frames + 1)))
    next(steps)
    first = time.perf_counter() - start
    wall, cpu = time.perf_counter(), time.process_time()
    for _ in steps:
        pass
    return {
        "total": time.perf_counter() - start,
        "first": first,
        "wall": (time.perf_counter() - wall) / frames,
        "cpu": (time.process_time() - cpu) / frames,
        "device": src.device,
    }


def readout_seconds(repeats: int = 20) -> tuple[float, float]:
    """Best seconds to write the last render to the EXR and to read it back into numpy (the frame path)."""
    import bpy
    import numpy as np

    result = bpy.data.images["Render Result"]
    write, read = float("inf"), float("inf")
    with tempfile.TemporaryDirectory() as tmp:
        path = str(Path(tmp) / "frame.exr")
        for _ in range(repeats):
            t0 = time.perf_counter()
            result.save_render(path)
            t1 = time.perf_counter()
            image = bpy.data.images.load(path, check_existing=False)
            buf = np.empty(image.size[0] * image.size[1] * 4, np.float32)
            image.pixels.foreach_get(buf)
            bpy.data.images.remove(image)
            write, read = min(write, t1 - t0), min(read, time.perf_counter() - t1)
    return write, read


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=200)
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--scenes", default=",".join(BUILTIN_SCENES))
    parser.add_argument("--denoise", default="FAST", help="denoiser of the per-scene table (FAST|HIGH|NONE…)")
    parser.add_argument("--long", type=int, default=0, help="also render this many consecutive steps")
    args = parser.parse_args()
    load = os.getloadavg()[0]
    print(
        f"{args.size}x{args.size}, {args.spp} spp, {args.denoise} denoiser; "
        f"{os.cpu_count()} CPUs, load {load:.1f}"
    )
    lines = [
        "| scene | build + 1st frame s | s/frame | CPU s/frame | 1000 frames (min) |",
        "|---|---:|---:|---:|---:|",
    ]
    results = {}
    for scene in args.scenes.split(","):
        r = measure(scene, args.size, args.spp, args.frames, denoise=args.denoise)
        results[scene] = r
        lines.append(
            f"| {scene} | {r['first']:.2f} | {r['wall']:.3f} | {r['cpu']:.3f} | {r['wall'] * 1000 / 60:.1f} |"
        )
    write, read = readout_seconds()
    print(
        f"device: {r['device']}; EXR readout per frame: write {write * 1e3:.1f} ms + read {read * 1e3:.1f} ms"
    )
    print("\n".join(lines))
    ref_scene = "bricks" if "bricks" in results else next(iter(results))
    high = measure(ref_scene, args.size, args.spp, args.frames, denoise="HIGH")
    fast = results[ref_scene]
    print()
    print(
        format_table(
            [
                Row(
                    f"{ref_scene} frames/s, {args.denoise} vs HIGH denoiser",
                    1 / fast["wall"],
                    1 / high["wall"],
                    "frames/s",
                    "HIGH",
                ),
                Row(
                    f"{ref_scene} frames per CPU-s, {args.denoise} vs HIGH",
                    1 / fast["cpu"],
                    1 / high["cpu"],
                    "frames/CPU-s",
                    "HIGH",
                ),
            ]
        )
    )
    if args.long:
        r = measure(ref_scene, args.size, args.spp, args.long - 1, progress=True)
        print(
            f"\n{ref_scene}: {args.long} steps (build + every frame) in {r['total'] / 60:.1f} min, "
            f"{r['wall']:.3f} s/frame after the first (CPU {r['cpu']:.3f}) -> 1000 steps ≈ "
            f"{(r['first'] + r['wall'] * 999) / 60:.1f} min; load {os.getloadavg()[0]:.1f} at the end"
        )


if __name__ == "__main__":
    main()
