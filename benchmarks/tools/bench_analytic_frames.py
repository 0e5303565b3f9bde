"""CPU time of one analytic frame (docs/scenes.md, "Timings"): the median over POSES poses of the default
analytic orbit (radius 4, 30°, 1000 steps), per scene and samples per pixel.

Usage (from the repository root; one thread, as the table was measured)::

    OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.tools.bench_analytic_frames [--size 200] [--poses 20]
"""

from __future__ import annotations

import argparse
import statistics
import time

from spikenerf.scenes.analytic import AnalyticSource
from spikenerf.scenes.trajectory import orbit


def main(argv: list[str] | None = None) -> dict[tuple[str, int], float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=200)
    parser.add_argument("--poses", type=int, default=20)
    args = parser.parse_args(argv)
    path = orbit(4.0, 30.0)
    every = max(1, len(path.poses) // args.poses)
    result = {}
    for scene in ("analytic-orbs", "analytic-blocks"):
        for spp in (1, 4):
            source = AnalyticSource(scene, args.size, args.size, path, supersample=round(spp**0.5))
            times = []
            for pose in path.poses[::every][: args.poses]:
                t0 = time.process_time()
                source.render(pose)
                times.append(time.process_time() - t0)
            result[scene, spp] = statistics.median(times)
            print(f"`{scene}`, spp {spp}: {1000 * result[scene, spp]:.1f} ms CPU a frame ({args.size}²)")
    return result


if __name__ == "__main__":
    main()
