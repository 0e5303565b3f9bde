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
from spikenerf.render.base import RadianceModel
from spikenerf.render.volume import RenderOutput
from spikenerf.scenes.trajectory import Intrinsics, look_at
from spikenerf.train.pose_fit import fit_view_poses
from spikenerf.train.pose_refine import se3_exp

K = Intrinsics.from_fov(48, 32, math.radians(40.0))


EYES = ((0.6, -0.4, 0.3), (-0.5, 0.2, -0.3))
TARGETS = ((2.0, 1.0, 0.5), (-1.0, 2.0, 0.0))


class Scene(torch.nn.Module):
    """A frozen-field stand-in with depth: a textured sphere of radius 3 around the origin seen from inside,
    and in front of each camera a textured ball of radius 0.3 at 1 unit (parallax tells a rotation of
    the camera from a shift). The colour is smooth in the 3D point seen."""

    def __init__(self) -> None:
        super().__init__()
        self.freq = torch.nn.Parameter(torch.tensor([1.7, 2.3, 1.1]))
        eye, target = torch.tensor(EYES), torch.tensor(TARGETS)
        ahead = torch.nn.functional.normalize(target - eye, dim=-1)
        self.register_buffer("balls", eye + 1.0 * ahead)

    def texture(self, p: Tensor) -> Tensor:  # (N, 3) → (N, 1)
        s = torch.sin(self.freq[0] * 2 * p[:, 0] + 1.5 * p[:, 2]) * torch.cos(self.freq[1] * 2 * p[:, 1])
        return (0.5 + 0.4 * s + 0.05 * torch.sin(self.freq[2] * 2 * p[:, 2]))[:, None]

    def forward(self, o: Tensor, d: Tensor) -> Tensor:  # rays (N, 3), unit (N, 3) → depth (N,)
        b, c = (o * d).sum(-1), (o * o).sum(-1) - 9.0
        t = -b + torch.sqrt((b * b - c).clamp_min(1e-9))  # the far wall (the camera is inside it)
        for centre in self.balls:
            oc = o - centre
            b, c = (oc * d).sum(-1), (oc * oc).sum(-1) - 0.09
            disc = b * b - c
            near = -b - torch.sqrt(disc.clamp_min(1e-9))
            t = torch.where((disc > 0) & (near > 0) & (near < t), near, t)
        return t


class SceneModel(RadianceModel):
    """:class:`RadianceModel` interface around :class:`Scene` (one channel, opaque)."""

    def __init__(self) -> None:
        torch.nn.Module.__init__(self)
        self.field = Scene()  # type: ignore[assignment]

    @property
    def channels(self) -> int:
        return 1

    @property
    def scene_box(self) -> Tensor:
        return torch.tensor([[-3.0, -3.0, -3.0], [3.0, 3.0, 3.0]])

    @property
    def device(self) -> torch.device:
        return torch.device("cpu")

    def render_rays(self, origins, dirs, near, far, perturb=False):  # type: ignore[no-untyped-def]
        t = self.field(origins, dirs)
        color = self.field.texture(origins + t[:, None] * dirs)
        return RenderOutput(color, t, torch.ones_like(t), num_samples=len(t))


def _views(model: SceneModel, poses: Tensor) -> Tensor:
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
    rel = a[:, :3, :3].transpose(1, 2).double() @ b[:, :3, :3].double()
    cos = ((rel.diagonal(dim1=1, dim2=2).sum(-1) - 1) / 2).clamp(-1, 1)
    return np.degrees(torch.arccos(cos).numpy())


def test_a_known_pose_error_is_recovered_with_the_field_frozen() -> None:
    model, truth = SceneModel(), _truth()
    images = _views(model, truth)
    start = _perturbed(truth, 3.0, 0.1)
    before = _rotation_error_deg(start, truth)
    assert np.allclose(before, 3.0, atol=1e-3)
    state = {k: v.clone() for k, v in model.state_dict().items()}
    fit = fit_view_poses(model, start, images, K, steps=150, lr=3e-3, batch=256)
    after = _rotation_error_deg(fit.poses, truth)
    shift = (fit.poses[:, :3, 3] - truth[:, :3, 3]).norm(dim=1).numpy()
    assert after.max() < 0.3, (before, after)  # 3° → well under a tenth of it
    assert shift.max() < 0.03, shift  # 0.1 → under a third
    assert fit.loss_last < 0.1 * fit.loss_first
    assert np.allclose(fit.rotation_deg.numpy(), 3.0, atol=0.5)  # the size of the correction it applied
    for k, v in model.state_dict().items():  # the field is frozen and left trainable as it was
        assert torch.equal(v, state[k]), k
    assert all(p.requires_grad for p in model.parameters())
    assert model.training


def test_the_exact_pose_stays_put_and_zero_steps_change_nothing() -> None:
    model, truth = SceneModel(), _truth()
    images = _views(model, truth)
    still = fit_view_poses(model, truth, images, K, steps=0)
    assert torch.equal(still.poses, truth) and math.isnan(still.loss_first)
    fit = fit_view_poses(model, truth, images, K, steps=40, lr=3e-3, batch=256)
    assert _rotation_error_deg(fit.poses, truth).max() < 0.1


def test_same_seed_same_poses_and_another_seed_differs() -> None:
    model, truth = SceneModel(), _truth()
    images, start = _views(model, truth), _perturbed(truth, 2.0, 0.05)
    a, b = (fit_view_poses(model, start, images, K, steps=10, batch=64, seed=1) for _ in range(2))
    c = fit_view_poses(model, start, images, K, steps=10, batch=64, seed=2)
    assert torch.equal(a.poses, b.poses)
    assert not torch.equal(a.poses, c.poses)


@pytest.mark.parametrize(
    ("kwargs", "param"),
    [
        ({"steps": -1}, "test_pose_steps"),
        ({"steps": 2.5}, "test_pose_steps"),
        ({"lr": 0.0}, "test_pose_lr"),
        ({"lr": float("nan")}, "test_pose_lr"),
        ({"batch": 0}, "test_pose_batch"),
    ],
)
def test_bad_settings_name_their_parameter(kwargs: dict, param: str) -> None:
    model, truth = SceneModel(), _truth()
    with pytest.raises(InputError) as err:
        fit_view_poses(model, truth, _views(model, truth), K, **kwargs)
    assert param in err.value.params and param in str(err.value)
