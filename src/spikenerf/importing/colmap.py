"""Estimate keyframe poses of a spike recording with COLMAP (through the optional ``pycolmap``).

Keyframes are TFP reconstructions written as 8-bit sRGB PNGs named by their spike step; COLMAP extracts SIFT
features (one shared camera), matches them sequentially (a video) and runs incremental mapping. The largest
model is written as text and read back by :func:`spikenerf.importing.colmap_model.read_colmap_text`, so
estimated and imported COLMAP models share one reader. The work folder is kept between attempts: a finished
model is reused.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import sys
from collections.abc import Iterator
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from spikenerf.core.color import display_uint8, srgb_encode
from spikenerf.core.errors import InputError
from spikenerf.importing.alignment import trajectory_jump
from spikenerf.importing.colmap_model import COLMAP_MISSING, read_colmap_text
from spikenerf.importing.pose_set import PoseSet

MODEL_DIR = "model"
#: reprojection error (pixels) where the final bundle adjustment's Cauchy loss starts to flatten
ROBUST_SCALE = 0.5


@dataclass(frozen=True)
class ColmapSettings:
    """How COLMAP runs on the keyframes (docs/real-data.md; the CLI flags have the same names).

    Attributes:
        focal: focal length in pixels when known (fixed, principal point at the centre); None: estimated.
        overlap: sequential-matching neighbours (more than ``exhaustive_up_to`` keyframes).
        exhaustive_up_to: match every pair up to this many keyframes (closes the loop of an orbit).
        max_features: SIFT features per image. peak_threshold: SIFT's contrast threshold (lower: more
        features in flat, low-contrast images). affine: affine-shape SIFT with domain-size pooling.
        upsample: SIFT starts at twice the image size (COLMAP's default, octave −1); off: at the image size
        (API only, not measured on the benchmark). contrast: local contrast normalisation of the
        keyframes, the Gaussian's sigma in pixels (0: off; see :func:`write_keyframes`).
        final_ba: a last global bundle adjustment of the largest model with a robust (Cauchy, 0.5 px) loss,
            the focal fixed when known. COLMAP's own bundle adjustments use a plain squared loss, so a few
            wrong matches that pass its 4 px filter tilt the cameras; on the benchmark scenes this step
            lowered the rotation error in every one of 12 models (docs/real-data.md).
        seed: COLMAP's random seed (RANSAC); with one thread a run is repeatable.
    """

    focal: float | None = None
    overlap: int = 10
    exhaustive_up_to: int = 120
    max_features: int = 8192
    peak_threshold: float = round(0.02 / 3, 6)  # as the CLI shows and passes it
    affine: bool = False
    upsample: bool = True
    contrast: float = 0.0
    final_ba: bool = True
    seed: int = 0


def require_pycolmap() -> object:
    """The ``pycolmap`` module; InputError with the one-line install hint when it is missing."""
    try:
        import pycolmap
    except ImportError as err:
        raise InputError(COLMAP_MISSING) from err
    return pycolmap


def write_keyframes(images: np.ndarray, steps: np.ndarray, folder: Path, contrast: float = 0.0) -> list[str]:
    """Write linear gray keyframes (N, H, W) as ``{step:06d}.png`` (8-bit sRGB); returns their names.

    ``contrast`` > 0: local contrast normalisation, each pixel's sRGB value minus the Gaussian-weighted local
    mean over the local standard deviation, with a Gaussian of that many pixels (dark and bright parts of
    the scene then give SIFT features alike); 0: the global exposure only.
    """
    import imageio.v3 as iio

    folder.mkdir(parents=True, exist_ok=True)
    names = []
    for image, step in zip(images, steps, strict=True):
        name = f"{int(step):06d}.png"
        scaled = image / max(float(np.percentile(image, 99.5)), 1e-6)  # exposure: use the full 8-bit range
        encoded = srgb_encode(np.clip(scaled, 0, 1))
        if contrast > 0:
            encoded = local_contrast(encoded, contrast)
        iio.imwrite(folder / name, display_uint8(encoded))
        names.append(name)
    return names


def local_contrast(image: np.ndarray, sigma: float) -> np.ndarray:
    """(H, W) in [0, 1] → (H, W) in [0, 1]: ``0.5 + (x − mean) / (6·std)``, local Gaussian mean and std."""
    from scipy.ndimage import gaussian_filter

    centred = image - gaussian_filter(image, sigma, mode="reflect")
    std = np.sqrt(gaussian_filter(centred**2, sigma, mode="reflect"))
    spread = np.maximum(std, 0.02)  # flat areas: not blown up to pure noise
    return np.clip(0.5 + centred / (6 * spread), 0, 1)


def colmap_fingerprint(images: np.ndarray, steps: np.ndarray, settings: ColmapSettings) -> str:
    """What identifies a COLMAP model: a hash of the keyframe images (N, H, W) themselves (so another
    recording, ``--range``, ``--window``, ``--layout`` or ``--raw-width`` never reuses it), their steps and
    the settings."""
    digest = hashlib.sha256(np.ascontiguousarray(images, dtype=np.float32).tobytes()).hexdigest()
    return json.dumps({"steps": [int(s) for s in steps], "images": digest, **asdict(settings)})


def run_colmap(
    images: np.ndarray,
    steps: np.ndarray,
    work: Path,
    settings: ColmapSettings = ColmapSettings(),
    min_registered: float = 0.5,
    keyframe_every: int | None = None,
    threads: int = -1,
    verbose: bool = False,
) -> PoseSet:
    """Estimate the poses of keyframes (N, H, W), linear gray, at spike ``steps`` (N,); see ColmapSettings.

    Returns:
        A :class:`PoseSet` of the registered keyframes (steps from their names, a shared camera, points).
    Raises:
        InputError: pycolmap is missing, or fewer than ``min_registered`` of the keyframes register (the
            message says how many and suggests a smaller ``--keyframe-every``).
    """
    model, stamp = work / MODEL_DIR, work / "steps.json"
    want = colmap_fingerprint(images, steps, settings)
    if stamp.is_file() and stamp.read_text() != want:  # other keyframe images (any recording/range/window)
        shutil.rmtree(work)
    if not (model / "images.txt").is_file():
        try:
            _estimate(images, steps, work, settings, (threads, verbose, want))
        except InputError:
            raise
        except (RuntimeError, ValueError, TypeError) as err:  # pycolmap's own failures
            why = (str(err).strip().splitlines() or [type(err).__name__])[0]
            raise InputError(f"COLMAP failed on the keyframes ({why})", path=work) from err
        if not (model / "images.txt").is_file():
            raise _too_few(0, len(steps), keyframe_every)
    found = read_colmap_text(model)
    if len(found.poses) < max(3, min_registered * len(steps)):
        for name in ("images", "sparse", "database.db"):  # big and rebuildable; the model stays for a rerun
            path = work / name
            shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)
        raise _too_few(len(found.poses), len(steps), keyframe_every, kept=work.parent)
    return found


def unfolded_colmap(
    images: np.ndarray, steps: np.ndarray, folders: tuple[Path, Path], settings: ColmapSettings, run: tuple
) -> PoseSet:
    """:func:`run_colmap` in ``folders[0]``, checked for a folded model.

    When the model matched every pair (the loop) and its trajectory has a jump
    (:func:`spikenerf.importing.alignment.trajectory_jump`), the keyframes are mapped again with sequential
    matching only, in ``folders[1]``, and that model is kept when it has none (its ``note`` says so).

    Args:
        images: keyframes (N, H, W), linear gray; steps: their spike steps (N,).
        run: ``(min_registered, keyframe_every, verbose)`` as :func:`run_colmap` takes them.
    Raises:
        InputError: a jump remains (names the steps), or :func:`run_colmap`'s own errors.
    """
    min_registered, keyframe_every, verbose = run
    estimate = lambda folder, cs: run_colmap(  # noqa: E731
        images, steps, folder, cs, min_registered, keyframe_every, threads=colmap_threads(), verbose=verbose
    )
    found = estimate(folders[0], settings)
    jump = trajectory_jump(found.poses, found.steps)
    if jump is not None and len(steps) <= settings.exhaustive_up_to:  # the loop pairs may have folded it
        try:
            again = estimate(folders[1], replace(settings, exhaustive_up_to=0))
        except InputError:  # too few registered sequentially: the fold is the better message
            again = None
        if again is not None and trajectory_jump(again.poses, again.steps) is None:
            return replace(again, note=f"sequential matching (matching all pairs gave a {jump.describe()})")
    if jump is not None:
        raise InputError(
            f"COLMAP's keyframe trajectory has a {jump.describe()}: the model is folded (a symmetric or "
            "repetitive scene); try another frame_range or keyframe_every, or give poses FILE",
            path=folders[0] / MODEL_DIR,
            param=("frame_range", "keyframe_every", "poses"),
        )
    return found


def _estimate(images: np.ndarray, steps: np.ndarray, work: Path, cs: ColmapSettings, run: tuple) -> None:
    """Run pycolmap (tested with 4.2) on the keyframes; writes ``work/model`` (text) unless nothing maps."""
    threads, verbose, want = run
    model = work / MODEL_DIR
    pycolmap = require_pycolmap()
    if not verbose:
        pycolmap.logging.minloglevel = 3  # fatal only: COLMAP logs drown the one-line CLI output
    for stale in ("images", "sparse", "database.db"):  # an interrupted attempt: start it over
        path = work / stale
        shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)
    image_dir, sparse = work / "images", work / "sparse"
    names = write_keyframes(images, steps, image_dir, cs.contrast)
    sparse.mkdir(parents=True)
    (work / "steps.json").write_text(want)
    db = work / "database.db"
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.use_gpu, extraction.num_threads = False, threads
    extraction.sift.max_num_features, extraction.sift.peak_threshold = cs.max_features, cs.peak_threshold
    extraction.sift.first_octave = -1 if cs.upsample else 0
    extraction.sift.estimate_affine_shape = extraction.sift.domain_size_pooling = cs.affine
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "SIMPLE_PINHOLE"
    if cs.focal is not None:
        reader.camera_params = f"{cs.focal},{images.shape[2] / 2},{images.shape[1] / 2}"
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
    matching.guided_matching = cs.affine  # affine shapes: guided matching is what COLMAP pairs them with
    if len(steps) <= cs.exhaustive_up_to:  # every pair: closes the loop of an orbit
        pycolmap.match_exhaustive(database_path=db, matching_options=matching, device=pycolmap.Device.cpu)
    else:
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = cs.overlap
        pycolmap.match_sequential(
            database_path=db, matching_options=matching, pairing_options=pairing, device=pycolmap.Device.cpu
        )
    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads, options.random_seed = threads, cs.seed
    if cs.focal is not None:
        options.ba_refine_focal_length = options.ba_refine_principal_point = False
    models = pycolmap.incremental_mapping(
        database_path=db, image_path=image_dir, output_path=sparse, options=options
    )
    if not models:
        return
    best = max(models.values(), key=lambda r: r.num_reg_images())
    if cs.final_ba:
        with contextlib.nullcontext() if verbose else _no_stderr():  # it logs its heading regardless
            _global_ba(pycolmap, best, cs.focal is not None, threads)
    tmp = work / ".model.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    best.write_text(str(tmp))
    tmp.rename(model)


@contextlib.contextmanager
def _no_stderr() -> Iterator[None]:
    """Silence file descriptor 2 (C++ logging) for the duration."""
    sys.stderr.flush()
    saved, null = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(null)


def _global_ba(pycolmap: object, model: object, fixed_focal: bool, threads: int) -> None:
    """A last global bundle adjustment of ``model`` in place (focal fixed when it was given)."""
    ba = pycolmap.BundleAdjustmentOptions()
    ba.refine_focal_length = not fixed_focal
    ba.refine_principal_point = False
    ba.refine_extra_params = ba.print_summary = False
    ba.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY  # robust to the odd wrong match
    ba.ceres.loss_function_scale = ROBUST_SCALE
    ba.ceres.solver_options.num_threads = threads
    pycolmap.bundle_adjustment(model, ba)


def _too_few(registered: int, total: int, keyframe_every: int | None, kept: Path | None = None) -> InputError:
    hint = f" (now {keyframe_every})" if keyframe_every else ""
    where = f" (its model stays in {kept}: a rerun with a lower min_registered takes it)" if kept else ""
    return InputError(
        f"COLMAP registered {registered} of {total} keyframes, too few for a trajectory{where}; try a "
        f"smaller keyframe_every{hint} so that neighbouring keyframes overlap more, or give poses FILE "
        "('orbit' with the orbit's radius and elevation for a camera that circled the scene)",
        param=("keyframe_every", "poses", "min_registered"),
    )


def colmap_threads() -> int:
    """COLMAP's threads: ``OMP_NUM_THREADS`` where set (``spikenerf --threads N`` sets it; with one thread a
    run is repeatable), else -1, every core."""
    try:
        return max(int(os.environ.get("OMP_NUM_THREADS", "")), 1)
    except ValueError:
        return -1
