"""Which part of the realistic camera noise costs a method its test PSNR: an ablation in one run.

Simulates one scene several times with the same camera seed: noise-free (``ideal``), the ``realistic``
preset, and the preset with one group of its parameters switched off (``simulate --noise-param``):

- ``no-dark``: ``dark_mean=0 dark_std=0`` (no dark current);
- ``no-fixed``: ``threshold_std=0 capacitance_std=0 prnu_std=0`` (no per-pixel threshold or gain pattern);
- ``no-temporal``: ``jitter_std=0 photons_per_white=inf readout_delay=0`` (no per-step noise);
- ``dark-only``: everything off but the dark current;
- ``fixed-only``: everything off but the per-pixel threshold and gain patterns;
- ``drop-excess``: the preset with ``excess_carry=0`` (a saturated pixel drops what it holds beyond one
  spike a step instead of firing it later).

Then trains the method on each dataset once per training seed (with ``--set KEY=VALUE`` overrides of the
training config, as ``train --set``; ``--tag`` keeps such runs apart from the others) and prints each
variant's test PSNR (the trainer's own evaluation on the held-out views) and its difference from
``realistic``, paired over the seeds (mean and 95 % t interval); with ``--tag``, also each variant's
difference from its runs without the tag (trained before, in the same folder); ``--set`` needs a
``--tag`` (its runs would otherwise share those runs' folders and results). ``--true-pattern`` holds
``integral.pixel_gain``'s map at the simulator's own per-pixel response instead of learning it (1 on an
ideal stream), in folders of their own (``-true`` after the tag). Runs that learned the map print its match
with the simulator's pattern: the correlation of the centred log-maps and the regression slope (1: the full
amplitude).

Run (one thread per training; about a minute per training at 64×64 on the development CPU)::

    python -m benchmarks.experiments.bench_noise_ablation --out /tmp/ablation --scene analytic-blocks \\
        --size 64 --frames 1000 --iters 300 --seeds 0,1,2 --jobs 2
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from spikenerf.pipelines.benchmark.stats import t_interval

ALL_OFF = {"threshold_std": 0, "capacitance_std": 0, "prnu_std": 0, "jitter_std": 0,
           "photons_per_white": math.inf, "readout_delay": 0}  # fmt: skip
VARIANTS: dict[str, dict | None] = {
    "ideal": None,
    "realistic": {},
    "no-dark": {"dark_mean": 0, "dark_std": 0},
    "no-fixed": {"threshold_std": 0, "capacitance_std": 0, "prnu_std": 0},
    "no-temporal": {"jitter_std": 0, "photons_per_white": math.inf, "readout_delay": 0},
    "dark-only": ALL_OFF,
    "fixed-only": {
        "dark_mean": 0,
        "dark_std": 0,
        "jitter_std": 0,
        "photons_per_white": math.inf,
        "readout_delay": 0,
    },
    "drop-excess": {"excess_carry": 0},
}


def suffix(args: argparse.Namespace) -> str:
    """What the folder names add for a threshold other than 1 (``-phi1.25``)."""
    return "" if args.threshold == 1.0 else f"-phi{args.threshold:g}"


def simulate(args: argparse.Namespace, name: str) -> Path:
    """The variant's dataset (simulated unless already there)."""
    out = args.out / f"data-{name}{suffix(args)}"
    if (out / "config.yaml").exists():
        return out
    params = VARIANTS[name]
    noise = ["--noise", "ideal"] if params is None else ["--noise", "realistic"]
    for key, value in (params or {}).items():
        noise += ["--noise-param", f"{key}={value}"]
    command = [sys.executable, "-m", "spikenerf", "--threads", "1", "simulate", "--scene", args.scene,
               "--width", str(args.size), "--height", str(args.size), "--frames", str(args.frames),
               "--test-views", str(args.test_views), "--blur-fps", "0", "--color", "gray", "--seed", "0",
               "--threshold", str(args.threshold),
               *noise, "--out", str(out), "--quiet"]  # fmt: skip
    subprocess.run(command, check=True)
    return out


