"""The differentiable camera pieces, kornia style: pose corrections (``so3_exp``, ``se3_exp``), rays
(``camera_directions``, ``pixel_rays``), the projection (``project_points``) and the lens
(``Distortion.distort``/``undistort``, torch): a smoke test, the refusals (InputError naming the parameter)
and a float64 ``gradcheck`` each (the exponentials' own gradchecks are in ``test_pose_refine.py``)."""

from __future__ import annotations

from collections.abc import Callable

import pytest
import torch

from helpers import refusal_test
from spikenerf.data.rays import camera_directions, pixel_rays
from spikenerf.scenes.distortion import Distortion
from spikenerf.scenes.projection import project_points
from spikenerf.scenes.trajectory import Intrinsics
from spikenerf.train.pose_refine import se3_exp, so3_exp

D = torch.float64
K = Intrinsics(width=8, height=6, fl_x=10.0, fl_y=9.0, cx=4.0, cy=3.0)
LENSES = [
    Distortion("OPENCV", k1=-0.1, k2=0.02, p1=0.001, p2=-0.002),
    Distortion("OPENCV_FISHEYE", k1=0.05, k2=-0.01),
]
PIXELS = torch.tensor([[0, 0], [7, 5], [3, 2], [4, 1]])


def _pose(seed: int) -> torch.Tensor:
    """A camera-to-world pose (4, 4) float64: a small rotation, a shift back along +z."""
    gen = torch.Generator().manual_seed(seed)
    xi = torch.cat([torch.randn(3, generator=gen, dtype=D) * 0.2, torch.tensor([0.1, -0.2, 3.0], dtype=D)])
    return se3_exp(xi)


def test_smoke() -> None:
    assert torch.equal(so3_exp(torch.zeros(2, 3)), torch.eye(3).expand(2, 3, 3))
    rot = so3_exp(torch.tensor([0.0, 0.0, torch.pi / 2]))
    assert torch.allclose(rot @ torch.tensor([1.0, 0.0, 0.0]), torch.tensor([0.0, 1.0, 0.0]), atol=1e-6)
    assert se3_exp(torch.zeros(0, 6)).shape == (0, 4, 4)
    dirs = camera_directions(K, PIXELS)
    assert dirs.shape == (4, 3) and torch.all(dirs[:, 2] == -1)
    origins, unit = pixel_rays(torch.eye(4), K, PIXELS)
    assert origins.shape == unit.shape == (4, 3) and torch.allclose(unit.norm(dim=-1), torch.ones(4))
    # a point on each ray projects back onto its pixel centre
    u, v, depth = project_points(torch.eye(4), origins + 2.0 * unit, K)
    assert torch.allclose(u, PIXELS[:, 0] + 0.5, atol=1e-5) and torch.allclose(
        v, PIXELS[:, 1] + 0.5, atol=1e-5
    )
    assert torch.all(depth > 0)
    for lens in LENSES:
        x, y = torch.tensor([0.1, -0.3], dtype=D), torch.tensor([0.2, 0.05], dtype=D)
        xu, yu = lens.undistort(*lens.distort(x, y))
        assert torch.allclose(xu, x, atol=1e-9) and torch.allclose(yu, y, atol=1e-9)


REFUSALS: list[tuple[str, Callable[[], object], str]] = [
    ("so3 width", lambda: so3_exp(torch.zeros(2, 4)), "omega"),  # (a tuple unpacking error before)
    ("so3 0-d", lambda: so3_exp(torch.tensor(1.0)), "omega"),
    ("se3 width", lambda: se3_exp(torch.zeros(2, 5)), "xi"),  # (an expand error before)
    ("directions 1-d", lambda: camera_directions(K, torch.zeros(4, dtype=torch.long)), "pixels"),
    ("directions (N, 3)", lambda: camera_directions(K, torch.zeros(4, 3, dtype=torch.long)), "pixels"),
    ("rays pose (3, 3)", lambda: pixel_rays(torch.eye(3), K, PIXELS), "c2w"),
    ("rays pose count", lambda: pixel_rays(torch.eye(4).expand(3, 4, 4), K, PIXELS), "c2w"),
    ("project points", lambda: project_points(torch.eye(4), torch.zeros(5, 2), K), "points"),
    ("project pose", lambda: project_points(torch.eye(3), torch.zeros(5, 3), K), "c2w"),
    ("lens term", lambda: Distortion("OPENCV", k1=float("nan")), "k1"),
    ("lens model", lambda: Distortion("KANNALA"), "camera_model"),  # type: ignore[arg-type]
]


test_bad_inputs_are_refused_naming_the_parameter = refusal_test(REFUSALS)


def test_gradcheck_rays_in_the_pose() -> None:
    """What pose refinement and the exposure poses differentiate: the rays of a pose, one or per pixel."""
    pose = _pose(0).requires_grad_()
    assert torch.autograd.gradcheck(lambda p: pixel_rays(p, K, PIXELS), (pose,))
    poses = torch.stack([_pose(s) for s in range(4)]).requires_grad_()
    assert torch.autograd.gradcheck(lambda p: pixel_rays(p, K, PIXELS), (poses,))
    lensed = Intrinsics(width=8, height=6, fl_x=10.0, fl_y=9.0, cx=4.0, cy=3.0, distortion=LENSES[0])
    assert torch.autograd.gradcheck(lambda p: pixel_rays(p, lensed, PIXELS), (pose,))


@pytest.mark.parametrize("lens", [None, *LENSES], ids=["pinhole", "opencv", "fisheye"])
def test_gradcheck_projection_in_points_and_pose(lens: Distortion | None) -> None:
    k = Intrinsics(width=8, height=6, fl_x=10.0, fl_y=9.0, cx=4.0, cy=3.0, distortion=lens)
    gen = torch.Generator().manual_seed(1)
    points = (torch.rand(5, 3, generator=gen, dtype=D) * 0.6 - 0.3).requires_grad_()  # in front of the camera
    pose = _pose(2).requires_grad_()
    assert torch.autograd.gradcheck(lambda x, p: project_points(p, x, k), (points, pose))


@pytest.mark.parametrize("lens", LENSES, ids=["opencv", "fisheye"])
def test_gradcheck_lens_both_ways(lens: Distortion) -> None:
    """``undistort`` is a fixed number of Newton steps: differentiable, and its Jacobian is the inverse of
    ``distort``'s once converged."""
    gen = torch.Generator().manual_seed(3)
    x, y = ((torch.rand(6, generator=gen, dtype=D) * 0.8 - 0.4).requires_grad_() for _ in range(2))
    assert torch.autograd.gradcheck(lens.distort, (x, y))
    xd, yd = (v.detach().requires_grad_() for v in lens.distort(x, y))
    assert torch.autograd.gradcheck(lens.undistort, (xd, yd))
    jac_d = torch.autograd.functional.jacobian(
        lambda a: torch.stack(lens.distort(a[0], a[1])), torch.stack([x[:1], y[:1]]).detach()
    )
    jac_u = torch.autograd.functional.jacobian(
        lambda a: torch.stack(lens.undistort(a[0], a[1])), torch.stack([xd[:1], yd[:1]]).detach()
    )
    assert torch.allclose(jac_u.reshape(2, 2) @ jac_d.reshape(2, 2), torch.eye(2, dtype=D), atol=1e-7)
