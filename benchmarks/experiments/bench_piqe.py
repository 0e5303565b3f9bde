"""PIQE (``spikenerf.eval.piqe``): does it agree with the open implementations, and what does it say of
sharp renders, blurred ones and spike reconstructions? (docs/metrics.md, *PIQE*)

Run: ``.venv/bin/python -m benchmarks.experiments.bench_piqe [--reference-site SITE]``.

**Agreement** (with ``--reference-site``): SITE is the ``site-packages`` of a throwaway virtual environment
holding the references, never spikenerf's own:

    python3.11 -m venv /tmp/piqe_ref
    /tmp/piqe_ref/bin/pip install pypiqe            # numpy + OpenCV; a port of the MATLAB code
    /tmp/piqe_ref/bin/pip install --no-deps pyiqa   # only its piqe module is loaded (below)

SITE is appended to ``sys.path``, so spikenerf's numpy and torch are the ones imported. pyiqa's package
``__init__`` imports every metric it has (transformers, timm, ...); the script loads its
``pyiqa/archs/piqe_arch.py`` alone, which needs only torch. A reference that is missing is skipped.
The images: analytic scene renders (``--size`` px square, a multiple of 16, sRGB-encoded as eval scores
them) at a few orbit poses, as they are, with Gaussian noise and blurred, in float64. Both references
rescale an image so that its maximum grey level is 255 (MATLAB and spikenerf do not); the renders have a
white background, and each image is divided by its brightest grey (a change below 1e-6 for them), so that
all three see the same grey levels (an image whose brightest grey is still not 1 is skipped, and said).
The images are not quantised to 8 bits: 8-bit RGB values can give grey levels of exactly k + 0.5, which
MATLAB (and spikenerf) round up and numpy and torch round to even. pypiqe converts colour as BGR, so it is
given the grey image; pyiqa gets the RGB image and the grey one. Printed: each image's scores and the
largest absolute difference per reference. pyiqa builds its Gaussian window in float32, which moves its
scores by about 1e-3 here; the ``pyiqa f64`` column scores the grey image again with that window built in
float64 (the same formula, patched in for this run).

**Reconstructions** (always): for each scene, the grey sharp frame at step 0, the same frame blurred by 1 px,
and the TFP reconstruction (window 41, the middle of a 200-step stream of that static frame) from an
ideal and from a realistic-noise spike camera, all sRGB-encoded: the images that ``eval``'s checks score.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import types
from pathlib import Path
from typing import Any

import numpy as np
from scipy.ndimage import gaussian_filter

from spikenerf.camera.model import CameraConfig
from spikenerf.camera.reconstruct import tfp
from spikenerf.camera.simulation import simulate
from spikenerf.core.color import GRAY_WEIGHTS, rgb_to_gray, srgb_encode
from spikenerf.eval.piqe import piqe
from spikenerf.scenes.analytic import AnalyticSource
from spikenerf.scenes.trajectory import orbit

SCENES = ("analytic-orbs", "analytic-blocks")
STEPS = (0, 300, 600)
NOISE = (0.01, 0.03, 0.1)
BLUR = (1.0, 2.5)


def _pyiqa_piqe(site: Path):  # type: ignore[no-untyped-def]
    """pyiqa's ``piqe`` function, loaded without the package ``__init__``; None where it is absent."""
    root = site / "pyiqa"
    if not (root / "archs" / "piqe_arch.py").is_file():
        return None
    for name, path in (("pyiqa", root), ("pyiqa.archs", root / "archs"), ("pyiqa.utils", root / "utils")):
        module = types.ModuleType(name)
        module.__path__ = [str(path)]
        sys.modules[name] = module
    return importlib.import_module("pyiqa.archs.piqe_arch").piqe


def _float64_window(size: int, sigma: float, channels: int = 1, filter_type: str = "gaussian") -> Any:
    """pyiqa's ``fspecial`` Gaussian (channels, 1, size, size), computed and kept in float64."""
    import torch

    taps = np.arange(size) - (size - 1) / 2
    h = np.exp(-np.add.outer(taps**2, taps**2) / (2 * sigma**2))
    return torch.from_numpy(h / h.sum()).repeat(channels, 1, 1, 1)


