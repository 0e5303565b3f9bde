"""Lens distortion (scenes/distortion.py): the models, their inverse, the rays and projections through them,
a pinhole left bit for bit as it was, the lens in a dataset's transforms.json, and the refusals."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from helpers import run_cli
from spikenerf.capture.options import SimulateOptions
from spikenerf.capture.simulate import simulate_dataset
from spikenerf.core.errors import InputError
from spikenerf.data.dataset import load_dataset
from spikenerf.data.rays import camera_directions, image_pixels, image_rays
from spikenerf.data.writer import DatasetWriter
from spikenerf.scenes import analytic, transforms
from spikenerf.scenes.distortion import NEWTON_STEPS, Distortion, checked, colmap_camera
from spikenerf.scenes.poses import look_at
from spikenerf.scenes.projection import project_points
from spikenerf.scenes.trajectory import Intrinsics, orbit

W, H = 40, 30
#: realistic lenses: a barrel lens with tangential terms, a pincushion one, one with every radial term,
#: and two fisheyes
LENSES = [
    Distortion("OPENCV", k1=-0.28, k2=0.07, p1=1e-3, p2=-2e-3),
    Distortion("OPENCV", k1=0.15, k2=0.02),
    Distortion("OPENCV", k1=-0.2, k2=0.04, k3=-0.004, k4=2e-4, p1=-5e-4, p2=5e-4),
    Distortion("OPENCV_FISHEYE", k1=0.04, k2=-0.01, k3=2e-3, k4=-1e-4),
    Distortion("OPENCV_FISHEYE"),
]


def _camera(lens: Distortion | None, focal: float = 24.0) -> Intrinsics:
    return Intrinsics(W, H, focal, focal * 1.05, W / 2 + 0.7, H / 2 - 0.4, lens)


def _distorted_grid(k: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Normalised distorted coordinates of every pixel centre and the image's edges (float64)."""
    u, v = np.meshgrid(np.linspace(0, W, 81), np.linspace(0, H, 61))
    return (u - k.cx) / k.fl_x, (v - k.cy) / k.fl_y


@pytest.mark.parametrize("lens", LENSES, ids=lambda lens: lens.describe())
def test_undistort_inverts_distort_over_the_image(lens: Distortion) -> None:
    k = _camera(lens)
    xd, yd = _distorted_grid(k)
    x, y = lens.undistort(xd, yd)  # numpy, float64
    bx, by = lens.distort(x, y)
    assert np.hypot(bx - xd, by - yd).max() < 1e-9
    for dtype, tol in ((torch.float64, 1e-9), (torch.float32, 1e-6)):  # torch, as the rays use it
        tx, ty = lens.undistort(torch.tensor(xd, dtype=dtype), torch.tensor(yd, dtype=dtype))
        assert tx.dtype == dtype
        back = lens.distort(tx.double(), ty.double())
        err = torch.hypot(back[0] - torch.tensor(xd), back[1] - torch.tensor(yd)).max()
        assert float(err) < tol, (dtype, float(err))
    # and the other way round: undistort ∘ distort of pinhole points inside the image
    px, py = lens.undistort(xd[::4, ::4], yd[::4, ::4])
    ux, uy = lens.undistort(*lens.distort(px, py))
    assert np.hypot(ux - px, uy - py).max() < 1e-9


