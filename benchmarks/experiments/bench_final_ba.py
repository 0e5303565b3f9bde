"""The robust final bundle adjustment of ``spikenerf import``, measured alone on finished COLMAP models.

Run: ``.venv/bin/python -m benchmarks.experiments.bench_final_ba --truth SIM MODEL [MODEL ...]``, where SIM
is the simulated dataset (exact poses) that the keyframes came from and each MODEL a COLMAP text model of its
keyframes made without the final pass (``spikenerf import --no-final-ba``: DATASET/colmap/model; images
named by spike step). ``--truth`` may be given once per model (``--truth A M1 --truth B M2``), or once.
Each model is scored against the truth
after similarity alignment (rotation error mean/max in degrees at the keyframes), then the final pass
(``importing/colmap.py: _global_ba``: Cauchy loss, 0.5 px, focal fixed with ``--fixed-focal``) runs on it
and it is scored again. Prints one row per model, the ratio after/before, and the mean paired difference with
its 95% Student-t interval.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
from scipy import stats

from spikenerf.data.dataset import load_dataset
from spikenerf.importing.alignment import trajectory_errors
from spikenerf.importing.colmap import _global_ba, _no_stderr, require_pycolmap
from spikenerf.importing.colmap_model import read_colmap_text


def score(model: Path, truth: np.ndarray) -> dict[str, float]:
    found = read_colmap_text(model)
    return trajectory_errors(found.poses, truth[found.steps])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("models", nargs="+", type=Path)
    p.add_argument("--truth", type=Path, action="append", required=True)
    p.add_argument(
        "--fixed-focal", action="store_true", help="keep the focal length (models made with --fov)"
    )
    a = p.parse_intermixed_args()
    truths = a.truth if len(a.truth) == len(a.models) else a.truth[:1] * len(a.models)
    pycolmap = require_pycolmap()
    pycolmap.logging.minloglevel = 3
    before, after = [], []
    print("| model | rot mean° before | after | rot max° before | after |\n|---|---:|---:|---:|---:|")
    for model, sim in zip(a.models, truths, strict=True):
        truth = load_dataset(sim).trajectory.poses
        b = score(model, truth)
        rec = pycolmap.Reconstruction(str(model))
        with _no_stderr():
            _global_ba(pycolmap, rec, a.fixed_focal, threads=1)
        with tempfile.TemporaryDirectory() as tmp:
            rec.write_text(tmp)
            e = score(Path(tmp), truth)
        before.append([b["rot_mean_deg"], b["rot_max_deg"]])
        after.append([e["rot_mean_deg"], e["rot_max_deg"]])
        print(
            f"| {model} | {b['rot_mean_deg']:.3f} | {e['rot_mean_deg']:.3f} | {b['rot_max_deg']:.3f} | "
            f"{e['rot_max_deg']:.3f} |",
            flush=True,
        )
    b, e = np.array(before), np.array(after)
    for i, name in enumerate(("mean", "max")):
        d = b[:, i] - e[:, i]
        half = stats.t.ppf(0.975, len(d) - 1) * d.std(ddof=1) / np.sqrt(len(d)) if len(d) > 1 else np.nan
        print(
            f"rot {name}: after/before {np.mean(e[:, i] / b[:, i]):.2f}; reduction {d.mean():.3f}° "
            f"(95% CI {d.mean() - half:.3f} to {d.mean() + half:.3f}; "
            f"{int((d > 0).sum())}/{len(d)} models lower)"
        )


if __name__ == "__main__":
    main()