def run_folder(args: argparse.Namespace, name: str, seed: int) -> Path:
    """The folder of one training: ``run-<variant>[-phi<φ>]<tag>[-true]-<seed>`` (``-true``: with
    ``--true-pattern``, apart from the runs that learn the map under the same tag)."""
    true = "-true" if args.true_pattern else ""
    return args.out / f"run-{name}{suffix(args)}{args.tag}{true}-{seed}"


def train(job: tuple[str, Path, int, argparse.Namespace]) -> tuple[str, int, float]:
    """(variant, seed, test PSNR) of one training (kept in its :func:`run_folder`'s ``result.json``)."""
    name, dataset, seed, args = job
    run = run_folder(args, name, seed)
    done = run / "result.json"
    if done.exists():
        return name, seed, float(json.loads(done.read_text())["psnr"])
    import torch

    torch.set_num_threads(1)
    from spikenerf.core.atomic import write_text_atomic
    from spikenerf.train.config import TrainConfig
    from spikenerf.train.config_file import apply_overrides
    from spikenerf.train.trainer import Trainer

    cfg = TrainConfig(dataset=str(dataset), method=args.method, iters=args.iters, eval_every=0,
                      eval_views=args.test_views, seed=seed, device="cpu")  # fmt: skip
    cfg = TrainConfig.from_dict(apply_overrides(cfg.to_dict(), args.set)).validate()
    if args.true_pattern:  # the simulator's own response in place of the learned map
        if not cfg.integral.pixel_gain:
            raise SystemExit(
                "--true-pattern replaces integral.pixel_gain's map: add --set integral.pixel_gain=true"
            )
        hold_true_pattern(dataset)
    # a training stopped before its result.json was written continues from its checkpoint
    psnr = float(Trainer(cfg, run, resume=True, progress=False).train().test_psnr)
    write_text_atomic(done, json.dumps({"psnr": psnr}))
    return name, seed, psnr


def true_response(dataset: Path) -> np.ndarray:
    """The dataset's per-pixel response ``g_p φ / φ_p``, float32 (H, W): its realistic camera's fixed
    patterns drawn again from its seed and ``noise_params``, as ``SpikeCamera`` draws them (gray); 1 on an
    ideal stream (every pixel nominal)."""
    import yaml

    from spikenerf.camera.noise import noise_with

    config = yaml.safe_load((dataset / "config.yaml").read_text())
    shape = (int(config["spike_h"]), int(config["spike_w"]))
    if config.get("noise") != "realistic":
        return np.ones(shape, np.float32)
    _, pattern_seed, _ = np.random.SeedSequence(config["seed"]).spawn(3)
    phi = float(config["threshold"])
    patterns = noise_with(config.get("noise_params")).draw_patterns(shape, phi, pattern_seed)
    return (patterns.gain * phi / patterns.threshold).astype(np.float32)


def hold_true_pattern(dataset: Path) -> None:
    """Make every ``SensorResponse`` of this process answer the dataset's true response (a fixed map)."""
    import torch

    from spikenerf.train.sensor_response import SensorResponse

    truth = torch.from_numpy(true_response(dataset)).reshape(1, -1)

    def factor(self: SensorResponse, pixels: torch.Tensor) -> torch.Tensor:
        width = int(self.log_response.shape[-1])
        flat = pixels[:, 1].long() * width + pixels[:, 0].long()
        return truth[:, flat.cpu()].transpose(0, 1).to(pixels.device)

    SensorResponse.factor = factor  # type: ignore[method-assign]


