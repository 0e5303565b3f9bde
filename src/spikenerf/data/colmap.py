"""Estimate keyframe poses of a spike recording with COLMAP (through the optional ``pycolmap``).

Keyframes are TFP reconstructions written as 8-bit sRGB PNGs named by their spike step; COLMAP extracts SIFT
features (one shared camera), matches them sequentially (a video) and runs incremental mapping. The largest
model is written as text and read back by :func:`spikenerf.data.poses.read_colmap_text`, so estimated and
imported COLMAP models share one reader. The work folder is kept between attempts: a finished model is reused.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np

from spikenerf.core.color import srgb_encode
from spikenerf.core.errors import InputError
from spikenerf.data.poses import COLMAP_MISSING, PoseSet, read_colmap_text

MODEL_DIR = "model"


def require_pycolmap() -> object:
    """The ``pycolmap`` module; InputError with the one-line install hint when it is missing."""
    try:
        import pycolmap
    except ImportError as err:
        raise InputError(COLMAP_MISSING) from err
    return pycolmap


def write_keyframes(images: np.ndarray, steps: np.ndarray, folder: Path) -> list[str]:
    """Write linear gray keyframes (N, H, W) as ``{step:06d}.png`` (8-bit sRGB); returns their names."""
    import imageio.v3 as iio

    folder.mkdir(parents=True, exist_ok=True)
    names = []
    for image, step in zip(images, steps, strict=True):
        name = f"{int(step):06d}.png"
        scaled = image / max(float(np.percentile(image, 99.5)), 1e-6)  # exposure: use the full 8-bit range
        iio.imwrite(folder / name, np.round(srgb_encode(np.clip(scaled, 0, 1)) * 255).astype(np.uint8))
        names.append(name)
    return names


def colmap_fingerprint(
    images: np.ndarray, steps: np.ndarray, focal: float | None, overlap: int, exhaustive_up_to: int
) -> str:
    """What identifies a COLMAP model: a hash of the keyframe images (N, H, W) themselves (so another
    recording, ``--range``, ``--window``, ``--layout`` or ``--raw-width`` never reuses it), their steps and
    the matching settings."""
    digest = hashlib.sha256(np.ascontiguousarray(images, dtype=np.float32).tobytes()).hexdigest()
    return json.dumps(
        {
            "steps": [int(s) for s in steps],
            "images": digest,
            "focal": focal,
            "overlap": overlap,
            "exh": exhaustive_up_to,
        }
    )


def run_colmap(
    images: np.ndarray,
    steps: np.ndarray,
    work: Path,
    overlap: int = 10,
    min_registered: float = 0.5,
    keyframe_every: int | None = None,
    threads: int = -1,
    focal: float | None = None,
    exhaustive_up_to: int = 120,
    verbose: bool = False,
) -> PoseSet:
    """Estimate the poses of keyframes (N, H, W) linear gray at spike ``steps`` (N,).

    Up to ``exhaustive_up_to`` keyframes every pair is matched (it closes loops); more are matched
    sequentially with ``overlap`` neighbours (a video). ``focal`` (pixels), when known, is fixed with the
    principal point at the centre; otherwise COLMAP estimates it.

    Returns:
        A :class:`PoseSet` of the registered keyframes (steps from their names, a shared camera, points).
    Raises:
        InputError: pycolmap is missing, or fewer than ``min_registered`` of the keyframes register (the
            message says how many and suggests a smaller ``--keyframe-every``).
    """
    model, stamp = work / MODEL_DIR, work / "steps.json"
    want = colmap_fingerprint(images, steps, focal, overlap, exhaustive_up_to)
    if stamp.is_file() and stamp.read_text() != want:  # other keyframe images (any recording/range/window)
        shutil.rmtree(work)
    if not (model / "images.txt").is_file():
        try:
            _estimate(images, steps, work, (overlap, threads, focal, exhaustive_up_to, verbose), want)
        except InputError:
            raise
        except (RuntimeError, ValueError, TypeError) as err:  # pycolmap's own failures
            why = (str(err).strip().splitlines() or [type(err).__name__])[0]
            raise InputError(f"COLMAP failed on the keyframes ({why})", path=work) from err
        if not (model / "images.txt").is_file():
            raise _too_few(0, len(steps), keyframe_every)
    found = read_colmap_text(model)
    if len(found.poses) < max(3, min_registered * len(steps)):
        raise _too_few(len(found.poses), len(steps), keyframe_every)
    return found


def _estimate(images: np.ndarray, steps: np.ndarray, work: Path, settings: tuple, want: str) -> None:
    """Run pycolmap (tested with 4.2) on the keyframes; writes ``work/model`` (text) unless nothing maps."""
    overlap, threads, focal, exhaustive_up_to, verbose = settings
    model = work / MODEL_DIR
    pycolmap = require_pycolmap()
    if not verbose:
        pycolmap.logging.minloglevel = 3  # fatal only: COLMAP logs drown the one-line CLI output
    for stale in ("images", "sparse", "database.db"):  # an interrupted attempt: start it over
        path = work / stale
        shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)
    image_dir, sparse = work / "images", work / "sparse"
    names = write_keyframes(images, steps, image_dir)
    sparse.mkdir(parents=True)
    (work / "steps.json").write_text(want)
    db = work / "database.db"
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.use_gpu, extraction.num_threads = False, threads
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "SIMPLE_PINHOLE"
    if focal is not None:
        reader.camera_params = f"{focal},{images.shape[2] / 2},{images.shape[1] / 2}"
    pycolmap.extract_features(
        database_path=db,
        image_path=image_dir,
        image_names=names,
        camera_mode=pycolmap.CameraMode.SINGLE,
        reader_options=reader,
        extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )
    matching = pycolmap.FeatureMatchingOptions()
    matching.use_gpu, matching.num_threads = False, threads
    if len(steps) <= exhaustive_up_to:  # every pair: closes the loop of an orbit
        pycolmap.match_exhaustive(database_path=db, matching_options=matching, device=pycolmap.Device.cpu)
    else:
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = overlap
        pycolmap.match_sequential(
            database_path=db, matching_options=matching, pairing_options=pairing, device=pycolmap.Device.cpu
        )
    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads, options.random_seed = threads, 0
    if focal is not None:
        options.ba_refine_focal_length = options.ba_refine_principal_point = False
    models = pycolmap.incremental_mapping(
        database_path=db, image_path=image_dir, output_path=sparse, options=options
    )
    if not models:
        return
    best = max(models.values(), key=lambda r: r.num_reg_images())
    tmp = work / ".model.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    best.write_text(str(tmp))
    tmp.rename(model)


def _too_few(registered: int, total: int, keyframe_every: int | None) -> InputError:
    hint = f" (now {keyframe_every})" if keyframe_every else ""
    return InputError(
        f"COLMAP registered {registered} of {total} keyframes, too few for a trajectory; try a smaller "
        f"keyframe_every{hint} so that neighbouring keyframes overlap more, or give poses FILE",
        param=("keyframe_every", "poses"),
    )
