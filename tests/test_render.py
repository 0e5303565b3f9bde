"""Rays, volume rendering and the model API (tiny sizes, seconds)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from spikenerf.core.errors import InputError
from spikenerf.data.rays import image_rays, pixel_rays, ray_box_bounds
from spikenerf.fields import GridFieldConfig, MLPFieldConfig
from spikenerf.render import build_model, model_from_hparams, render_image, render_mean
from spikenerf.render.volume import composite, sample_pdf, weights_from_density
from spikenerf.scenes.poses import look_at
from spikenerf.scenes.trajectory import Intrinsics

BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
SMALL_GRID = GridFieldConfig(n_voxels_init=24**3, n_voxels_final=32**3, upsample_steps=(5,), occupancy=False)


def _logit(p: float) -> float:
    return math.log(p / (1 - p))


def grid_slab(channels: int = 3, z_range: tuple[float, float] = (-1.0, 1.0), color: float = 0.3):
    """A grid model whose density is huge for z in ``z_range`` (world), zero elsewhere, colour constant."""
    model = build_model("grid", channels, BOX, SMALL_GRID)
    f = model.field
    with torch.no_grad():
        f.density_planes.zero_()
        f.density_lines.zero_()
        coord = torch.linspace(-1, 1, f.resolution)  # BOX is [-1, 1]^3, so normalised = world
        f.density_planes[0, 0] = 1.0  # plane XY, paired with line Z
        f.density_lines[0, 0, :, 0] = 40.0 * ((coord >= z_range[0]) & (coord <= z_range[1])).float()
        f.decoder[-1].weight.zero_()
        f.decoder[-1].bias.fill_(_logit(color))
    return model


# -- rays ---------------------------------------------------------------------------------------------------
def test_centre_pixel_of_identity_pose_looks_down_minus_z() -> None:
    intr = Intrinsics.from_fov(5, 5, 0.8)
    o, d = pixel_rays(torch.eye(4), intr, torch.tensor([[2, 2]]))
    assert torch.allclose(d, torch.tensor([[0.0, 0.0, -1.0]]), atol=1e-6)
    assert torch.allclose(o, torch.zeros(1, 3))


def test_top_left_pixel_is_up_and_left_and_directions_are_unit() -> None:
    intr = Intrinsics.from_fov(8, 6, 0.9)
    o, d = image_rays(torch.eye(4), intr)
    assert d.shape == (48, 3) and o.shape == (48, 3)
    assert torch.allclose(d.norm(dim=-1), torch.ones(48), atol=1e-6)
    top_left, bottom_right = d[0], d[-1]
    assert top_left[0] < 0 and top_left[1] > 0  # row 0 has the most positive camera y
    assert bottom_right[0] > 0 and bottom_right[1] < 0
    assert torch.argmax(d[:, 1]) < 8  # first row
    # row-major: index = row * W + col
    _, d_px = pixel_rays(torch.eye(4), intr, torch.tensor([[3, 2]]))
    assert torch.allclose(d[2 * 8 + 3], d_px[0])


def test_per_pixel_poses_match_a_shared_pose_and_translate_origins() -> None:
    intr = Intrinsics.from_fov(6, 4, 0.7)
    pose = torch.as_tensor(look_at(np.array([3.0, 1.0, 2.0]), np.zeros(3)), dtype=torch.float32)
    pixels = torch.tensor([[0, 0], [5, 3], [2, 1]])
    o1, d1 = pixel_rays(pose, intr, pixels)
    o2, d2 = pixel_rays(pose.expand(3, 4, 4), intr, pixels)
    assert torch.allclose(d1, d2) and torch.allclose(o1, o2)
    assert torch.allclose(o1[0], torch.tensor([3.0, 1.0, 2.0]))
    _, centre = pixel_rays(pose, Intrinsics.from_fov(5, 5, 0.7), torch.tensor([[2, 2]]))
    expected = -torch.tensor([3.0, 1.0, 2.0]) / math.sqrt(14.0)  # the look-at target is the image centre
    assert torch.allclose(centre[0], expected, atol=1e-6)


def test_ray_box_bounds_slab_test() -> None:
    o = torch.tensor([[0.0, 0.0, 3.0], [0.0, 0.0, 0.0], [5.0, 5.0, 3.0]])
    d = torch.tensor([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    near, far = ray_box_bounds(o, d, BOX, min_near=0.05)
    assert torch.allclose(near[0], torch.tensor(2.0)) and torch.allclose(far[0], torch.tensor(4.0))
    assert near[1] == pytest.approx(0.05) and far[1] == pytest.approx(1.0)  # camera inside the box
    assert far[2] == near[2]  # a miss is an empty segment


# -- compositing --------------------------------------------------------------------------------------------
@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(0.0, 1e4, allow_nan=False), min_size=1, max_size=40),
    st.floats(1e-4, 1.0),
)
def test_weights_are_nonnegative_and_sum_to_at_most_one(sigmas: list[float], delta: float) -> None:
    sigma = torch.tensor([sigmas], dtype=torch.float32)
    w = weights_from_density(sigma, torch.full_like(sigma, delta))
    assert (w >= 0).all()
    assert w.sum() <= 1.0 + 1e-6


def test_composite_of_an_opaque_sample_gives_its_colour_and_depth() -> None:
    t = torch.linspace(0.05, 4.95, 50)[None]
    sigma = torch.where((t > 2.0) & (t < 2.5), 1e4, 0.0)
    w = weights_from_density(sigma, torch.full_like(t, 0.1))
    colors = torch.full((1, 50, 3), 0.2)
    color, depth, opacity = composite(w, colors, t)
    assert torch.allclose(color, torch.full((1, 3), 0.2), atol=1e-5)
    assert opacity.item() == pytest.approx(1.0, abs=1e-6)
    assert depth.item() == pytest.approx(2.05, abs=1e-4)


def test_sample_pdf_follows_the_weights() -> None:
    edges = torch.linspace(0.0, 1.0, 11)[None].repeat(2, 1)
    weights = torch.zeros(2, 10)
    weights[:, 7] = 1.0
    for perturb in (False, True):
        t = sample_pdf(edges, weights, 64, perturb)
        assert t.shape == (2, 64)
        assert ((t >= 0.7 - 1e-6) & (t <= 0.8 + 1e-6)).float().mean() > 0.9


# -- models -------------------------------------------------------------------------------------------------
def _down_ray(n: int = 1) -> tuple[torch.Tensor, ...]:
    o = torch.tensor([[0.1, -0.2, 3.0]]).repeat(n, 1)
    d = torch.tensor([[0.0, 0.0, -1.0]]).repeat(n, 1)
    return (o, d, *ray_box_bounds(o, d, BOX))


@pytest.mark.parametrize("channels", [1, 3])
def test_empty_grid_renders_white(channels: int) -> None:
    model = grid_slab(channels, z_range=(5.0, 6.0))  # the slab is outside the box: empty
    # softplus leaves a haze of σ = 25·softplus(−10) ≈ 1e-3 per unit before the occupancy grid exists
    out = model.render_rays(*_down_ray(4), perturb=True)
    assert out.color.shape == (4, channels)
    assert torch.allclose(out.color, torch.ones_like(out.color), atol=5e-3)
    model.field.update_occupancy()  # nothing above the threshold: the update is refused, not an empty grid
    assert model.field.occupancy.occupied_fraction() == 1.0
    out = model.render_rays(*_down_ray(4), perturb=True)
    assert torch.allclose(out.color, torch.ones_like(out.color), atol=5e-3) and out.num_samples > 0


def test_empty_mlp_renders_exactly_white() -> None:
    model = build_model("mlp", 3, BOX, MLPFieldConfig.tiny())
    with torch.no_grad():
        for net in (model.field.coarse, model.field.fine):
            net.sigma.weight.zero_()
            net.sigma.bias.fill_(-1.0)  # relu → zero density
    out = model.render_rays(*_down_ray(3), perturb=True)
    assert torch.equal(out.color, torch.ones(3, 3)) and torch.equal(out.opacity, torch.zeros(3))
    assert out.coarse_color is not None and out.coarse_color.shape == (3, 3)


@pytest.mark.parametrize("kind", ["grid", "mlp"])
def test_opaque_field_renders_its_colour(kind: str) -> None:
    if kind == "grid":
        model = grid_slab(3, color=0.3)
    else:
        model = build_model("mlp", 3, BOX, MLPFieldConfig.tiny())
        with torch.no_grad():
            for net in (model.field.coarse, model.field.fine):
                net.sigma.weight.zero_()
                net.sigma.bias.fill_(500.0)
                net.out.weight.zero_()
                net.out.bias.fill_(_logit(0.3))
    out = model.render_rays(*_down_ray(2), perturb=False)
    assert torch.allclose(out.color, torch.full((2, 3), 0.3), atol=1e-4)
    assert torch.allclose(out.opacity, torch.ones(2), atol=1e-4)
    assert torch.allclose(out.depth, torch.full((2,), 2.0), atol=0.1)  # enters the box at z = 1


def test_depth_of_a_known_slab() -> None:
    model = grid_slab(1, z_range=(-0.25, 0.25))
    out = model.render_rays(*_down_ray(1), perturb=False)
    step = model.field.step_size
    assert out.opacity.item() == pytest.approx(1.0, abs=1e-4)
    # the slab's top face is at z = 0.25 → distance 2.75 from z = 3 (within one marching step)
    assert abs(out.depth.item() - 2.75) < step


def test_render_image_shapes_and_hparams_round_trip() -> None:
    model = build_model("grid", 1, BOX, SMALL_GRID)
    intr = Intrinsics.from_fov(7, 5, 0.8)
    pose = look_at(np.array([0.0, -3.0, 1.0]), np.zeros(3))
    img = render_image(model, pose, intr, chunk=11)
    assert img.color.shape == (5, 7, 1) and img.depth.shape == (5, 7) and img.opacity.shape == (5, 7)
    clone = model_from_hparams(model.hparams(), model.state_dict())
    assert torch.equal(render_image(clone, pose, intr).color, img.color)
    other = look_at(np.array([3.0, 0.0, 1.0]), np.zeros(3))
    assert torch.equal(render_mean(model, [pose], intr), img.color)  # one pose: its render
    both = (img.color + render_image(model, other, intr).color) / 2
    assert torch.allclose(render_mean(model, np.stack([pose, other]), intr), both)


def test_build_model_rejects_bad_input() -> None:
    with pytest.raises(InputError):
        build_model("voxels", 3, BOX)
    with pytest.raises(InputError):
        build_model("grid", 2, BOX)
    with pytest.raises(InputError):
        build_model("grid", 3, BOX, {"no_such_key": 1})


def test_rays_and_projections_stay_float32_under_bf16_autocast() -> None:
    from spikenerf.scenes.projection import project_points

    k = Intrinsics.from_fov(400, 400, 0.87)
    gen = torch.Generator().manual_seed(0)
    poses = torch.as_tensor(np.stack([look_at([4.0, 0.3 * i, 1.5], [0.0, 0.0, 0.0]) for i in range(64)]),
                            dtype=torch.float32)  # fmt: skip
    pixels = torch.randint(0, 400, (64, 2), generator=gen)
    points = torch.rand(64, 3, generator=gen) - 0.5
    exact = (*pixel_rays(poses, k, pixels), *project_points(poses, points, k))
    with torch.autocast("cpu", torch.bfloat16):  # what train --amp bf16 wraps the step in
        cast = (*pixel_rays(poses, k, pixels), *project_points(poses, points, k))
    for a, b in zip(exact, cast, strict=True):
        assert b.dtype == torch.float32 and torch.equal(a, b)


class _Numpy2Array(np.ndarray):
    """An array with numpy 2's ``device`` attribute (the string "cpu"), under numpy 1 too."""

    device = "cpu"