def test_known_values_of_each_model() -> None:
    """Hand-computed: radial k1 only, the tangential terms, and the equidistant fisheye."""
    xd, yd = Distortion(k1=0.1).distort(np.array([0.5, 0.0, 0.3]), np.array([0.0, -0.4, 0.4]))
    # r² = 0.25, 0.16, 0.25: the radius scales by 1.025, 1.016, 1.025
    np.testing.assert_allclose(xd, [0.5125, 0.0, 0.3075], rtol=0, atol=1e-15)
    np.testing.assert_allclose(yd, [0.0, -0.4064, 0.41], rtol=0, atol=1e-15)
    xd, yd = Distortion(p1=0.01, p2=0.02).distort(np.array([0.2]), np.array([0.1]))
    # x + 2·p1·x·y + p2·(r² + 2x²) = 0.2 + 0.0004 + 0.02·0.13; y + p1·(r² + 2y²) + 2·p2·x·y
    np.testing.assert_allclose([xd[0], yd[0]], [0.203, 0.1015], rtol=0, atol=1e-15)
    xd, yd = Distortion("OPENCV_FISHEYE").distort(np.array([1.0, 0.0]), np.array([0.0, math.sqrt(3)]))
    np.testing.assert_allclose([xd[0], yd[1]], [math.pi / 4, math.pi / 3], rtol=0, atol=1e-15)
    xd, _ = Distortion("OPENCV_FISHEYE", k1=0.1).distort(np.array([1.0]), np.array([0.0]))
    theta = math.pi / 4
    assert xd[0] == pytest.approx(theta * (1 + 0.1 * theta**2), abs=1e-15)
    # the inverse of a k1-only lens: x·(1 + k1·x²) = 0.5125 at x = 0.5
    x, y = Distortion(k1=0.1).undistort(np.array([0.5125]), np.array([0.0]))
    assert x[0] == pytest.approx(0.5, abs=1e-12) and y[0] == 0


@pytest.mark.parametrize("lens", LENSES, ids=lambda lens: lens.describe())
def test_rays_of_a_distorted_camera_project_back_to_their_pixel_centres(lens: Distortion) -> None:
    k = _camera(lens)
    c2w = look_at(np.array([0.3, -2.5, 1.1]), np.zeros(3))
    for dtype, tol in ((torch.float64, 1e-6), (torch.float32, 2e-3)):
        origins, dirs = image_rays(torch.tensor(c2w, dtype=dtype), k)
        points = origins + dirs * torch.linspace(0.5, 4.0, len(dirs), dtype=dtype)[:, None]
        u, v, depth = project_points(torch.tensor(c2w, dtype=dtype), points, k)
        pixels = image_pixels(k).to(dtype) + 0.5
        assert bool((depth > 0).all())
        assert float((u - pixels[:, 0]).abs().max()) < tol and float((v - pixels[:, 1]).abs().max()) < tol
    # numpy projection, and a pinhole projection of the same points misses by pixels (the lens matters)
    pts = (origins + 2 * dirs).double().numpy()
    u, v, _ = project_points(c2w, pts, k)
    np.testing.assert_allclose(np.stack([u, v], -1), (image_pixels(k) + 0.5).numpy(), atol=1e-3)
    u0, v0, _ = project_points(c2w, pts, replace(k, distortion=None))
    assert np.hypot(u0 - u, v0 - v).max() > 0.5


def test_zero_terms_are_the_pinhole_bit_for_bit() -> None:
    pinhole = _camera(None)
    assert _camera(Distortion()).distortion is None  # OPENCV with zero terms is no lens at all
    assert _camera(Distortion()) == pinhole and Intrinsics(W, H, 24.0, 25.2, 20.7, 14.6).distortion is None
    pixels = image_pixels(pinhole)
    for dtype in (torch.float32, torch.float64):
        px = pixels.to(dtype)  # the formula the rays had before lenses (data/rays.py)
        u = (px[:, 0] + 0.5 - pinhole.cx) / pinhole.fl_x
        v = -(px[:, 1] + 0.5 - pinhole.cy) / pinhole.fl_y
        before = torch.stack([u, v, -torch.ones_like(u)], dim=-1)
        assert torch.equal(camera_directions(_camera(Distortion()), pixels, dtype), before)
    s = 2  # the analytic scenes' own rays (simulate), as they were
    uu, vv = np.meshgrid((np.arange(W * s) + 0.5) / s, (np.arange(H * s) + 0.5) / s)
    dirs = np.stack(
        [(uu - pinhole.cx) / pinhole.fl_x, -(vv - pinhole.cy) / pinhole.fl_y, -np.ones_like(uu)], -1
    )
    assert np.array_equal(
        analytic.camera_directions(pinhole, s), dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
    )
    # a pinhole's projection as it was
    c2w, pts = (
        look_at(np.array([0.0, -3.0, 1.0]), np.zeros(3)),
        np.random.default_rng(0).uniform(-1, 1, (50, 3)),
    )
    # camera coordinates by the same batched product as project_points: a plain (N, 3) @ (3, 3) may take
    # another BLAS kernel, whose fused multiply-adds round differently on some CPUs
    rel = ((pts - c2w[:3, 3])[:, None, :] @ c2w[:3, :3])[:, 0, :]
    u, v, _ = project_points(c2w, pts, pinhole)
    assert np.array_equal(u, pinhole.fl_x * rel[:, 0] / -rel[:, 2] + pinhole.cx)
    assert np.array_equal(v, -pinhole.fl_y * rel[:, 1] / -rel[:, 2] + pinhole.cy)


