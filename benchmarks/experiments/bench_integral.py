"""spike-integral's window length L and steps per window S: test PSNR and seconds per iteration of each
setting, against the oracle (``nerf-gt``) and window-aware Spike-NeRF trained in the same run.

Run (one dataset, every setting trained with the same seed and thread count, then ``eval --lpips none``)::

    spikenerf --threads 1 simulate --scene analytic-orbs --width 100 --height 100 --color gray --out DS
    python -m benchmarks.experiments.bench_integral DS --iters 1000 \\
        --settings 11x1,11x2,11x4,11x8,41x4,41x8 --out OUT

With ``--paired DS2,DS3 --seeds 0,1,2`` it instead trains the oracle, window-aware NeRF + TFP, window-aware
Spike-NeRF, NeRF on learned reconstructions and spike-integral's defaults (``--variants`` picks some of them,
``--color rgb`` trains the RGB stream) on every dataset and seed, and prints the paired differences with
95% intervals (``spikenerf.pipelines.benchmark.stats.differences``, the benchmark's own statistics).

Each row prints the test PSNR, its difference to the oracle, and the seconds per iteration as a ratio to
window-aware Spike-NeRF's (the method ``train`` defaulted to before spike-integral). Finished runs in OUT are
reused, so an interrupted sweep resumes. Training is deterministic for a given thread count; the seconds
depend on the machine's load, which is why only their ratio is printed.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

#: the reference rows: (name, train flags)
REFERENCES = (
    ("nerf-gt (oracle)", ["--method", "nerf-gt"]),
    (
        "spike-nerf, window-aware",
        ["--method", "spike-nerf", "--window-poses", "4", "--set", "targets.mask=true"],
    ),
)


def parse_settings(text: str) -> list[tuple[int, int]]:
    """``11x2,41x4`` → [(11, 2), (41, 4)] (window length L × steps per window S)."""
    out = []
    for item in text.split(","):
        length, _, samples = item.partition("x")
        out.append((int(length), int(samples or 2)))
    return out


def train_and_eval(dataset: Path, out: Path, flags: list[str], iters: int, seed: int) -> tuple[float, float]:
    """(test PSNR in dB, seconds per iteration) of one run, trained unless ``out/metrics.json`` exists."""
    timing = out / "bench_seconds.json"
    if not (out / "metrics.json").is_file():
        cli = [sys.executable, "-m", "spikenerf", "--threads", "1"]
        start = time.perf_counter()
        subprocess.run([*cli, "train", str(dataset), "--iters", str(iters), "--seed", str(seed), "--quiet",
                        "--out", str(out), *flags], check=True)  # fmt: skip
        seconds = time.perf_counter() - start
        subprocess.run([*cli, "eval", str(out), "--lpips", "none"], check=True, capture_output=True)
        timing.write_text(json.dumps({"seconds": seconds}))
    seconds = json.loads(timing.read_text())["seconds"] if timing.is_file() else float("nan")
    psnr = json.loads((out / "metrics.json").read_text())["mean"]["psnr"]
    return float(psnr), seconds / iters


#: the paired comparison's rows: variant name -> train flags (spike-integral with its defaults)
PAIRED = {
    "nerf-gt": ["--method", "nerf-gt"],
    "nerf-recon-window": ["--method", "nerf-recon", "--window-poses", "4"],
    # with the masks the benchmark's window-aware row keeps (train's default drops them there)
    "spike-nerf-window": ["--method", "spike-nerf", "--window-poses", "4", "--set", "targets.mask=true"],
    "nerf-recon-learned": ["--method", "nerf-recon", "--recon", "learned"],
    "spike-integral": ["--method", "spike-integral"],
}
#: (ours, baseline) pairs printed by ``--paired``
PAIRS = (
    ("spike-integral", "nerf-gt"),
    ("spike-integral", "spike-nerf-window"),
    ("spike-integral", "nerf-recon-window"),
    ("spike-integral", "nerf-recon-learned"),
)


def paired(
    datasets: list[Path], seeds: list[int], out: Path, iters: int, variants: list[str], color: str = "gray"
) -> None:
    """Train the ``variants`` (:data:`PAIRED` names) on each dataset and seed (``OUT/DATASET/VARIANT-sK``);
    print per-row and per-scene means and the paired table of the :data:`PAIRS` among them."""
    from spikenerf.pipelines.benchmark.stats import differences
    from spikenerf.pipelines.benchmark.tables import Cell, differences_table, to_markdown

    cells = []
    for dataset in datasets:
        for seed in seeds:
            for variant in variants:
                folder = out / dataset.name / f"{variant}-s{seed}"
                flags = [*PAIRED[variant], "--color", color]
                psnr, _ = train_and_eval(dataset, folder, flags, iters, seed)
                ssim = json.loads((folder / "metrics.json").read_text())["mean"]["ssim"]
                cells.append(Cell(dataset.name, variant, color, psnr, ssim, seed=seed))
    print("| variant | " + " | ".join(d.name for d in datasets) + " | mean |")
    print("|---|" + "---:|" * (len(datasets) + 1))
    for variant in variants:
        means = [
            sum(c.psnr for c in cells if c.variant == variant and c.scene == d.name) / len(seeds)
            for d in datasets
        ]
        print(
            f"| {variant} | " + " | ".join(f"{m:.2f}" for m in means) + f" | {sum(means) / len(means):.2f} |"
        )
    pairs = tuple(p for p in PAIRS if p[0] in variants and p[1] in variants)
    print(to_markdown(differences_table(differences(cells, [color], pairs))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--iters", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--settings", default="11x1,11x2,11x4,11x8,41x4,41x8", help="LxS,LxS,…")
    parser.add_argument("--paired", default="", help="more datasets (comma list): the paired comparison")
    parser.add_argument("--seeds", default="0", help="training seeds of the paired comparison")
    parser.add_argument("--variants", default=",".join(PAIRED), help="rows of the paired comparison")
    parser.add_argument("--color", choices=("gray", "rgb"), default="gray", help="stream of the comparison")
    args = parser.parse_args()
    if args.paired:
        datasets = [args.dataset, *(Path(p) for p in args.paired.split(","))]
        variants = args.variants.split(",")
        unknown = sorted(set(variants) - set(PAIRED))
        if unknown:
            parser.error(f"--variants: unknown {', '.join(unknown)} (known: {', '.join(PAIRED)})")
        paired(datasets, [int(s) for s in args.seeds.split(",")], args.out, args.iters, variants, args.color)
        return
    rows = []
    for name, flags in REFERENCES:
        folder = args.out / name.split()[0].replace(",", "")
        rows.append((name, *train_and_eval(args.dataset, folder, flags, args.iters, args.seed)))
    for length, samples in parse_settings(args.settings):
        flags = ["--method", "spike-integral", "--integral-window", str(length), "--integral-samples",
                 str(samples)]  # fmt: skip
        folder = args.out / f"integral-L{length}-S{samples}"
        rows.append((f"spike-integral L={length} S={samples}",
                     *train_and_eval(args.dataset, folder, flags, args.iters, args.seed)))  # fmt: skip
    oracle, reference = rows[0][1], rows[1][2]
    print("| run | test PSNR (dB) | − oracle (dB) | s/iteration ÷ window-aware Spike-NeRF's |")
    print("|---|---:|---:|---:|")
    for name, psnr, per_iter in rows:
        print(f"| {name} | {psnr:.2f} | {psnr - oracle:+.2f} | {per_iter / reference:.2f}× |")


if __name__ == "__main__":
    main()
