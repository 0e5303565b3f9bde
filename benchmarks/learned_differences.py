"""Paired differences of the rows beyond the paper's claims in a benchmark folder, with 95 % intervals.

Run: ``.venv/bin/python -m benchmarks.learned_differences OUT [--per-scene]`` after ``spikenerf
benchmark ... --out OUT`` with the variants below. The benchmark's own ``differences.md`` holds the
paper's claims (Spike-NeRF against its baselines); this prints, with the same statistics
(``pipelines.stats.differences``), what the learned reconstructor changes: NeRF on learned vs TFP
images, Spike-NeRF on learned vs TFP targets, and Spike-NeRF vs NeRF when both use the learned
reconstruction; and what window-aware TFP targets change (``--window-poses``, docs/method.md). Pairs
whose rows the folder lacks are left out. ``--per-scene`` adds each scene's PSNR differences.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from spikenerf.pipelines.stats import differences
from spikenerf.pipelines.tables import Cell, differences_table, to_markdown

#: (ours, baseline) pairs that isolate the learned reconstructor's effect
LEARNED = (
    ("nerf-recon-learned", "nerf-recon"),
    ("spike-nerf-learned", "spike-nerf"),
    ("spike-nerf-learned", "nerf-recon-learned"),
)
#: (ours, baseline) pairs that isolate the window-aware targets' effect
WINDOW = (
    ("nerf-recon-window", "nerf-recon"),
    ("spike-nerf-window", "spike-nerf"),
    ("spike-nerf-window", "nerf-recon-window"),
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="a benchmark folder with results.json")
    parser.add_argument(
        "--per-scene",
        action="store_true",
        help="also print each scene's PSNR difference per pair: the mean over seeds, then each seed's",
    )
    args = parser.parse_args()
    data = json.loads((args.out / "results.json").read_text())
    cells = [Cell(**c) for c in data["cells"]]
    colors = sorted({c.color for c in cells})
    print(to_markdown(differences_table(differences(cells, colors, LEARNED + WINDOW))))
    if args.per_scene:
        for color in colors:
            print(f"\n{color}, PSNR (dB):\n")
            print(per_scene_table([c for c in cells if c.color == color], PAPER + WINDOW))


#: the paper's headline pair, printed per scene beside the pairs above
PAPER = (("spike-nerf", "nerf-recon"),)


def per_scene_table(cells: list[Cell], pairs: tuple[tuple[str, str], ...]) -> str:
    """A Markdown table: one row per scene, one column per (ours, baseline) pair that the scene has for
    every seed; each entry is the mean PSNR difference over the paired seeds, then each seed's."""
    psnr = {(c.scene, c.variant, c.seed): c.psnr for c in cells}
    scenes = list(dict.fromkeys(c.scene for c in cells))
    seeds = sorted({c.seed for c in cells})
    lines = ["| scene | " + " | ".join(f"{a} − {b}" for a, b in pairs) + " |", "|---|" + "---:|" * len(pairs)]
    for scene in scenes:
        entries = []
        for ours, base in pairs:
            d = [psnr[scene, ours, k] - psnr[scene, base, k] for k in seeds
                 if (scene, ours, k) in psnr and (scene, base, k) in psnr]  # fmt: skip
            each = ", ".join(f"{x:+.2f}" for x in d)
            entries.append(f"{sum(d) / len(d):+.2f} ({each})" if d else "—")
        lines.append(f"| {scene} | " + " | ".join(entries) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