def test_the_lens_survives_scaling_and_beyond_its_fold_points_stay_outside() -> None:
    lens = Distortion(k1=-0.25, k2=0.02)  # folds back at r ≈ 1.3 (radius 0.83), beyond the corners (0.63)
    k = _camera(lens, focal=40.0)
    assert k.scaled(80, 60).distortion == lens and k.scaled(80, 60).fl_x == 2 * k.fl_x
    top, reach = lens.limit
    assert 1.0 < top < 2.0 and reach < top
    r = np.linspace(0, 20, 4001)  # along the x axis, past the fold: the distorted radius never falls back
    xd, _ = lens.distort(r, np.zeros_like(r))
    assert (np.diff(xd) > 0).all()
    corner = math.hypot(
        *(max(abs(0 - c), abs(n - c)) / f for n, c, f in ((W, k.cx, k.fl_x), (H, k.cy, k.fl_y)))
    )
    assert xd[r > top].min() > corner  # a point the polynomial would fold into the image lands outside


@pytest.mark.parametrize(
    ("make", "param", "words"),
    [
        (
            lambda: Distortion("FULL_OPENCV"),
            "camera_model",
            "camera_model must be one of OPENCV, OPENCV_FISHEYE",
        ),
        (lambda: Distortion(k1=math.nan), "k1", "k1 must be a finite number"),
        (lambda: Distortion(k3="0.1"), "k3", "k3 must be a finite number"),
        (lambda: Distortion("OPENCV_FISHEYE", p2=0.01), "p2", "p2 must be 0 for OPENCV_FISHEYE"),
        (lambda: _camera(Distortion(k1=-0.6)), "distortion", "stops growing at"),  # folds inside the image
        (lambda: _camera(Distortion("OPENCV_FISHEYE"), focal=8.0), "distortion", "beyond 89° off the axis"),
        (lambda: _camera(Distortion(p1=0.4, p2=-0.4)), "distortion", "not invertible"),
        (lambda: Intrinsics(W, H, 24.0, 24.0, 20, 15, distortion=0.1), "distortion", "must be a Distortion"),
    ],
)
def test_refusals_name_the_parameter(make, param: str, words: str) -> None:
    with pytest.raises(InputError, match=words) as err:
        make()
    assert err.value.params == (param,)


def test_newton_steps_suffice_for_a_strong_barrel_lens() -> None:
    """A lens close to folding at the image corners still converges in the fixed step count."""
    lens = Distortion(k1=-0.4, k2=0.05)
    k = Intrinsics(W, H, 40.0, 40.0, W / 2, H / 2, lens)  # corners at 0.625, the fold at 0.651
    xd, yd = _distorted_grid(k)
    x, y = lens.undistort(xd, yd, NEWTON_STEPS)
    assert np.hypot(*(a - b for a, b in zip(lens.distort(x, y), (xd, yd), strict=True))).max() < 1e-9


