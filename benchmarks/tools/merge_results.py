"""Tables I/II and the paired differences of several benchmark folders' cells taken together.

Run: ``.venv/bin/python -m benchmarks.tools.merge_results A/results.json B/results.json ...``

Use it when the seeds of one benchmark ran as separate ``spikenerf benchmark --seeds K`` calls (e.g. on a
GPU host lent for a few minutes at a time, where each call had to fit its own time limit). Every file must
come from the same scenes, size, frames, iterations, dataset seed and extra train arguments; a cell that
two files both hold (same scene, colour, variant and training seed) is refused. The tables and the
differences are computed by the benchmark's own functions
(``spikenerf.pipelines.benchmark.results.merged_markdown``), so they read exactly as a single
``--seeds 0,1,...`` run would have written them.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from spikenerf.core.errors import InputError
from spikenerf.pipelines.benchmark.results import merged_markdown


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path, nargs="+", help="results.json of each benchmark folder")
    args = parser.parse_args()
    try:
        print(merged_markdown(args.results))
    except InputError as err:
        sys.exit(str(err))


if __name__ == "__main__":
    main()
