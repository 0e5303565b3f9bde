"""``spikenerf export``: point clouds and meshes of a model whose geometry is known exactly.

The model is a grid field whose density factors are written by hand (:func:`make_sphere`): raw density
``k·(ρ² − |x − c|²)`` (a quadratic is a sum of separable terms, which the VM factors hold, up to bilinear
interpolation), so that its density equals the mesh's default level exactly on the big sphere of the
``analytic-orbs`` scene, and a constant colour. The point cloud must lie on that sphere's surface (within a
marching step), the mesh's vertices too, and both must carry that colour. The CLI writes the same from a
run folder whose checkpoint holds that model; bad input exits 2 with one line and writes nothing.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from helpers import run_cli
from spikenerf.core.color import display_uint8, srgb_encode
from spikenerf.core.errors import InputError
from spikenerf.core.ply import ply_bytes, read_ply, write_ply
from spikenerf.eval.choices import DEFAULT_DENSITY_LEVEL
from spikenerf.eval.export import INSTALL_HINT, mesh, point_cloud, subsample
from spikenerf.eval.trajectories import RenderPath
from spikenerf.render.geometry import backproject, density_grid, lattice_axes, lattice_normals, occupancy_of
from spikenerf.render.model import build_model
from spikenerf.scenes.analytic import CAMERA_ANGLE_X, SCENES, Sphere
from spikenerf.scenes.trajectory import Intrinsics, orbit

#: the analytic-orbs scene's big striped sphere: centre (0, 0, 0.05), radius 0.5
SPHERE = next(p for p in SCENES["analytic-orbs"][1] if isinstance(p, Sphere) and p.radius == 0.5)
COLOR = (0.8, 0.25, 0.1)  # linear


def make_sphere(model, center=SPHERE.center, radius=SPHERE.radius, color=COLOR, k=1000.0) -> None:  # type: ignore[no-untyped-def]
    """Write a solid sphere into a grid model's factors (in place): density = the default mesh level on the
    sphere's surface, higher inside; colour ``color`` everywhere."""
    f = model.field
    cfg = f.config
    t = torch.linspace(-1.0, 1.0, f.resolution)  # the texels' normalised coordinates (align_corners)
    lo, hi = f.scene_box[0].tolist(), f.scene_box[1].tolist()
    d2 = [((lo[i] + (t + 1) * 0.5 * (hi[i] - lo[i])) - center[i]) ** 2 for i in range(3)]
    raw_level = math.log(math.expm1(DEFAULT_DENSITY_LEVEL / cfg.distance_scale)) - cfg.density_shift
    rho2 = radius**2 + raw_level / k
    with torch.no_grad():
        f.density_planes.zero_()
        f.density_lines.zero_()
        f.density_planes[0, 0] = k * (rho2 - d2[1][:, None] - d2[0][None, :])  # plane 0: (h = y, w = x)
        f.density_lines[0, 0, :, 0] = 1.0
        f.density_planes[0, 1] = 1.0
        f.density_lines[0, 1, :, 0] = -k * d2[2]  # line 0: z
        last = f.decoder[-1]
        last.weight.zero_()
        last.bias.copy_(torch.logit(torch.tensor(color[: model.channels])))
        f.update_occupancy()


def surface_distance(points: np.ndarray) -> np.ndarray:
    """Distance (N,) of points (N, 3) to the analytic sphere's exact surface."""
    return np.abs(np.linalg.norm(points - np.asarray(SPHERE.center), axis=-1) - SPHERE.radius)


def expected_rgb(channels: int = 3) -> np.ndarray:
    return display_uint8(srgb_encode(np.array(COLOR if channels == 3 else COLOR[:1] * 3)))


@pytest.fixture(scope="module")
def sphere_model():  # type: ignore[no-untyped-def]
    config = {"n_voxels_init": 96**3, "n_voxels_final": 96**3, "density_components": 2, "app_components": 2}
    model = build_model("grid", 3, np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]), config).eval()
    make_sphere(model)
    return model