@pytest.mark.parametrize(
    ("model", "params"),
    [
        ("OPENCV", [24.0, 25.2, 20.7, 14.6, 0.0, 0.0, 0.0, 0.0]),
        ("FULL_OPENCV", [24.0, 25.2, 20.7, 14.6, *[0.0] * 8]),
        ("RADIAL", [24.0, 20.7, 14.6, 0.0, 0.0]),
        ("SIMPLE_RADIAL", [24.0, 20.7, 14.6, 0.0]),
    ],
)
def test_a_colmap_lens_with_zero_terms_is_the_pinhole_bit_for_bit(model: str, params: list[float]) -> None:
    """An OPENCV-family calibration whose terms are all zero is no lens at all: colmap_camera gives None,
    and the camera's rays are bit for bit the pinhole's."""
    focal, lens = colmap_camera(model, params)
    assert lens is None
    pinhole = Intrinsics(W, H, *focal)
    same = Intrinsics(
        W, H, *focal, Distortion("OPENCV", **dict.fromkeys(("k1", "k2", "k3", "k4", "p1", "p2"), 0))
    )
    assert same == pinhole and same.distortion is None
    pixels = image_pixels(pinhole)
    for dtype in (torch.float32, torch.float64):
        assert torch.equal(camera_directions(same, pixels, dtype), camera_directions(pinhole, pixels, dtype))


@pytest.mark.parametrize(
    ("model", "params"),
    [
        ("OPENCV_FISHEYE", [24.0, 25.2, 20.7, 14.6, 0.0, 0.0, 0.0, 0.0]),
        ("RADIAL_FISHEYE", [24.0, 20.7, 14.6, 0.0, 0.0]),
        ("SIMPLE_RADIAL_FISHEYE", [24.0, 20.7, 14.6, 0.0]),
        ("FISHEYE", [24.0, 25.2, 20.7, 14.6]),
        ("SIMPLE_FISHEYE", [24.0, 20.7, 14.6]),
    ],
)
def test_a_fisheye_with_zero_terms_is_equidistant_never_a_pinhole(
    model: str, params: list[float], tmp_path: Path
) -> None:
    """Zero fisheye terms still bend the rays (r_d = θ = atan r): COLMAP, checked(), the rays, the
    transforms.json round trip and the projection all keep the lens."""
    focal, lens = colmap_camera(model, params)
    assert lens == Distortion("OPENCV_FISHEYE") and not lens.is_pinhole
    k = Intrinsics(W, H, *focal, lens)
    assert checked(lens, k) is lens and k.distortion is lens
    r = np.array([0.0, 0.3, 1.0, 2.5])
    xd, yd = lens.distort(r, np.zeros_like(r))
    np.testing.assert_allclose(xd, np.arctan(r), rtol=0, atol=1e-15)
    np.testing.assert_array_equal(yd, 0)
    x, _ = lens.undistort(xd, yd)  # the round trip, at and off the axis
    np.testing.assert_allclose(x, r, rtol=1e-12, atol=1e-15)
    pixels = image_pixels(k)
    bent = camera_directions(k, pixels, torch.float64)
    flat = camera_directions(Intrinsics(W, H, *focal), pixels, torch.float64)
    radius = torch.hypot(flat[:, 0], flat[:, 1])  # the recorded (distorted) radius is the ray's angle
    assert torch.allclose(torch.atan(torch.hypot(bent[:, 0], bent[:, 1])), radius, rtol=0, atol=1e-12)
    assert float((bent[:, :2] - flat[:, :2]).abs().max()) > 0.1  # (not the pinhole's rays)
    header = DatasetWriter(tmp_path, k, 40000.0, np.array([[-1.0] * 3, [1.0] * 3]), 0.1, 5.0).header()
    assert header["camera_model"] == "OPENCV_FISHEYE" and "k1" not in header
    path = tmp_path / "t.json"
    path.write_text(json.dumps({**header, "frames": []}))
    assert transforms.intrinsics(transforms.read_transforms(path), path) == k
    c2w = look_at(np.array([0.3, -2.5, 1.1]), np.zeros(3))
    origins, dirs = image_rays(torch.tensor(c2w), k)
    u, v, _ = project_points(c2w, (origins + 2 * dirs).numpy(), k)
    np.testing.assert_allclose(np.stack([u, v], -1), (pixels + 0.5).numpy(), atol=1e-6)