def images(size: int, seed: int) -> list[tuple[str, np.ndarray]]:
    """(label, display RGB (H, W, 3) in [0, 1], its brightest grey 1) of each test image."""
    rng = np.random.default_rng(seed)
    path = orbit(4.0, 30.0)
    out = []
    for scene in SCENES:
        source = AnalyticSource(scene, size, size, path)
        for step in STEPS:
            clean = np.asarray(srgb_encode(source.render(path.poses[step])), dtype=np.float64)
            out.append((f"{scene} step {step}", clean))
            for sigma in NOISE:
                out.append((f"  + noise {sigma}", clean + sigma * rng.standard_normal(clean.shape)))
            for sigma in BLUR:
                out.append(
                    (f"  blurred {sigma} px", gaussian_filter(clean, (sigma, sigma, 0), mode="nearest"))
                )
    out = [(label, np.clip(x, 0, 1)) for label, x in out]
    return [(label, np.clip(x / (x @ np.asarray(GRAY_WEIGHTS)).max(), 0, 1)) for label, x in out]


def agreement(site: Path, size: int, seed: int) -> None:
    """Print our scores beside pypiqe's and pyiqa's (see the module doc) and the largest differences."""
    sys.path.append(str(site))
    try:
        from pypiqe import piqe as pypiqe
    except ImportError as err:
        print(f"pypiqe: not loaded ({err})")
        pypiqe = None
    pyiqa = _pyiqa_piqe(site)
    if pyiqa is None:
        print("pyiqa: not found")
    import torch

    worst: dict[str, float] = {}
    print(
        f"{'image':32} {'ours RGB':>9} {'ours grey':>9} {'pypiqe':>9} {'pyiqa RGB':>9} {'pyiqa grey':>10} "
        f"{'pyiqa f64':>9}"
    )
    for label, rgb in images(size, seed):
        grey = rgb @ np.asarray(GRAY_WEIGHTS)
        if grey.max() < 1 - 1e-9:  # the references would rescale it: not the same levels
            print(f"{label}: skipped, its brightest grey is {grey.max():.4f}, not 1")
            continue
        ours, ours_grey = piqe(rgb).score, piqe(grey).score
        row = {"ours grey": ours_grey}
        if pypiqe is not None:
            row["pypiqe"] = float(pypiqe(grey)[0])
        if pyiqa is not None:
            chw = torch.from_numpy(np.ascontiguousarray(rgb.transpose(2, 0, 1)))
            row["pyiqa RGB"] = float(pyiqa(chw[None])[0])
            row["pyiqa grey"] = float(pyiqa(torch.from_numpy(grey)[None, None])[0])
            func_util = sys.modules["pyiqa.archs.func_util"]
            fspecial, func_util.fspecial = func_util.fspecial, _float64_window
            try:
                row["pyiqa f64"] = float(pyiqa(torch.from_numpy(grey)[None, None])[0])
            finally:
                func_util.fspecial = fspecial
        for key, value in row.items():
            mine = ours if key in ("pyiqa RGB", "ours grey") else ours_grey
            worst[key] = max(worst.get(key, 0.0), abs(value - mine))
        cells = [f"{row.get(k, float('nan')):9.4f}" for k in ("ours grey", "pypiqe", "pyiqa RGB")]
        last = f"{row.get('pyiqa grey', float('nan')):10.4f} {row.get('pyiqa f64', float('nan')):9.4f}"
        print(f"{label:32} {ours:9.4f} {' '.join(cells)} {last}")
    for key, value in worst.items():
        if key != "ours grey":
            print(f"max |ours - {key}| = {value:.3g}")
    print(f"max |ours RGB - ours grey| = {worst['ours grey']:.3g} (the same grey levels, both ways)")


def reconstructions(size: int, seed: int) -> None:
    """Print PIQE of the sharp grey frame, the frame blurred by 1 px and its TFP reconstructions."""
    path = orbit(4.0, 30.0)
    print(f"\n{'scene':16} {'sharp':>6} {'blur 1px':>8} {'TFP ideal':>9} {'TFP realistic':>13}")
    for scene in SCENES:
        grey = rgb_to_gray(AnalyticSource(scene, size, size, path).render(path.poses[0]), channel_axis=-1)
        scores = [piqe(srgb_encode(grey)).score, piqe(srgb_encode(gaussian_filter(grey, 1.0))).score]
        for noise in ("ideal", "realistic"):
            spikes = simulate([grey] * 200, size, size, CameraConfig(noise=noise, seed=seed))
            scores.append(piqe(srgb_encode(tfp(spikes, window=41)[100])).score)
        print(f"{scene:16} {scores[0]:6.1f} {scores[1]:8.1f} {scores[2]:9.1f} {scores[3]:13.1f}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reference-site", type=Path, help="site-packages holding pypiqe and/or pyiqa")
    parser.add_argument("--size", type=int, default=128, help="image side, px (a multiple of 16)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.reference_site is not None:
        agreement(args.reference_site, args.size, args.seed)
    reconstructions(args.size, args.seed)


if __name__ == "__main__":
    main()