def test_point_cloud_lies_on_the_true_surface_with_its_colour(sphere_model) -> None:  # type: ignore[no-untyped-def]
    k = Intrinsics.from_fov(32, 32, CAMERA_ANGLE_X)
    poses = orbit(4.0, 30.0, duration=4.0, fps=1.0, center=(0.0, 0.0, 0.0)).poses
    path = RenderPath("orbit", poses, k, 0.1, 10.0)
    points, colors, found = point_cloud(sphere_model, path, chunk=4096)
    assert len(points) == found > 100 and points.dtype == np.float32 and colors.dtype == np.uint8
    dist = surface_distance(points)
    step = sphere_model.field.step_size
    assert np.median(dist) < 0.5 * step and np.percentile(dist, 95) < 1.5 * step, (np.median(dist), step)
    assert np.abs(np.median(colors, axis=0) - expected_rgb()).max() <= 3  # the constant colour, on white
    fewer, _, again = point_cloud(sphere_model, path, max_points=50, chunk=4096)
    assert len(fewer) == 50 and again == found
    assert np.array_equal(fewer, point_cloud(sphere_model, path, max_points=50, chunk=4096)[0])  # fixed seed
    assert np.array_equal(subsample(10, 20), np.arange(10)) and len(set(subsample(100, 7).tolist())) == 7
    # a stricter opacity keeps no more pixels (this surface is sharp: hardly fewer), a laxer one no fewer
    assert len(point_cloud(sphere_model, path, min_opacity=0.99, chunk=4096)[0]) <= found
    assert len(point_cloud(sphere_model, path, min_opacity=0.0, chunk=4096)[0]) >= found
    with pytest.raises(InputError, match="min_opacity"):  # nothing that opaque (an empty model)
        point_cloud(build_model("grid", 3, np.array([[-1.0] * 3, [1.0] * 3]), {"init_scale": 0.0}), path)