def map_match(run: Path, dataset: Path) -> tuple[float, float] | None:
    """(correlation, slope) of a run's learned map (``sensor_map.npy``) against the dataset's true response
    (:func:`true_response`), both as centred logs (H, W); slope 1: the full amplitude. None where the run
    has no map or the stream no pattern (an ideal stream, or one without the threshold and gain patterns)."""
    from spikenerf.train.sensor_response import SENSOR_MAP, read_sensor_map

    if not (run / SENSOR_MAP).exists():
        return None
    truth = np.log(true_response(dataset).astype(np.float64))
    if float(truth.std()) == 0.0:
        return None
    learned = np.log(read_sensor_map(run / SENSOR_MAP).astype(np.float64))
    learned, truth = learned - learned.mean(), truth - truth.mean()
    r = float(np.corrcoef(learned.ravel(), truth.ravel())[0, 1])
    return r, float((learned * truth).sum() / (truth * truth).sum())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--scene", default="analytic-blocks")
    parser.add_argument("--method", default="spike-integral")
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--test-views", type=int, default=4)
    parser.add_argument("--iters", type=int, default=300)
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument(
        "--threshold", type=float, default=1.0,
        help="the camera's φ (simulate --threshold): above 1 a white pixel fires less than once a step",
    )  # fmt: skip
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument(
        "--true-pattern", action="store_true",
        help="with --set integral.pixel_gain=true: hold the map at the simulator's own pattern",
    )  # fmt: skip
    parser.add_argument("--tag", default="", help="appended to the run folders' names (runs with --set)")
    args = parser.parse_args()
    names = args.variants.split(",")
    if unknown := [n for n in names if n not in VARIANTS]:
        parser.error(f"--variants: unknown {unknown}; known: {list(VARIANTS)}")
    if args.set and not args.tag:
        parser.error("--set needs --tag: its runs would share the folders and results of the runs without it")
    seeds = [int(s) for s in args.seeds.split(",")]
    args.out.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    datasets = {name: simulate(args, name) for name in ["realistic", *[n for n in names if n != "realistic"]]}
    jobs = [(name, path, seed, args) for name, path in datasets.items() for seed in seeds]
    with ProcessPoolExecutor(args.jobs) as pool:
        scores = {(n, s): p for n, s, p in pool.map(train, jobs)}
    base = [scores["realistic", s] for s in seeds]
    print(
        f"{args.method} on {args.scene} {args.size}×{args.size}, {args.frames} steps, "
        f"{args.iters} iterations, seeds {args.seeds}: test PSNR (dB), and the difference from realistic "
        "paired over seeds (95 % CI)"
    )
    print("| noise | PSNR (mean ± std) | − realistic | 95 % CI |")
    print("|---|---:|---:|---:|")
    for name in datasets:
        print(row(name, [scores[name, s] for s in seeds], base))
    # (a held true pattern leaves the learned map at 1: nothing to match)
    runs = [] if args.true_pattern else [(n, s, path) for n, path in datasets.items() for s in seeds]
    matches = {(n, s): map_match(run_folder(args, n, s), path) for n, s, path in runs}
    if any(m is not None for m in matches.values()):
        print("\nthe learned map against the true pattern (centred log-maps): correlation r, slope")
        for (name, seed), match in matches.items():
            if match is not None:
                print(f"{name} seed {seed}: r = {match[0]:.2f}, slope {match[1]:.2f}")
    if not args.tag:
        return
    # the same variants trained without --set, where they are there: the option's paired effect
    before = {name: untagged(args, name, seeds) for name in datasets}
    print(f"\nwith {' '.join(args.set) or 'the tag'} − without, paired over seeds (95 % CI)")
    print("| noise | PSNR (mean ± std) | − without | 95 % CI |")
    print("|---|---:|---:|---:|")
    for name, off in before.items():
        if off is not None:
            print(row(name, [scores[name, s] for s in seeds], off))


def untagged(args: argparse.Namespace, name: str, seeds: list[int]) -> list[float] | None:
    """The test PSNRs of the variant's runs without ``--tag`` (None unless every seed's is there)."""
    plain = argparse.Namespace(**{**vars(args), "tag": "", "true_pattern": False})
    files = [run_folder(plain, name, seed) / "result.json" for seed in seeds]
    if not all(f.exists() for f in files):
        return None
    return [float(json.loads(f.read_text())["psnr"]) for f in files]


def row(name: str, values: list[float], base: list[float]) -> str:
    """A table row: the mean ± std of ``values`` and their difference from ``base``, paired (95 % CI)."""
    diff = [v - b for v, b in zip(values, base, strict=True)]
    interval = t_interval(diff)
    ci = "" if interval is None else f"[{interval[0]:+.2f}, {interval[1]:+.2f}]"
    spread = f"{np.std(values, ddof=1):.2f}" if len(values) > 1 else "–"
    return f"| {name} | {np.mean(values):.2f} ± {spread} | {np.mean(diff):+.2f} | {ci} |"


if __name__ == "__main__":
    main()