def test_transforms_json_keys_round_trip_through_the_dataset_writer(tmp_path: Path) -> None:
    for lens in (LENSES[0], LENSES[3]):
        k = _camera(lens)
        writer = DatasetWriter(tmp_path, k, 40000.0, np.array([[-1.0] * 3, [1.0] * 3]), 0.1, 5.0)
        header = writer.header()
        assert header["camera_model"] == lens.model and header["k1"] == lens.k1
        assert {key for key in ("k1", "k2", "k3", "k4", "p1", "p2") if key in header} == {
            key for key in ("k1", "k2", "k3", "k4", "p1", "p2") if getattr(lens, key)
        }
        path = tmp_path / "t.json"
        path.write_text(json.dumps({**json.loads(json.dumps(header)), "frames": []}))
        assert transforms.intrinsics(transforms.read_transforms(path), path) == k
    # a nerfstudio view keeps its lens: camera_model OPENCV replaces the views' PINHOLE
    assert (
        DatasetWriter(tmp_path, _camera(LENSES[0]), 1.0, np.eye(2, 3) - 2, 0.1, 5.0).header(
            camera_model="PINHOLE"
        )["camera_model"]
        == "OPENCV"
    )
    assert (
        "camera_model" not in DatasetWriter(tmp_path, _camera(None), 1.0, np.eye(2, 3) - 2, 0.1, 5.0).header()
    )


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"camera_model": "EQUIRECTANGULAR"}, "field 'camera_model': 'EQUIRECTANGULAR' is not supported"),
        ({"camera_model": "OPENCV", "k2": "x"}, "field 'k2': expected a finite number, found 'x'"),
        ({"camera_model": "OPENCV", "p1": None}, "field 'p1': expected a finite number"),
        ({"camera_model": "OPENCV_FISHEYE", "p1": 0.1}, "field 'p1': p1 must be 0 for OPENCV_FISHEYE"),
        ({"camera_model": "OPENCV", "k1": -3.0}, "fields 'camera_model', 'k1': the OPENCV k1=-3 lens is not"),
    ],
)
def test_a_bad_lens_in_transforms_json_names_the_file_and_the_key(tmp_path: Path, change, words) -> None:
    path = tmp_path / "t.json"
    path.write_text(json.dumps({"w": W, "h": H, "fl_x": 24.0, **change, "frames": []}))
    with pytest.raises(InputError, match=words) as err:
        transforms.intrinsics(transforms.read_transforms(path), path)
    assert err.value.path == str(path)


def test_a_frame_with_its_own_lens_is_a_per_frame_camera(tmp_path: Path) -> None:
    path = tmp_path / "t.json"
    meta = {"w": W, "h": H, "fl_x": 24.0, "frames": [{"k1": 0.1}]}
    with pytest.raises(InputError, match=r"t\.json: frames\[0\]\.k1 differs from 0: per-frame cameras"):
        transforms.intrinsics(meta, path)
    same = {"camera_model": "OPENCV", "k1": 0.1}
    k = transforms.intrinsics({"w": W, "h": H, "fl_x": 24.0, **same, "frames": [dict(same)]}, path)
    assert k.distortion == Distortion(k1=0.1)


