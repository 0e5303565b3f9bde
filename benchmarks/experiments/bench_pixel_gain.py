"""What ``integral.pixel_gain`` (spike-integral's learned per-pixel response) does to test PSNR, and how well
its map matches the simulator's fixed pattern (docs/camera.md, Learning the per-pixel response).

Run the benchmark twice, the option off and on, on the same settings (one thread per training)::

    spikenerf --threads 1 benchmark --scenes analytic-blocks --methods spike-integral --color gray \\
      --size 64 --frames 1000 --iters 300 --test-views 4 --seeds 0,1,2 --no-render --noise realistic --out OFF
    # the same with --set integral.pixel_gain=true --out ON
    python -m benchmarks.experiments.bench_pixel_gain OFF ON

Prints, per metric, each folder's mean over seeds and the paired difference ON − OFF with its 95 % Student-t
interval; then, for a realistic dataset, each ON run's map against the true log-response
``log(g_p / φ_p)`` drawn again from the dataset's seed (both centred): the correlation and the regression
slope (1: the full amplitude).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import yaml

from spikenerf.camera.noise import noise_with
from spikenerf.pipelines.benchmark.stats import t_interval
from spikenerf.train.sensor_response import SENSOR_MAP, read_sensor_map


def runs(folder: Path) -> dict[str, Path]:
    """The spike-integral run folders under a benchmark ``folder``, by name (``spike-integral-seed1``)."""
    return {
        p.name: p for p in sorted(folder.glob("runs/*/*/spike-integral*")) if (p / "metrics.json").exists()
    }


def true_log_response(dataset: Path, shape: tuple[int, ...]) -> np.ndarray:
    """The centred ``log(g_p / φ_p)`` (``shape``) of the dataset's realistic camera, drawn from its seed as
    ``SpikeCamera`` draws it (the preset's parameters, with those ``simulate --noise-param`` replaced)."""
    config = yaml.safe_load((dataset / "config.yaml").read_text())
    _, pattern_seed, _ = np.random.SeedSequence(config["seed"]).spawn(3)
    params = noise_with(config.get("noise_params"))
    pattern = params.draw_patterns(shape, float(config["threshold"]), pattern_seed)
    truth = np.log(pattern.gain / pattern.threshold * float(config["threshold"]))
    return truth - truth.mean()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("off", type=Path)
    parser.add_argument("on", type=Path)
    args = parser.parse_args()
    off, on = runs(args.off), runs(args.on)
    names = [n for n in off if n in on]
    for metric in ("psnr", "ssim"):
        a = [json.loads((off[n] / "metrics.json").read_text())["mean"][metric] for n in names]
        b = [json.loads((on[n] / "metrics.json").read_text())["mean"][metric] for n in names]
        diff = [y - x for x, y in zip(a, b, strict=True)]
        print(f"{metric}: off {np.mean(a):.4f}, on {np.mean(b):.4f}, on − off {np.mean(diff):+.4f} "
              f"per run {[round(d, 4) for d in diff]}, 95% CI {t_interval(diff)}")  # fmt: skip
    for name in names:
        config = yaml.safe_load((on[name] / "config.yaml").read_text())
        dataset = Path(config["dataset"])
        if yaml.safe_load((dataset / "config.yaml").read_text()).get("noise") != "realistic":
            continue
        learned = np.log(read_sensor_map(on[name] / SENSOR_MAP))
        truth = true_log_response(dataset, learned.shape)
        learned = learned - learned.mean()
        r = float(np.corrcoef(learned.ravel(), truth.ravel())[0, 1])
        slope = float((learned * truth).sum() / (truth * truth).sum())
        print(f"{name}: map vs true pattern r = {r:.3f}, slope {slope:.3f} (true std {truth.std():.4f})")


if __name__ == "__main__":
    main()
