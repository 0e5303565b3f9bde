"""What a scene source gives the ``simulate`` pipeline: per-step radiance frames, poses and test views."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Protocol

import numpy as np

from spikenerf.scenes.trajectory import Intrinsics, Trajectory


class FrameSource(Protocol):
    """A source of linear radiance frames along a trajectory (Blender, analytic scene, image sequence).

    Attributes:
        name: scene name recorded in ``config.yaml``.
        intrinsics: the camera at the output resolution.
        trajectory: per-step poses, times and step indices of the training path.
        scene_box: (2, 3) float axis-aligned bounds (min, max) of the content, in world units.
    """

    name: str
    intrinsics: Intrinsics
    trajectory: Trajectory
    scene_box: np.ndarray

    def frames(self, steps: Sequence[int]) -> Iterator[np.ndarray]:
        """Yield the linear radiance frame (H, W, 3) float32 of each trajectory step, in order.

        Values are linear, 1.0 = white diffuse under the default light; the background is white.
        """
        ...

    def test_views(self) -> tuple[np.ndarray, np.ndarray]:
        """Held-out views: poses (N, 4, 4) and linear frames (N, H, W, 3) float32 (N may be 0)."""
        ...