def test_a_distorted_simulation_is_stored_read_and_cast_through_its_lens(capsys, tmp_path: Path) -> None:
    """End to end: an analytic scene filmed through a lens → dataset → load → rays, and ``info``."""
    lens = Distortion(k1=-0.2, k2=0.03, p1=1e-3)
    traj = orbit(4.0, 30.0, duration=8 / 40000, fps=40000)
    source = analytic.AnalyticSource("analytic-orbs", 16, 12, traj, supersample=1, distortion=lens)
    out = simulate_dataset(source, tmp_path / "ds", SimulateOptions(blur_fps=0, gt_every=4), progress=False)
    meta = json.loads((out / "transforms.json").read_text())
    assert meta["camera_model"] == "OPENCV" and meta["k1"] == -0.2 and "k3" not in meta
    ds = load_dataset(out)
    assert ds.intrinsics == source.intrinsics and ds.intrinsics.distortion == lens
    # the dataset's rays are the ones the scene was rendered along (the analytic source's own camera)
    pose = ds.trajectory.poses[4]
    _, dirs = image_rays(torch.tensor(pose), ds.intrinsics)
    want = analytic.camera_directions(source.intrinsics) @ pose[:3, :3].T
    np.testing.assert_allclose(dirs.numpy().reshape(12, 16, 3), want, atol=1e-9)
    code, text, err = run_cli(capsys, "info", out)
    assert code == 0 and "lens: OPENCV k1=-0.2 k2=0.03 p1=0.001" in text, err


def test_the_field_of_view_is_the_lens_one() -> None:
    """``view_angle_x``: what the image sees through its lens (an equidistant fisheye: width / focal); the
    pinhole's ``camera_angle_x`` under a fisheye undercounts it (100° of 137.5° here)."""
    pinhole = Intrinsics(24, 8, 10.0, 10.0, 12.0, 4.0)
    assert pinhole.view_angle_x == pinhole.camera_angle_x
    fisheye = replace(pinhole, distortion=Distortion("OPENCV_FISHEYE"))
    assert fisheye.view_angle_x == pytest.approx(24 / 10.0, abs=1e-12)
    assert math.degrees(fisheye.camera_angle_x) == pytest.approx(100.39, abs=0.01)
    barrel = replace(pinhole, distortion=Distortion(k1=-0.05))
    assert pinhole.camera_angle_x < barrel.view_angle_x < fisheye.view_angle_x


def test_an_import_without_a_box_sizes_the_scene_with_the_lens_field_of_view(capsys, tmp_path: Path) -> None:
    """Cameras alone size the scene from their view frustum at the focus: through the lens (a fisheye's
    137.5°), not the pinhole's 100° (a box 2.1 times too small: the scene beyond it never rendered)."""
    from spikenerf.camera.io import write_dat

    rec = tmp_path / "rec" / "s.dat"
    write_dat(rec, (np.random.default_rng(0).random((40, 8, 24)) < 0.3).astype(np.uint8))
    (rec.parent / "config.yaml").write_text("spike_h: 8\nspike_w: 24\nfps: 40000\n")
    truth = orbit(4.0, 30.0, duration=40 / 40000, fps=40000).poses  # radius 4 about the origin
    frames = [{"step": s, "transform_matrix": truth[s].tolist()} for s in range(0, 40, 8)]
    camera = {"w": 24, "h": 8, "fl_x": 10.0, "cx": 12.0, "cy": 4.0, "camera_model": "OPENCV_FISHEYE"}
    (tmp_path / "p.json").write_text(json.dumps({**camera, "frames": frames}))  # no scene box, no points
    code, _, err = run_cli(capsys, "import", rec, "--poses", tmp_path / "p.json", "--out", tmp_path / "ds")
    assert code == 0, err
    ds = load_dataset(tmp_path / "ds")
    distance = np.linalg.norm(ds.trajectory.poses[::8, :3, 3], axis=-1)  # the given poses, from the focus
    np.testing.assert_allclose(distance, 1 / math.tan(24 / 10.0 / 2), rtol=1e-5)  # half of w / f
    code, text, _ = run_cli(capsys, "info", tmp_path / "ds")
    assert code == 0 and "fov: 137.5° (through the lens)   lens: OPENCV_FISHEYE" in text, text
