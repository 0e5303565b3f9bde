"""What ``eval`` and ``render`` spend loading a dataset: with the GT renders and blur frames decoded (the
reference, as before) against without them (``load_dataset(..., train_images=False)``, what they use now).

Usage (from the repository root)::

    .venv/bin/python -m benchmarks.tools.bench_eval_load DATASET [--rounds 3]

Printed: the median seconds of each, alternated for ROUNDS rounds, and the ratio reference / ours.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from spikenerf.data.dataset import load_dataset


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    times: dict[bool, list[float]] = {True: [], False: []}
    for _ in range(args.rounds):
        for gt in (True, False):
            t0 = time.perf_counter()
            ds = load_dataset(args.dataset, train_images=gt)
            times[gt].append(time.perf_counter() - t0)
            print(f"train_images={gt}: {times[gt][-1]:.3f} s ({len(ds.gt)} GT, {len(ds.test)} test views)")
    ref, ours = statistics.median(times[True]), statistics.median(times[False])
    print(f"load_dataset: reference {ref:.3f} s, ours {ours:.3f} s, ratio {ref / ours:.1f}×")


if __name__ == "__main__":
    main()
