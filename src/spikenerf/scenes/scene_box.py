"""The scene box of an image sequence whose transforms.json gives none: an axis-aligned box around the point
the cameras' optical axes meet, with a warning where the cameras do not move or one lies far off the others
(``scenes/sequence.py``, ``docs/sequence.md``)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from spikenerf.core.errors import InputError

#: half-size of an estimated scene box, as a fraction of the nearest camera's distance to the box centre.
SCENE_BOX_FACTOR = 0.5
#: cameras whose positions all lie within this fraction of their distance to the estimated centre do not
#: move (no parallax): the estimated scene box is then a guess, which is warned of
STILL_FRACTION = 1e-3
#: a camera this many times further from the cameras' median position than their median distance to it is
#: named in a warning (a wrong translation, e.g. other units)
FAR_FACTOR = 1000.0


def estimate_scene_box(
    poses: np.ndarray, factor: float = SCENE_BOX_FACTOR, path: Path | None = None
) -> np.ndarray:
    """Axis-aligned box around the region the cameras look at.

    The centre is the least-squares point closest to all optical axes (camera centre, −Z direction); the
    half-size is ``factor`` × the nearest camera's distance to it. When the axes are (nearly) parallel or
    the point lies behind the cameras, the centre is put ahead of the mean camera by the cameras' spread
    (at least 1 unit) — a rough guess; give a ``scene_box`` key then.

    A warning (naming ``path``) says when the cameras do not move (no parallax: the box is a guess) or one
    lies orders of magnitude further than the others (``FAR_FACTOR``: a wrong pose, naming its frame); an
    InputError when no finite box comes out.

    Args:
        poses: (N, 4, 4) camera-to-world of ``frames[0…N−1]``. Returns: (2, 3) float64 (min, max).
    """
    box, converged = _estimate(poses, factor)
    _check_cameras(poses, box, path, converged)
    return box


def _estimate(poses: np.ndarray, factor: float) -> tuple[np.ndarray, bool]:
    """:func:`estimate_scene_box`'s box (2, 3) of ``poses`` (N, 4, 4), and whether the optical axes meet
    ahead of the cameras (else the centre is a guess)."""
    origins = poses[:, :3, 3]
    dirs = -poses[:, :3, 2] / np.linalg.norm(poses[:, :3, 2], axis=-1, keepdims=True)
    proj = np.eye(3) - dirs[:, :, None] * dirs[:, None, :]  # (N, 3, 3) projections orthogonal to each axis
    with np.errstate(over="ignore", invalid="ignore"):  # (positions near the float limit: refused later)
        a, b = proj.sum(0), np.einsum("nij,nj->i", proj, origins)
        centre, converged = None, False
        if np.linalg.eigvalsh(a / len(poses)).min() > 1e-3:
            centre = np.linalg.solve(a, b)
            converged = bool(np.mean(np.sum((centre - origins) * dirs, axis=-1)) > 0)
            centre = centre if converged else None
        if centre is None:
            mean_dir = dirs.mean(0)
            mean_dir /= max(np.linalg.norm(mean_dir), 1e-12)
            spread = float(np.linalg.norm(origins - origins.mean(0), axis=-1).max())
            centre = origins.mean(0) + mean_dir * max(2.0 * spread, 1.0)
        half = factor * float(np.linalg.norm(origins - centre, axis=-1).min())
        half = half if half > 0 else 1.0
        return np.stack([centre - half, centre + half]), converged


def _check_cameras(poses: np.ndarray, box: np.ndarray, path: Path | None, converged: bool) -> None:
    """Warn of a few cameras far off the others (beyond :data:`FAR_FACTOR` × the others' typical offset
    and their typical distance to the centre of the others' box: cameras at rest with a little pose noise
    do not make a moving one "far") or of cameras that stand still: within :data:`STILL_FRACTION` of their
    distance to what they face where the axes meet (``converged``), else (that distance is a guess) at one
    point; refuse a box that is not finite."""
    origins = poses[:, :3, 3]
    if not np.isfinite(box).all():
        frame = int(np.argmax(np.abs(origins).max(axis=1)))
        raise InputError(
            f"cannot estimate a scene box: the camera positions overflow (frames[{frame}] lies at "
            f"{np.abs(origins[frame]).max():.3g}); fix its transform_matrix or give a 'scene_box' key",
            path=path,
        )
    where = "" if path is None else f"{path}: "
    shown = f"[{', '.join(f'{v:.3g}' for v in box[0])}] to [{', '.join(f'{v:.3g}' for v in box[1])}]"
    with np.errstate(over="ignore", invalid="ignore"):
        offset = np.linalg.norm(origins - np.median(origins, axis=0), axis=-1)
        spread = float(np.linalg.norm(origins - origins.mean(0), axis=-1).max())
        distance = float(np.linalg.norm(origins.mean(0) - box.mean(0)))
    moved = offset[offset > 0]
    typical = float(np.median(moved)) if len(moved) else 0.0
    far = np.flatnonzero(~(offset <= FAR_FACTOR * typical)) if typical > 0 else np.zeros(0, dtype=np.int64)
    if 0 < len(far) < len(origins) / 2:  # against the scene the others see, too
        rest = np.setdiff1d(np.arange(len(origins)), far)
        others, _ = _estimate(poses[rest], SCENE_BOX_FACTOR)
        with np.errstate(over="ignore", invalid="ignore"):
            typical = max(typical, float(np.median(np.linalg.norm(origins[rest] - others.mean(0), axis=-1))))
        far = far[~(offset[far] <= FAR_FACTOR * typical)]
    if 0 < len(far) < len(origins) / 2:
        first = int(far[np.argmax(offset[far])])
        more = f" (and {len(far) - 1} more)" if len(far) > 1 else ""
        warnings.warn(
            f"{where}the camera of frames[{first}]{more} lies {offset[first]:.3g} from the cameras' median "
            f"position, over {FAR_FACTOR:g}× their typical {typical:.3g}: a wrong transform_matrix? The "
            f"estimated scene box is {shown}; fix the pose or give a 'scene_box' key",
            stacklevel=3,
        )
    elif len(origins) > 1 and not spread > (  # (one frame: a still on purpose)
        STILL_FRACTION * distance if converged else 1e-9 * max(1.0, float(np.abs(origins).max()))
    ):  # (axes that do not meet: the distance is a guess, so only cameras at one point are said)
        warnings.warn(
            f"{where}the {len(origins)} cameras do not move (all within {spread:.3g} of their mean position, "
            f"{distance:.3g} from what they face): no parallax, so the estimated scene box {shown} is a "
            "guess; give a 'scene_box' key",
            stacklevel=3,
        )