def test_projection_of_numpy_arrays_with_a_device_attribute_stays_numpy() -> None:
    """numpy ≥ 2 arrays have ``.device``: projecting them must not take the torch branch (it did, and
    spike-integral's set-up failed under numpy 2 with "'str' object has no attribute 'type'")."""
    from spikenerf.scenes.projection import project_points

    k = Intrinsics.from_fov(32, 32, 0.87)
    poses = np.stack([look_at([4.0, 0.1 * i, 1.5], [0.0, 0.0, 0.0]) for i in range(8)])
    points = (np.random.default_rng(0).random((8, 3)) - 0.5).view(_Numpy2Array)
    u, v, depth = project_points(poses.view(_Numpy2Array), points, k)
    plain = project_points(poses, points.view(np.ndarray), k)
    for a, b in zip((u, v, depth), plain, strict=True):
        assert isinstance(a, np.ndarray) and np.array_equal(a, b)


def test_depth_of_a_half_opaque_ray_is_its_weighted_mean_distance() -> None:
    """Depth is the weight-normalised mean distance, also where the ray is not opaque (spike-integral places
    its track points there)."""
    from spikenerf.render.volume import packed_composite

    weights, t = torch.tensor([[0.25, 0.25]]), torch.tensor([[1.0, 3.0]])
    color, depth, opacity = composite(weights, torch.ones(1, 2, 1), t, background=0.0)
    assert depth.item() == pytest.approx(2.0) and opacity.item() == pytest.approx(0.5)
    assert color.item() == pytest.approx(0.5)
    packed = packed_composite(weights[0], torch.tensor([0, 0]), 1, t[0], torch.ones(2, 1), None, 0.0)
    assert [x.item() for x in packed] == pytest.approx([0.5, 2.0, 0.5])


def test_sample_pdf_inverts_the_piecewise_constant_cdf() -> None:
    edges = torch.tensor([[0.0, 1.0, 2.0]])
    t = sample_pdf(edges, torch.tensor([[1.0, 3.0]]), 5, perturb=False)  # a quarter of the mass in bin 0
    assert t[0].tolist() == pytest.approx([0.0, 1.0, 4 / 3, 5 / 3, 2.0], abs=1e-4)
    uniform = sample_pdf(torch.linspace(0.5, 4.5, 5)[None], torch.ones(1, 4), 9, perturb=False)
    assert uniform[0].tolist() == pytest.approx(torch.linspace(0.5, 4.5, 9).tolist(), abs=1e-5)


def test_the_last_sample_reaches_the_far_bound() -> None:
    from spikenerf.render.volume import deltas_from_samples

    assert deltas_from_samples(torch.tensor([[0.5, 1.5]]), torch.tensor([2.5])).tolist() == [[1.0, 1.0]]
    assert deltas_from_samples(torch.tensor([[0.5, 3.0]]), torch.tensor([2.5])).tolist() == [[2.5, 0.0]]
