"""The trajectories ``spikenerf render`` (and ``export``) follow: ``test`` (the held-out views), the
generated paths (``orbit``, ``spiral``, ``interpolate``: :data:`GENERATORS`) or a trajectory file (a
transforms.json or a nerfstudio camera_path.json), each resolved to a :class:`RenderPath` (poses, camera, ray
bounds) by :func:`resolve_trajectory`, at the poses the run refined (:func:`refined_poses`)."""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from spikenerf.core.errors import InputError
from spikenerf.data.camera_path import read_camera_path
from spikenerf.data.dataset import SpikeDataset, near_far
from spikenerf.scenes.render_paths import (
    FORWARD_FACING,
    INTERPOLATE_KEYS,
    RENDER_PATHS,
    key_path,
    path_keys,
    spiral_path,
    view_agreement,
)
from spikenerf.scenes.trajectory import Intrinsics, orbit
from spikenerf.train.pose_refine import refined_dataset, refined_views

TRAJECTORIES = RENDER_PATHS
DEFAULT_ORBIT_FRAMES = 120


def refined_poses(ckpt: dict, config: Any, dataset: SpikeDataset) -> SpikeDataset:
    """``dataset`` with the test views and the path at the poses the run (its checkpoint ``ckpt``) refined
    (``--refine-poses``), where ``eval`` scores them and the orbit is centred; unchanged for a run that did
    not refine poses."""
    if not ckpt.get("poses"):
        return dataset
    test = refined_views(ckpt, config, dataset, dataset.test)
    return dataclasses.replace(refined_dataset(ckpt, config, dataset), test=test)


def orbit_poses(dataset: SpikeDataset, count: int) -> np.ndarray:
    """(count, 4, 4) poses of one closed orbit around the scene box centre at the training path's mean
    distance and elevation (no repeated end pose)."""
    center = dataset.scene_box.mean(0)
    offsets = dataset.trajectory.poses[:, :3, 3] - center
    radius = float(np.linalg.norm(offsets, axis=-1).mean())
    elevation = float(
        np.degrees(np.arcsin(np.clip(offsets[:, 2] / np.linalg.norm(offsets, axis=-1), -1, 1))).mean()
    )
    start = float(np.degrees(np.arctan2(offsets[0, 1], offsets[0, 0])))
    traj = orbit(
        radius, elevation, duration=float(count), fps=1.0, center=tuple(center), start_azimuth_deg=start
    )
    return traj.poses


def spiral_poses(dataset: SpikeDataset, count: int) -> np.ndarray:
    """(count, 4, 4) poses of a spiral around the mean training camera, looking at a focus depth from the
    dataset's near/far (:func:`spikenerf.scenes.render_paths.spiral_path`). A warning where the training
    cameras look around an object (:func:`~spikenerf.scenes.render_paths.view_agreement` below
    ``FORWARD_FACING``): the spiral is for forward-facing captures."""
    if (agree := view_agreement(dataset.trajectory.poses)) < FORWARD_FACING:
        warnings.warn(
            f"trajectory spiral: the training cameras look around the scene (their mean view direction has "
            f"length {agree:.2f}, under {FORWARD_FACING:.2f} for a forward-facing capture), so the spiral "
            "circles among what they film; orbit or interpolate follows such a path",
            stacklevel=2,
        )
    return spiral_path(dataset.trajectory.poses, dataset.near, dataset.far, count)


def interpolated_poses(dataset: SpikeDataset, count: int) -> np.ndarray:
    """(count, 4, 4) poses of a smooth path through :data:`INTERPOLATE_KEYS` training poses spread over the
    training path in time order (slerped rotations, Catmull-Rom positions:
    :func:`spikenerf.scenes.render_paths.key_path`)."""
    return key_path(path_keys(dataset.trajectory.poses, INTERPOLATE_KEYS), count)


#: the generated paths' poses, (dataset, count) → (count, 4, 4)
GENERATORS: dict[str, Callable[[SpikeDataset, int], np.ndarray]] = {
    "orbit": orbit_poses,
    "spiral": spiral_poses,
    "interpolate": interpolated_poses,
}
#: what the log says of a built-in path
ALONG = {
    "test": "at the test poses",
    "orbit": "along the orbit",
    "spiral": "along a spiral around the mean training camera",
    "interpolate": "along the training path",
}


@dataclass
class RenderPath:
    """What a render follows: ``name`` (the video's stem), ``poses`` (N, 4, 4) c2w, the camera and the
    ray bounds; ``file``: the trajectory file's name, None for the built-in paths (a file named
    ``test.json`` is no test trajectory); ``kind``: the built-in path's name, or the file's format
    (``transforms`` or ``camera_path``, nerfstudio's)."""

    name: str
    poses: np.ndarray
    intrinsics: Intrinsics
    near: float
    far: float
    file: str | None = None
    kind: str = ""


def resolve_trajectory(spec: str, dataset: SpikeDataset, count: int) -> RenderPath:
    """The :class:`RenderPath` of ``test``, a generated path (``orbit``, ``spiral``, ``interpolate``:
    ``count`` poses) or a trajectory file (a transforms.json or a nerfstudio camera_path.json); the built-in
    paths use the dataset's camera and bounds, a file its own camera where it gives one (``w``/``h`` default
    to the dataset's size) and its ``near``/``far``, else bounds around the scene box from its poses."""
    k, near, far = dataset.intrinsics, dataset.near, dataset.far
    if spec == "test":
        if len(dataset.test) == 0:
            raise InputError(
                "the dataset has no test views (transforms_test.json): give trajectory orbit or a poses file",
                path=dataset.root,
                param="trajectory",
            )
        return RenderPath("test", np.asarray(dataset.test.poses, np.float64), k, near, far, kind="test")
    if spec in GENERATORS:
        return RenderPath(spec, GENERATORS[spec](dataset, count), k, near, far, kind=spec)
    path = Path(spec)
    if not path.is_file():
        what = "no such file" if not path.exists() else "not a file"
        raise InputError(
            f"trajectory: expected {', '.join(TRAJECTORIES)}, a transforms.json or a nerfstudio "
            f"camera_path.json file, found {spec!r} ({what})",
            param="trajectory",
        )
    found = read_camera_path(path, (k.width, k.height))
    near, far = found.bounds or near_far(found.poses, dataset.scene_box)
    return RenderPath(path.stem, found.poses, found.intrinsics or k, near, far, path.name, found.kind)
