"""Paired differences of the rows beyond the paper's claims in a benchmark folder, with 95 % intervals.

Run: ``.venv/bin/python -m benchmarks.learned_differences OUT`` after ``spikenerf benchmark ... --out OUT``
with the variants below. The benchmark's own ``differences.md`` holds the paper's claims (Spike-NeRF
against its baselines); this prints, with the same statistics (``pipelines.stats.differences``), what the
learned reconstructor changes: NeRF on learned vs TFP images, Spike-NeRF on learned vs TFP targets, and
Spike-NeRF vs NeRF when both use the learned reconstruction; and what window-aware TFP targets change
(``--window-poses``, docs/method.md). Pairs whose rows the folder lacks are left out.
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
    args = parser.parse_args()
    data = json.loads((args.out / "results.json").read_text())
    cells = [Cell(**c) for c in data["cells"]]
    colors = sorted({c.color for c in cells})
    print(to_markdown(differences_table(differences(cells, colors, LEARNED + WINDOW))))


if __name__ == "__main__":
    main()
