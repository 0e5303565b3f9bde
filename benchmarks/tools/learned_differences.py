"""Paired differences of the rows beyond the paper's claims in a benchmark folder, with 95 % intervals.

Run: ``.venv/bin/python -m benchmarks.tools.learned_differences OUT [--per-scene]`` after ``spikenerf
benchmark ... --out OUT`` with the variants below. The benchmark's own ``differences.md`` holds the
paper's claims (Spike-NeRF against its baselines); this prints, with the same statistics
(``spikenerf.pipelines.benchmark.results.extra_differences_markdown``), what the learned reconstructor
changes: NeRF on learned vs TFP images, Spike-NeRF on learned vs TFP targets, and Spike-NeRF vs NeRF when
both use the learned reconstruction; and what window-aware TFP targets change (``--window-poses``,
docs/method.md; the pairs: ``variants.LEARNED_COMPARISONS`` and ``WINDOW_COMPARISONS``). Pairs whose rows
the folder lacks are left out. ``--per-scene`` adds each scene's PSNR differences.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from spikenerf.pipelines.benchmark.results import extra_differences_markdown


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="a benchmark folder with results.json")
    parser.add_argument(
        "--per-scene",
        action="store_true",
        help="also print each scene's PSNR difference per pair: the mean over seeds, then each seed's",
    )
    args = parser.parse_args()
    print(extra_differences_markdown(args.out / "results.json", args.per_scene))


if __name__ == "__main__":
    main()
