"""Test-time pose optimisation (eval --test-pose-opt): a known pose error is recovered with the field frozen,
the field is left untouched, the result is deterministic, and bad settings name their parameter."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch import Tensor

from spikenerf.core.errors import InputError
from spikenerf.data.rays import image_rays
from spikenerf.importing.alignment import rotation_angles_deg
from spikenerf.render.base import RadianceModel
from spikenerf.render.volume import RenderOutput
from spikenerf.scenes.poses import look_at
from spikenerf.scenes.trajectory import Intrinsics
from spikenerf.train import pose_fit
from spikenerf.train.pose_fit import fit_view_poses
from spikenerf.train.pose_refine import se3_exp

K = Intrinsics.from_fov(48, 32, math.radians(40.0))


DEPTHS = (1.0, 2.0, 3.5)


class Fog(torch.nn.Module):
    """A frozen-field stand-in with depth and no edges: a pixel sees the mean of a smooth 3D texture at
    three depths along its ray (1, 2 and 3.5 units), so the parallax between them tells a rotation of the
    camera from a shift, and the error surface has no occlusion boundaries."""

    def __init__(self) -> None:
        super().__init__()
        self.freq = torch.nn.Parameter(torch.tensor([3.4, 4.6, 2.2]))

    def forward(self, p: Tensor) -> Tensor:  # (..., 3) → (...)
        x, y, z = p.unbind(-1)
        s = torch.sin(self.freq[0] * x + 0.7 * z) * torch.cos(self.freq[1] * y - 0.4 * x)
        return 0.5 + 0.3 * s + 0.1 * torch.sin(self.freq[2] * z + y)


class FogModel(RadianceModel):
    """:class:`RadianceModel` interface around :class:`Fog` (one channel)."""

    def __init__(self) -> None:
        torch.nn.Module.__init__(self)
        self.field = Fog()  # type: ignore[assignment]

    @property
    def channels(self) -> int:
        return 1

    @property
    def scene_box(self) -> Tensor:
        return torch.tensor([[-5.0, -5.0, -5.0], [5.0, 5.0, 5.0]])

    @property
    def device(self) -> torch.device:
        return torch.device("cpu")

    def render_rays(self, origins, dirs, near, far, perturb=False):  # type: ignore[no-untyped-def]
        t = torch.tensor(DEPTHS)
        color = self.field(origins[:, None] + t[:, None] * dirs[:, None]).mean(1, keepdim=True)
        depth = torch.full_like(color[:, 0], t.mean().item())
        return RenderOutput(color, depth, torch.ones_like(depth), num_samples=len(t) * len(depth))


def _views(model: FogModel, poses: Tensor) -> Tensor:
    with torch.no_grad():
        out = [model.render_rays(*image_rays(p, K), None, None).color for p in poses]
    return torch.stack(out).view(len(poses), K.height, K.width, 1)


def _truth() -> Tensor:
    eyes = [(0.6, -0.4, 0.3), (-0.5, 0.2, -0.3)]
    targets = [(2.0, 1.0, 0.5), (-1.0, 2.0, 0.0)]
    return torch.as_tensor(
        np.stack([look_at(e, t) for e, t in zip(eyes, targets, strict=True)]), dtype=torch.float32
    )


def _perturbed(truth: Tensor, deg: float, shift: float) -> Tensor:
    """``truth`` moved by a known correction: a rotation of ``deg`` degrees and a shift of ``shift``."""
    g = torch.Generator().manual_seed(3)
    xi = torch.randn(len(truth), 6, generator=g)
    xi[:, :3] *= math.radians(deg) / xi[:, :3].norm(dim=1, keepdim=True)
    xi[:, 3:] *= shift / xi[:, 3:].norm(dim=1, keepdim=True)
    return truth @ se3_exp(xi)


def _rotation_error_deg(a: Tensor, b: Tensor) -> np.ndarray:
    return rotation_angles_deg(a[:, :3, :3].double().numpy(), b[:, :3, :3].double().numpy())


@pytest.mark.parametrize("max_rays", [8192, 256])  # all views in one group; one view per group
def test_a_known_pose_error_is_recovered_with_the_field_frozen(monkeypatch, max_rays: int) -> None:
    monkeypatch.setattr(pose_fit, "MAX_RAYS", max_rays)
    model, truth = FogModel(), _truth()
    images = _views(model, truth)
    start = _perturbed(truth, 3.0, 0.1)
    before = _rotation_error_deg(start, truth)
    assert np.allclose(before, 3.0, atol=1e-3)
    state = {k: v.clone() for k, v in model.state_dict().items()}
    fit = fit_view_poses(model, start, images, K, steps=300, lr=5e-3, batch=256)
    after = _rotation_error_deg(fit.poses, truth)
    shift = (fit.poses[:, :3, 3] - truth[:, :3, 3]).norm(dim=1).numpy()
    assert after.max() < 0.4, (before, after)  # 3° → well under a seventh of it (measured 0.23°, 0.18°)
    assert shift.max() < 0.04, shift  # 0.1 → under 40% (measured 0.010, 0.027)
    assert fit.loss_last < 0.01 * fit.loss_first
    assert np.allclose(fit.rotation_deg.numpy(), 3.0, atol=0.5)  # the size of the correction it applied
    for k, v in model.state_dict().items():  # the field is frozen and left trainable as it was
        assert torch.equal(v, state[k]), k
    assert all(p.requires_grad and p.grad is None for p in model.parameters())
    assert model.training


def test_the_exact_pose_stays_put_and_zero_steps_change_nothing() -> None:
    model, truth = FogModel(), _truth()
    images = _views(model, truth)
    still = fit_view_poses(model, truth, images, K, steps=0)
    assert torch.equal(still.poses, truth) and math.isnan(still.loss_first)
    fit = fit_view_poses(model, truth, images, K, steps=40, lr=3e-3, batch=256)
    assert _rotation_error_deg(fit.poses, truth).max() < 0.1


def test_same_seed_same_poses_and_another_seed_differs() -> None:
    model, truth = FogModel(), _truth()
    images, start = _views(model, truth), _perturbed(truth, 2.0, 0.05)
    a, b = (fit_view_poses(model, start, images, K, steps=10, batch=64, seed=1) for _ in range(2))
    c = fit_view_poses(model, start, images, K, steps=10, batch=64, seed=2)
    assert torch.equal(a.poses, b.poses)
    assert not torch.equal(a.poses, c.poses)


@pytest.mark.parametrize(
    ("kwargs", "param"),
    [
        ({"steps": -1}, "steps"),
        ({"steps": 2.5}, "steps"),
        ({"steps": True}, "steps"),
        ({"lr": 0.0}, "lr"),
        ({"lr": float("nan")}, "lr"),
        ({"lr": "0.1"}, "lr"),
        ({"lr": 10**400}, "lr"),  # (an int beyond a float: OverflowError before)
        ({"steps": 2**63}, "steps"),
        ({"batch": 0}, "batch"),
    ],
)
def test_bad_settings_name_their_parameter(kwargs: dict, param: str) -> None:
    model, truth = FogModel(), _truth()
    with pytest.raises(InputError) as err:
        fit_view_poses(model, truth, _views(model, truth), K, **kwargs)
    assert param in err.value.params and param in str(err.value)


def test_a_view_of_a_camera_motion_is_fitted_through_the_mean_of_its_window_renders() -> None:
    """A view showing the mean light of S poses (a TFP keyframe of a window-aware run) is fitted with one
    correction that moves all S, through the mean of their renders."""
    model, truth = FogModel(), _truth()
    turn = torch.zeros(4, 6)
    turn[:, 1] = torch.linspace(-0.08, 0.08, 4)  # a 9° pan across the window, in the camera frame
    window = truth[:, None] @ se3_exp(turn)  # (V, S, 4, 4)
    with torch.no_grad():
        images = torch.stack([_views(model, window[:, s]) for s in range(4)]).mean(0)  # (V, H, W, 1)
    g = torch.Generator().manual_seed(5)
    xi = torch.randn(len(truth), 6, generator=g)
    xi[:, :3] *= math.radians(3.0) / xi[:, :3].norm(dim=1, keepdim=True)
    xi[:, 3:] *= 0.1 / xi[:, 3:].norm(dim=1, keepdim=True)
    start = window @ se3_exp(xi)[:, None]  # one unknown correction per view, the same for its S poses
    fit = fit_view_poses(model, start, images, K, steps=300, lr=5e-3, batch=128)
    assert fit.poses.shape == window.shape
    errors = [_rotation_error_deg(fit.poses[:, s], window[:, s]) for s in range(4)]
    assert max(e.max() for e in errors) < 0.5, errors  # 3° → under a sixth of it
    assert fit.loss_last < 0.01 * fit.loss_first
    # one pose per view given as (V, 1, 4, 4) is the (V, 4, 4) fit
    a = fit_view_poses(model, start[:, 0], images, K, steps=5, batch=64)
    b = fit_view_poses(model, start[:, :1], images, K, steps=5, batch=64)
    assert b.poses.shape == (2, 1, 4, 4) and torch.equal(a.poses, b.poses[:, 0])
    for bad in (start[:1], start[:, :0]):  # too few views; no pose in a view's window
        with pytest.raises(ValueError, match="do not match"):
            fit_view_poses(model, bad, images, K, steps=1)


def test_a_wide_window_keeps_a_step_within_max_rays(monkeypatch) -> None:
    model, truth = FogModel(), _truth()
    images = _views(model, truth)
    monkeypatch.setattr(pose_fit, "MAX_RAYS", 96)
    rays: list[int] = []
    real = model.render_rays

    def counted(origins, *args, **kw):  # type: ignore[no-untyped-def]
        rays.append(len(origins))
        return real(origins, *args, **kw)

    monkeypatch.setattr(model, "render_rays", counted)
    window = truth[:, None].repeat(1, 8, 1, 1)  # S = 8: 12 pixels of one view per step
    fit = fit_view_poses(model, window, images, K, steps=3, batch=64)
    assert rays == [96] * 6 and fit.poses.shape == (2, 8, 4, 4)  # 2 groups of one view × 3 steps
