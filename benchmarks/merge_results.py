"""Tables I/II and the paired differences of several benchmark folders' cells taken together.

Run: ``.venv/bin/python -m benchmarks.merge_results A/results.json B/results.json ...``

Use it when the seeds of one benchmark ran as separate ``spikenerf benchmark --seeds K`` calls (e.g. on a
GPU host lent for a few minutes at a time, where each call had to fit its own time limit). Every file must
come from the same scenes, size, frames, iterations, dataset seed and extra train arguments; a cell that
two files both hold (same scene, colour, variant and training seed) is refused. The tables and the
differences are computed by the benchmark's own functions (``pipelines.tables``, ``pipelines.stats``), so
they read exactly as a single ``--seeds 0,1,...`` run would have written them.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from spikenerf.pipelines.results import differences_markdown, seed_note
from spikenerf.pipelines.stats import differences
from spikenerf.pipelines.tables import Cell, table1_markdown, table2_markdown
from spikenerf.pipelines.variants import ABLATION_VARIANTS, TABLE1_VARIANTS

#: config entries that must agree between the merged folders
SAME = (
    "scenes", "size", "frames", "iters", "field_kind", "seed", "test_views", "blur_views", "extra_train_args",
)  # fmt: skip


def load(paths: list[Path]) -> tuple[dict, list[Cell], dict[str, str]]:
    """The shared config, every cell and the 'trained on' texts of ``paths`` (results.json files)."""
    config, cells, trained_on, seen = None, [], {}, set()
    for path in paths:
        data = json.loads(path.read_text())
        mine = {k: data["config"][k] for k in SAME}
        if config is not None and mine != config:
            diff = [k for k in SAME if mine[k] != config[k]]
            sys.exit(f"{path}: its benchmark differs from {paths[0]} in {', '.join(diff)}")
        config = mine
        for c in data["cells"]:
            key = (c["scene"], c["color"], c["variant"], c["seed"])
            if key in seen:
                sys.exit(f"{path}: cell {'/'.join(map(str, key))} is also in an earlier file")
            seen.add(key)
            cells.append(Cell(**c))
        trained_on.update(data.get("trained_on", {}))
    assert config is not None
    return config, cells, trained_on


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path, nargs="+", help="results.json of each benchmark folder")
    args = parser.parse_args()
    config, cells, views = load(args.results)
    colors = sorted({c.color for c in cells}, key=["gray", "rgb"].index)
    variants = list(dict.fromkeys(c.variant for c in cells))
    seeds = sorted({c.seed for c in cells})
    print(f"{len(cells)} cells from {len(args.results)} folders; {seed_note(seeds)}\n")
    t1 = [v for v in variants if v in TABLE1_VARIANTS]
    blocks = [table1_markdown(cells, t1, config["scenes"], c, views) for c in colors]
    print("# Table I\n\n" + "\n\n".join(blocks))
    if any(v in ABLATION_VARIANTS for v in variants):
        print("\n# Table II\n\n" + "\n\n".join(table2_markdown(cells, c, views) for c in colors))
    print("\n" + differences_markdown(differences(cells, colors)))


if __name__ == "__main__":
    main()