def test_backproject_puts_depth_on_the_ray() -> None:
    origins = torch.tensor([[0.0, 0.0, 3.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    dirs = torch.tensor([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    points = backproject(origins, dirs, torch.tensor([2.5, 1.0, 9.0]), torch.tensor([0.9, 0.51, 0.5]), 0.5)
    assert points.tolist() == [[0.0, 0.0, 0.5], [1.0, 1.0, 0.0]]  # the third, at opacity 0.5, is dropped


def test_mesh_vertices_lie_on_the_level_set_and_the_sphere(sphere_model) -> None:  # type: ignore[no-untyped-def]
    pytest.importorskip("skimage")
    verts, faces, colors, _ = mesh(sphere_model, resolution=48)
    assert len(faces) > 500 and faces.max() < len(verts) and colors.shape == (len(verts), 3)
    dist = surface_distance(verts)
    cell = float(lattice_axes(sphere_model, 48)[1].max())
    # marching cubes interpolates the density linearly between lattice points: within a cell of the surface
    assert np.median(dist) < 0.35 * cell and dist.max() < cell, (np.median(dist), dist.max(), cell)
    finer, _, _, _ = mesh(sphere_model, resolution=96)
    assert np.median(surface_distance(finer)) < 0.6 * np.median(dist)  # and closer on a finer lattice
    assert (np.abs(colors.astype(int) - expected_rgb()).max(axis=1) <= 2).all()
    # a closed sphere: every edge is shared by exactly two triangles
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert (counts == 2).all()
    # a higher level is a smaller sphere
    inner, _, _, _ = mesh(sphere_model, resolution=48, density_level=10 * DEFAULT_DENSITY_LEVEL)
    r = np.linalg.norm(inner - np.asarray(SPHERE.center), axis=-1)
    assert np.median(r) < SPHERE.radius - 0.005
    with pytest.raises(InputError, match=r"density_level 1e\+06 lies outside the density's range"):
        mesh(sphere_model, resolution=16, density_level=1e6)


def test_density_grid_matches_the_field_at_the_lattice_points(sphere_model) -> None:  # type: ignore[no-untyped-def]
    grid = density_grid(sphere_model, 9)
    coords, spacing = lattice_axes(sphere_model, 9)
    assert grid.shape == (9, 9, 9) and torch.allclose(spacing, torch.full((3,), 0.25))
    ijk = torch.tensor([[4, 4, 4], [0, 8, 3], [6, 2, 5]])
    points = sphere_model.field.denormalize(coords[ijk])
    with torch.no_grad():
        direct = sphere_model.field(points, torch.zeros(3, 3))[0]
    assert torch.allclose(grid[ijk[:, 0], ijk[:, 1], ijk[:, 2]], direct, rtol=1e-4, atol=1e-3)
    # the base field's chunked default gives the same as the grid's separable one
    from spikenerf.fields.base import Field

    assert torch.allclose(Field.density_lattice(sphere_model.field, coords), grid, rtol=1e-4, atol=1e-3)


def test_mesh_normals_point_out_of_the_sphere_from_the_density_gradient(sphere_model) -> None:  # type: ignore[no-untyped-def]
    """Every vertex normal is a unit vector pointing away from the sphere's centre, within a few degrees of
    the true radial direction (minus the gradient of a density that is higher inside), and lattice_normals
    gives minus the exact gradient of a linear density."""
    pytest.importorskip("skimage")
    verts, _, _, normals = mesh(sphere_model, resolution=64)
    radial = verts - np.asarray(SPHERE.center)
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    assert normals.dtype == np.float32 and np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
    cos = (normals * radial).sum(axis=1)
    assert cos.min() > 0.9 and np.median(cos) > 0.99, (cos.min(), np.median(cos))
    axes = [np.arange(5) * h for h in (0.5, 0.25, 1.0)]  # (anisotropic spacing)
    x, y, z = np.meshgrid(*axes, indexing="ij")
    ramp = 3.0 * x - 2.0 * y + 0.5 * z
    points = np.array([[0.3, 0.6, 2.2], [1.9, 0.1, 3.9], [0.0, 0.0, 0.0]])
    want = -np.array([3.0, -2.0, 0.5]) / np.linalg.norm([3.0, -2.0, 0.5])
    np.testing.assert_allclose(
        lattice_normals(ramp, points, np.array([0.5, 0.25, 1.0])), [want] * 3, atol=1e-6
    )
    assert not lattice_normals(np.ones((3, 3, 3)), points[:1], np.ones(3)).any()  # no gradient: no normal


def test_the_mesh_skips_the_empty_space_of_the_occupancy_grid(sphere_model) -> None:  # type: ignore[no-untyped-def]
    """Where the run has an occupancy grid the field is asked on a smaller lattice around its occupied
    cells, with the same surface while the grid is conservative (here: it holds the whole sphere); density
    in cells the grid calls empty (which the renderer skips) makes no surface."""
    pytest.importorskip("skimage")
    field, grid = sphere_model.field, occupancy_of(sphere_model)
    assert grid is not None and grid.occupied_fraction() < 0.2
    asked: list[int] = []
    lattice = field.density_lattice

    def counted(coords: torch.Tensor) -> torch.Tensor:
        asked.append(len(coords))
        return lattice(coords)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(field, "density_lattice", counted)
        skipped = mesh(sphere_model, resolution=64)
        whole = mesh(sphere_model, resolution=64, occupancy=False)
    assert asked[1] == 64 and asked[0] < 0.7 * 64, asked  # (the sphere spans half the box)
    assert np.array_equal(skipped[1], whole[1]) and np.array_equal(skipped[2], whole[2])
    np.testing.assert_allclose(skipped[0], whole[0], atol=1e-6)  # (the separable sums' float rounding)
    np.testing.assert_allclose(skipped[3], whole[3], atol=1e-4)
    saved = grid.grid.clone()
    try:  # the grid calls the sphere's +x half empty: the mesh keeps only the other half
        grid.grid[grid.resolution // 2 + 4 :] = False
        half = mesh(sphere_model, resolution=64)[0]
        assert half[:, 0].max() < 0.2 < whole[0][:, 0].max()
        coords = lattice_axes(sphere_model, 9)[0]  # (occupancy=False: the whole lattice, as before)
        assert torch.equal(density_grid(sphere_model, 9, occupancy=False), field.density_lattice(coords))
    finally:
        grid.grid.copy_(saved)


def test_ply_round_trip_point_cloud_and_mesh(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    points = rng.normal(size=(7, 3)).astype(np.float32)
    colors = rng.integers(0, 256, size=(7, 3), dtype=np.uint8)
    faces = np.array([[0, 1, 2], [2, 3, 6]])
    write_ply(tmp_path / "m.ply", points, colors, faces)
    got = read_ply(tmp_path / "m.ply")
    assert np.array_equal(got.points, points) and np.array_equal(got.colors, colors)
    assert got.faces is not None and np.array_equal(got.faces, faces)
    data = ply_bytes(points, colors)
    assert data.startswith(b"ply\nformat binary_little_endian 1.0\n") and b"element face" not in data
    assert len(data) - data.index(b"end_header\n") - len(b"end_header\n") == 7 * 15  # 3 float32 + 3 uint8
    (tmp_path / "p.ply").write_bytes(data)
    assert read_ply(tmp_path / "p.ply").faces is None and read_ply(tmp_path / "p.ply").normals is None
    normals = rng.normal(size=(7, 3)).astype(np.float32)
    write_ply(tmp_path / "n.ply", points, colors, faces, normals)
    shaded = read_ply(tmp_path / "n.ply")
    assert shaded.normals is not None and np.array_equal(shaded.normals, normals)
    assert np.array_equal(shaded.points, points) and np.array_equal(shaded.colors, colors)
    assert b"property float nx\nproperty float ny\nproperty float nz\nproperty uchar red" in ply_bytes(
        points, colors, None, normals
    )
    (tmp_path / "t.ply").write_bytes(data[:-5])
    with pytest.raises(InputError, match="truncated"):
        read_ply(tmp_path / "t.ply")
    with pytest.raises(ValueError):
        ply_bytes(points, colors, np.array([[0, 1, 7]]))


# ---------------------------------------------------------------- the command, on a run folder


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 5-iteration run of analytic-orbs (gray) whose checkpoint's model is then made the sphere."""
    from spikenerf.cli import main
    from spikenerf.train.checkpoint import CHECKPOINT, load_checkpoint, model_of, save_checkpoint

    root = tmp_path_factory.mktemp("export")
    ds, run = root / "ds", root / "run"
    main(["simulate", "--scene", "analytic-orbs", "--width", "32", "--height", "32", "--frames", "60",
          "--test-views", "2", "--out", str(ds)])  # fmt: skip
    main(["train", str(ds), "--iters", "5", "--batch", "256", "--eval-every", "0", "--eval-views", "1",
          "--device", "cpu", "--quiet", "--out", str(run)])  # fmt: skip
    ckpt = load_checkpoint(run / CHECKPOINT)
    model = model_of(ckpt, run / CHECKPOINT)
    make_sphere(model)
    ckpt["model"] = model.state_dict()
    save_checkpoint(run / CHECKPOINT, ckpt)
    return run


def test_export_point_cloud_and_mesh_from_a_run(run_dir: Path, tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "cloud.ply"
    code, said, err = run_cli(capsys, "export", run_dir, "--device", "cpu", "--quiet", "--out", out)
    assert code == 0, err
    assert said.startswith(f"wrote {out}: ") and "points (of" in said and "iteration 5 of" not in said
    cloud = read_ply(out)
    assert cloud.faces is None and len(cloud.points) > 20
    assert np.median(surface_distance(cloud.points)) < 0.03
    assert cloud.colors is not None and (cloud.colors[:, 0] == cloud.colors[:, 1]).all()  # a gray run
    code, said, err = run_cli(capsys, "export", run_dir, "--device", "cpu", "--trajectory", "orbit",
                              "--orbit-frames", 3, "--max-points", 40, "--quiet", "--overwrite",
                              "--out", out)  # fmt: skip
    assert code == 0, err
    assert len(read_ply(out).points) == 40 and "in 3 views" in said
    if "skimage" in sys.modules or pytest.importorskip("skimage"):
        mesh_out = tmp_path / "mesh.ply"
        code, said, err = run_cli(capsys, "export", run_dir, "--kind", "mesh", "--resolution", 40,
                                  "--device", "cpu", "--out", mesh_out)  # fmt: skip
        assert code == 0, err
        got = read_ply(mesh_out)
        assert got.faces is not None and len(got.faces) > 100
        assert np.median(surface_distance(got.points)) < 0.025  # a third of a cell (the run's box: 2.6 wide)
        assert got.normals is not None and got.normals.shape == got.points.shape  # shaded by viewers
        outward = got.points - np.asarray(SPHERE.center)
        assert np.median((got.normals * outward).sum(axis=1)) > 0
        assert cloud.normals is None


def _refused(capsys, *args: object) -> str:  # type: ignore[no-untyped-def]
    code, _, err = run_cli(capsys, "export", *args)
    assert code == 2 and err.startswith("spikenerf: error: ") and err.count("\n") == 1, err
    return err.strip()


def test_export_writes_into_its_run_folder_as_render_does(run_dir: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    """``export RUN --out RUN/cloud.ply`` is written (a run holds no .ply of its own, and no command replaces
    or empties a run folder), as ``render RUN --out RUN/render`` is; the run stays as it was."""
    out = run_dir / "cloud.ply"
    before = sorted(p.name for p in run_dir.iterdir())
    try:
        code, said, err = run_cli(capsys, "export", run_dir, "--device", "cpu", "--quiet", "--out", out)
        assert code == 0 and said.startswith(f"wrote {out}: ") and not err, err
        assert len(read_ply(out).points) > 0
        assert sorted(p.name for p in run_dir.iterdir()) == sorted([*before, "cloud.ply"])  # no lock left
        assert "iterations: 5 of 5" in run_cli(capsys, "info", run_dir)[1]  # still the run it was
    finally:
        out.unlink(missing_ok=True)  # (the module's run, as the other tests find it)


def test_bad_input_exits_2_in_one_line_and_writes_nothing(
    run_dir: Path, tmp_path: Path, capsys, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    out = tmp_path / "x.ply"
    assert "run folder not found" in _refused(capsys, tmp_path / "none", "--out", out)
    unfinished = tmp_path / "unfinished"  # a run folder train has not checkpointed yet
    unfinished.mkdir()
    (unfinished / "config.yaml").write_text((run_dir / "config.yaml").read_text())
    assert "missing checkpoint" in _refused(capsys, unfinished, "--device", "cpu", "--out", out)
    assert "--resolution applies to --kind mesh" in _refused(capsys, run_dir, "--resolution", 8, "--out", out)
    assert "--max-points applies to --kind pointcloud" in _refused(
        capsys, run_dir, "--kind", "mesh", "--max-points", 3, "--out", out
    )
    assert "--orbit-frames sets the views of --trajectory orbit/spiral/interpolate" in _refused(
        capsys, run_dir, "--orbit-frames", 3, "--out", out
    )
    assert "expected a .ply file" in _refused(capsys, run_dir, "--out", tmp_path / "x.obj")
    dataset = run_dir.parent / "ds"  # a file among a dataset's is a stranger its --overwrite refuses
    assert "lies inside a dataset folder" in _refused(
        capsys, run_dir, "--device", "cpu", "--out", dataset / "a.ply"
    )
    err = _refused(capsys, run_dir, "--kind", "mesh", "--device", "cpu", "--density-level", 1e9, "--out", out)
    assert "--density-level 1e+09 lies outside the density's range" in err
    away = tmp_path / "away.json"  # one camera above the scene, looking up: no opaque pixel
    away.write_text(json.dumps({"frames": [{"transform_matrix": [[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 5],
                                                                 [0, 0, 0, 1]]}]}))  # fmt: skip
    err = _refused(capsys, run_dir, "--trajectory", away, "--device", "cpu", "--quiet", "--out", out)
    assert err.startswith("spikenerf: error: no pixel of the 1 view(s) has an opacity above --min-opacity")
    monkeypatch.setitem(sys.modules, "skimage.measure", None)  # import → ImportError: the extra is missing
    assert _refused(capsys, run_dir, "--kind", "mesh", "--out", out) == f"spikenerf: error: --{INSTALL_HINT}"
    monkeypatch.undo()
    assert not out.exists() and not (dataset / "a.ply").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "away.json",
        "unfinished",
    ]  # no temporaries, no locks left
    out.write_bytes(b"mine")
    assert "exists; pass --overwrite to replace it" in _refused(
        capsys, run_dir, "--device", "cpu", "--out", out
    )
    assert out.read_bytes() == b"mine"


def test_mesh_faces_are_wound_counter_clockwise_seen_from_outside(sphere_model) -> None:  # type: ignore[no-untyped-def]
    """PLY viewers take a face's front as counter-clockwise: the right-hand normal of every triangle of the
    sphere must point out of it (marching cubes winds them the other way; a viewer showed the mesh inside
    out: dark, or culled away)."""
    pytest.importorskip("skimage")
    verts, faces, _, _ = mesh(sphere_model, resolution=32)
    tri = verts[faces].astype(np.float64)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    outward = tri.mean(axis=1) - np.asarray(SPHERE.center)
    assert ((normal * outward).sum(axis=1) > 0).all()


def test_export_generated_paths_take_orbit_frames_and_check_memory_first(
    run_dir: Path, tmp_path: Path, capsys, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    """--orbit-frames sets the views of every generated path (spiral and interpolate as orbit, as render
    takes it), and a count beyond the memory is refused naming --orbit-frames before any pose is made (10⁷
    orbit poses took minutes to build, then were refused naming duration/fps)."""
    out = tmp_path / "interpolate.ply"
    code, said, err = run_cli(capsys, "export", run_dir, "--device", "cpu", "--trajectory", "interpolate",
                              "--orbit-frames", 2, "--quiet", "--out", out)  # fmt: skip
    assert code == 0, err
    assert "in 2 views" in said and read_ply(out).points.shape[1] == 3
    import spikenerf.eval.export as export

    def made(*args: object) -> None:
        raise AssertionError("the poses were made before the memory check")

    monkeypatch.setattr(export, "resolve_trajectory", made)
    for path in ("orbit", "interpolate"):
        err = _refused(capsys, run_dir, "--device", "cpu", "--trajectory", path, "--orbit-frames", 10**12,
                       "--quiet", "--out", tmp_path / "big.ply")  # fmt: skip
        assert "--trajectory/--orbit-frames: this needs about" in err, err
    assert not (tmp_path / "big.ply").exists()
