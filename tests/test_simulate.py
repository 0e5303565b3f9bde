"""The analytic scene, the simulate pipeline (end to end, resume) and `spikenerf simulate` errors."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import pytest
import yaml

from spikenerf.capture.blur import blur_windows
from spikenerf.capture.frame_cache import render_missing
from spikenerf.capture.options import SimulateOptions
from spikenerf.capture.simulate import simulate_dataset
from spikenerf.cli import main
from spikenerf.core.color import rgb_to_gray
from spikenerf.core.errors import InputError
from spikenerf.data.dataset import load_dataset
from spikenerf.data.writer import work_dir
from spikenerf.scenes import analytic
from spikenerf.scenes.analytic import (
    AnalyticSource,
    Box,
    Sphere,
    Texture,
    camera_directions,
    render_primitives,
)
from spikenerf.scenes.poses import look_at, pose_at
from spikenerf.scenes.registry import list_scenes, make_scene_source
from spikenerf.scenes.trajectory import Intrinsics, novel_views, orbit

WHITE = Texture("solid", (1.0, 1.0, 1.0))


def _render(prims, k: Intrinsics, c2w: np.ndarray, ss: int = 1) -> np.ndarray:
    return render_primitives(prims, c2w[:3, 3], camera_directions(k, ss) @ c2w[:3, :3].T, ss)


# ------------------------------------------------------------------------------------------- the scene
def test_background_is_white_and_frames_are_linear_float32() -> None:
    traj = orbit(4.0, 30.0, duration=0.0001)
    src = AnalyticSource("analytic-orbs", 40, 30, traj, novel_views(4.0, 2))
    away = look_at(np.array([0.0, 0.0, 3.0]), np.array([0.0, 0.0, 10.0]))  # looking up, away from the scene
    np.testing.assert_array_equal(src.render(away), np.ones((30, 40, 3), np.float32))
    frame = next(src.frames([0]))
    assert frame.dtype == np.float32 and frame.shape == (30, 40, 3)
    assert (frame[0] == 1.0).all() and (frame[:, 0] == 1.0).all()  # border rows/columns are background
    assert frame.min() >= 0.0 and frame.max() <= 1.0 and frame.min() < 0.3  # dark checker cells
    np.testing.assert_array_equal(frame, src.render(traj.poses[0]))  # deterministic
    poses, views = src.test_views()
    assert poses.shape == (2, 4, 4) and views.shape == (2, 30, 40, 3)
    with pytest.raises(InputError, match="not on the trajectory"):
        list(src.frames([999]))


def test_rays_agree_with_the_trainers_rays_and_up_is_up() -> None:
    from spikenerf.data.rays import image_rays

    k = Intrinsics.from_fov(12, 9, 0.7)
    c2w = orbit(4.0, 30.0, duration=0.0001).poses[3]
    _, dirs = image_rays(c2w, k)
    np.testing.assert_allclose(
        camera_directions(k) @ c2w[:3, :3].T, dirs.numpy().reshape(9, 12, 3), atol=1e-6
    )
    img = _render([Sphere((0, 0, 0.8), 0.3, WHITE)], Intrinsics.from_fov(20, 20, 0.69), c2w)
    rows = np.nonzero((img < 1).any(-1))[0]
    assert rows.max() < 10  # a sphere above the look-at point is in the top half of the image (row 0 = top)


def test_sphere_silhouette_has_the_projected_area() -> None:
    k = Intrinsics.from_fov(101, 101, 0.6911)
    c2w = look_at(np.array([4.0, 0.0, 0.0]), np.zeros(3))
    img = _render([Sphere((0, 0, 0), 0.8, WHITE)], k, c2w)
    covered = (img < 1.0).any(-1).sum()
    radius_px = k.fl_x * math.tan(math.asin(0.8 / 4.0))
    assert covered == pytest.approx(math.pi * radius_px**2, rel=0.03)
    assert img[50, 50] == pytest.approx(analytic.AMBIENT + (1 - analytic.AMBIENT) * analytic.LIGHT_DIR[0])


def test_box_face_on_is_a_square_and_facing_the_light_is_white() -> None:
    k = Intrinsics.from_fov(64, 64, 0.6911)
    c2w = look_at(np.array([0.0, 0.0, 4.0]), np.zeros(3), up=np.array([0.0, 1.0, 0.0]))
    img = _render([Box((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5), WHITE)], k, c2w)
    rows, cols = np.nonzero((img < 1.0).any(-1))
    side = 2 * k.fl_x * 0.5 / 3.5  # the near face (z = 0.5) seen from 3.5 units away
    assert rows.max() - rows.min() + 1 == pytest.approx(side, abs=1.01)
    assert cols.max() - cols.min() + 1 == pytest.approx(side, abs=1.01)
    eye = 4.0 * analytic.LIGHT_DIR  # looking along the light: the sphere's centre pixel has n·l = 1
    img = _render(
        [Sphere((0, 0, 0), 0.5, WHITE)], Intrinsics.from_fov(33, 33, 0.69), look_at(eye, np.zeros(3))
    )
    assert img[16, 16] == pytest.approx(1.0, abs=1e-3) and img.max() <= 1.0 + 1e-6


def test_shadow_and_supersampling() -> None:
    k = Intrinsics.from_fov(48, 48, 0.6911)
    slab = Box((-1, -1, -0.6), (1, 1, -0.5), WHITE)
    blocker = Sphere(tuple(0.4 * analytic.LIGHT_DIR - [0, 0, 0.1]), 0.2, WHITE)
    c2w = look_at(np.array([0.0, 0.01, 4.0]), np.zeros(3))
    lit, shadowed = _render([slab], k, c2w), _render([slab, blocker], k, c2w)
    assert (shadowed < lit - 0.3).any()  # the slab under the sphere (towards the light) is darker
    src1 = AnalyticSource("analytic-blocks", 32, 32, orbit(4.0, 30.0, duration=0.0001), supersample=1)
    src3 = AnalyticSource("analytic-blocks", 32, 32, src1.trajectory, supersample=3)
    a, b = src1.render(src1.trajectory.poses[0]), src3.render(src1.trajectory.poses[0])
    assert abs(a.mean() - b.mean()) < 0.02 and not np.array_equal(a, b)
    assert len(np.unique(b)) > len(np.unique(a))  # averaged edges give intermediate values


def test_registry_lists_analytic_scenes_and_rejects_unknown_ones() -> None:
    names = {s.name: s for s in list_scenes()}
    assert "analytic-orbs" in names and not names["analytic-orbs"].needs_blender
    traj = orbit(4.0, 30.0, duration=0.0001)
    src = make_scene_source("analytic-orbs", 8, 8, traj, np.zeros((0, 4, 4)), spp=9)
    assert isinstance(src, AnalyticSource) and src.supersample == 3
    with pytest.raises(InputError, match="unknown scene 'no-such-scene'"):
        make_scene_source("no-such-scene", 8, 8, traj, np.zeros((0, 4, 4)))
    with pytest.raises(InputError, match="not found"):
        make_scene_source("missing.blend", 8, 8, traj, np.zeros((0, 4, 4)))


def test_blur_windows_and_pose_interpolation() -> None:
    assert (
        blur_windows(1000, 40000, 400)[:2] == [(0, 100), (100, 200)]
        and len(blur_windows(1000, 40000, 400)) == 10
    )
    assert blur_windows(50, 40000, 400) == [(0, 50)]  # a partial window keeps its real exposure
    assert blur_windows(25, 40000, 4000)[-1] == (20, 25) and blur_windows(10, 40000, 0) == []
    traj = orbit(4.0, 0.0, duration=0.001)
    mid = pose_at(traj.poses, 4.5)
    az = math.atan2(mid[1, 3], mid[0, 3])
    assert az == pytest.approx(2 * math.pi * 4.5 / 40, abs=1e-4)
    np.testing.assert_allclose(mid[:3, :3].T @ mid[:3, :3], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(pose_at(traj.poses, 7.0), traj.poses[7], atol=1e-12)


# ------------------------------------------------------------------------------------------ end to end
ARGS = ["--width", "16", "--height", "16", "--frames", "50", "--blur-fps", "4000", "--test-views", "3"]


def _simulate(out: Path, *extra: str) -> None:
    main(["simulate", "--scene", "analytic-orbs", "--out", str(out), *ARGS, "--no-progress", *extra])


def test_simulate_end_to_end(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    _simulate(out, "--color", "all", "--threshold", "1.5", "--seed", "3")
    names = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file())
    assert names == sorted(
        [".spikenerf", "config.yaml", "transforms.json", "transforms_blur.json", "transforms_test.json",
         "spikes_gray.dat",
         "transforms_gt.json", "transforms_tfp.json", *[f"tfp/{s:05d}.png" for s in range(0, 50, 10)],
         "spikes_rgb_r.dat", "spikes_rgb_g.dat", "spikes_rgb_b.dat", "spikes_bayer.dat",
         *[f"gt/{s:05d}.png" for s in range(0, 50, 10)], *[f"blur/{i:05d}.png" for i in range(5)],
         *[f"test/{i:05d}.png" for i in range(3)]]
    )  # fmt: skip
    assert not work_dir(out).exists()
    cfg = yaml.safe_load((out / "config.yaml").read_text())
    keys = "spike_h spike_w fps threshold colors noise seed scene steps warmup gt_every blur_fps test_views"
    for key in [*keys.split(), "spikenerf_version", "command"]:
        assert key in cfg
    assert cfg["command"].startswith("spikenerf simulate --scene analytic-orbs --out ")
    assert (cfg["threshold"], cfg["colors"], cfg["steps"], cfg["seed"]) == (
        1.5,
        ["gray", "rgb", "bayer"],
        50,
        3,
    )
    ds = load_dataset(out)
    assert len(ds.trajectory) == 50 and ds.spikes("rgb").shape == (50, 3, 16, 16)
    np.testing.assert_allclose(ds.trajectory.times, np.arange(50) / 40000.0)
    np.testing.assert_array_equal(ds.gt.steps, [0, 10, 20, 30, 40])
    np.testing.assert_array_equal(ds.blur.step_ranges, [[i, i + 10] for i in range(0, 50, 10)])
    assert len(ds.test) == 3

    # the recorded data agrees with an independent render of the same scene and path
    src = AnalyticSource(
        "analytic-orbs", 16, 16, orbit(4.0, 30.0, duration=50 / 40000.0), novel_views(4.0, 3)
    )
    frames = np.stack(list(src.frames(range(50))))
    np.testing.assert_allclose(ds.gt.images, frames[::10], atol=2e-3)
    np.testing.assert_allclose(ds.blur.images[1], frames[10:20].mean(0), atol=2e-3)
    np.testing.assert_allclose(ds.blur.poses[1], pose_at(src.trajectory.poses, 14.5), atol=1e-6)
    np.testing.assert_allclose(ds.test.images, src.test_views()[1], atol=2e-3)
    # ideal camera: per-pixel count = floor(a0 + Σ I / φ), a0 ∈ [0, 1) → within one spike of Σ I / φ
    excess = ds.spikes("gray").sum(0) - rgb_to_gray(frames, channel_axis=-1).sum(0) / 1.5
    assert excess.min() > -1.05 and excess.max() < 1.05
    excess = ds.spikes("rgb").sum(0) - frames.transpose(0, 3, 1, 2).sum(0) / 1.5
    assert excess.min() > -1.05 and excess.max() < 1.05


class _Flaky(AnalyticSource):
    """Counts rendered steps; raises after ``fail_after`` frames (an interrupted run)."""

    def __init__(self, *args, fail_after: int | None = None, **kw) -> None:
        super().__init__(*args, **kw)
        self.fail_after, self.rendered = fail_after, 0

    def frames(self, steps: Sequence[int]) -> Iterator[np.ndarray]:
        for frame in super().frames(steps):
            if self.fail_after is not None and self.rendered == self.fail_after:
                raise KeyboardInterrupt
            self.rendered += 1
            yield frame


def test_resume_reuses_cached_frames(tmp_path: Path) -> None:
    traj = orbit(4.0, 30.0, duration=40 / 40000.0)
    make = lambda **kw: _Flaky("analytic-orbs", 16, 16, traj, novel_views(4.0, 1), **kw)  # noqa: E731
    options = SimulateOptions(colors=("gray", "rgb"), blur_fps=4000.0)
    out = tmp_path / "ds"
    first = make(fail_after=15)
    with pytest.raises(KeyboardInterrupt):
        simulate_dataset(first, out, options, progress=False)
    assert first.rendered == 15 and not out.exists()
    assert len(list((work_dir(out) / ".frames").glob("0*.npy"))) == 15
    second = make()
    simulate_dataset(second, out, options, progress=False)
    assert second.rendered == 25 and not work_dir(out).exists()
    ref = make()
    simulate_dataset(ref, tmp_path / "ref", options, progress=False)
    assert ref.rendered == 40
    for name in ["spikes_gray.dat", "spikes_rgb_r.dat", "transforms.json", "gt/00010.png", "blur/00002.png"]:
        assert (out / name).read_bytes() == (tmp_path / "ref" / name).read_bytes(), name
    failing = make(fail_after=0)  # failing before any frame is cached leaves no work folder behind
    with pytest.raises(KeyboardInterrupt):
        simulate_dataset(failing, tmp_path / "none", options, progress=False)
    assert not work_dir(tmp_path / "none").exists() and not (tmp_path / "none").exists()
    # a cache of another scene/resolution is not reused
    other = _Flaky("analytic-orbs", 8, 8, traj, fail_after=3)
    with pytest.raises(KeyboardInterrupt):
        simulate_dataset(other, tmp_path / "x", options, progress=False)
    small = _Flaky("analytic-orbs", 16, 16, traj)
    simulate_dataset(small, tmp_path / "x", options, progress=False)
    assert small.rendered == 40


def test_render_processes_write_the_same_dataset(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``jobs`` > 1 renders an analytic scene in worker processes; the dataset is byte-identical."""
    from spikenerf.capture import render_workers as workers

    pools = []

    class Recording(workers.ProcessPoolExecutor):
        def __init__(self, *args, **kw) -> None:  # type: ignore[no-untyped-def]
            pools.append(args[0])
            super().__init__(*args, **kw)

    monkeypatch.setattr(workers, "ProcessPoolExecutor", Recording)
    traj = orbit(4.0, 30.0, duration=24 / 40000.0)
    source = AnalyticSource("analytic-orbs", 16, 16, traj, novel_views(4.0, 1))
    options = SimulateOptions(colors=("gray", "rgb"), blur_fps=4000.0)
    simulate_dataset(source, tmp_path / "one", options, progress=False)
    assert pools == []
    simulate_dataset(source, tmp_path / "two", options, progress=False, jobs=2)
    assert pools == [2]
    for name in ["spikes_gray.dat", "spikes_rgb_g.dat", "transforms.json", "gt/00010.png", "test/00000.png"]:
        assert (tmp_path / "one" / name).read_bytes() == (tmp_path / "two" / name).read_bytes(), name
    with pytest.raises(InputError, match="jobs must be an integer ≥ 1"):
        simulate_dataset(source, tmp_path / "zero", options, progress=False, jobs=0)


class _ThreadProbe:
    """A parallel source whose every frame holds the worker's thread settings (BLAS, OpenMP)."""

    parallel_render = True

    def frames(self, steps: list[int]):  # type: ignore[no-untyped-def]
        names = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")
        for _ in steps:
            yield np.array([float(os.environ.get(n, "0")) for n in names])


def test_render_workers_get_their_share_of_the_cores(monkeypatch: pytest.MonkeyPatch) -> None:
    # without it, each of 14 workers on a 16-core host may start a BLAS pool of 16 threads
    from spikenerf.capture import render_workers as workers

    monkeypatch.setattr(workers, "_cores", lambda: 8)
    for name in workers.THREAD_VARS:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "3")  # a setting of the user's is kept
    frames = list(workers.render_frames(_ThreadProbe(), list(range(6)), 2))  # type: ignore[arg-type]
    assert [f.tolist() for f in frames] == [[4.0, 3.0]] * 6
    assert "OPENBLAS_NUM_THREADS" not in os.environ and os.environ["OMP_NUM_THREADS"] == "3"


def _fails(capsys, argv: list[str]) -> str:
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


def test_bad_inputs_exit_2_with_one_line(tmp_path: Path, capsys) -> None:
    out = tmp_path / "ds"
    _simulate(out)
    (out / "marker").write_text("x")
    assert "already exists" in _fails(
        capsys, ["simulate", "--scene", "analytic-orbs", "--out", str(out), *ARGS]
    )
    assert (out / "marker").exists()  # refused: nothing touched
    assert "did not write (marker)" in _fails(  # a file the user added: --overwrite would delete it
        capsys, ["simulate", "--scene", "analytic-orbs", "--overwrite", "--out", str(out), *ARGS]
    )
    (out / "marker").unlink()
    _simulate(out, "--overwrite", "--frames", "20")
    assert load_dataset(out).config["steps"] == 20
    bad = tmp_path / "bad.json"
    bad.write_text('{"frames": [')
    err = _fails(
        capsys,
        ["simulate", "--scene", "analytic-orbs", "--eval-views", str(bad), "--out", str(tmp_path / "y")],
    )
    assert "bad.json: malformed JSON" in err and not (tmp_path / "y").exists()
    assert "unknown scene" in _fails(capsys, ["simulate", "--scene", "nope", "--out", str(tmp_path / "z")])
    assert "exactly one of" in _fails(capsys, ["simulate", "--out", str(tmp_path / "z")])
    assert "--out" in _fails(capsys, ["simulate", "--scene", "analytic-orbs"])
    assert "--frames" in _fails(
        capsys, ["simulate", "--scene", "analytic-orbs", "--frames", "0", "--out", "q"]
    )
    no_blur = ["simulate", "--scene", "analytic-orbs", "--blur-fps", "0", "--blur-views", "3", "--out", "q"]
    assert "--blur-views: there is no blur camera with --blur-fps 0" in _fails(capsys, no_blur)
    meta = out / "transforms.json"
    data = json.loads(meta.read_text())
    data["frames"][0]["file_path"] = "../../secret.png"
    meta.write_text(json.dumps(data))
    assert "escapes the dataset folder" in _fails(capsys, ["info", str(out)])
    meta.write_text(meta.read_text()[:100])
    assert "transforms.json: malformed JSON" in _fails(capsys, ["info", str(out)])


def test_list_scenes_and_info(tmp_path: Path, capsys) -> None:
    main(["simulate", "--list-scenes"])
    listing = capsys.readouterr().out
    assert "analytic-orbs" in listing and "analytic-blocks" in listing
    _simulate(tmp_path / "ds", "--color", "rgb")
    capsys.readouterr()
    main(["info", str(tmp_path / "ds")])
    text = capsys.readouterr().out
    assert "steps: 50" in text and "16×16" in text and "spikes [rgb]" in text and "test views: 3" in text
    motion = float(text.split("image motion: ", 1)[1].split()[0])
    assert 0 < motion < 1  # a 16-pixel image on a 50-step orbit: 7.2° a step
    assert (tmp_path / "ds" / "preview.png").is_file()


def test_simulate_from_an_image_sequence(tmp_path: Path, capsys) -> None:
    from spikenerf.data.dataset import write_image

    traj = orbit(4.0, 30.0, duration=6 / 40000.0)
    src = AnalyticSource("analytic-orbs", 16, 16, traj)
    frames = []
    for i, image in enumerate(src.frames(range(6))):
        write_image(tmp_path / "seq" / f"{i:03d}.png", image)
        frames.append({"file_path": f"{i:03d}.png", "transform_matrix": traj.poses[i].tolist()})
    seq = tmp_path / "seq" / "transforms.json"
    seq.write_text(json.dumps({"camera_angle_x": analytic.CAMERA_ANGLE_X, "frames": frames}))
    out = tmp_path / "ds"
    main(["simulate", "--sequence", str(seq), "--steps-per-frame", "2", "--out", str(out), "--no-progress"])
    ds = load_dataset(out)
    assert len(ds.trajectory) == 12 and ds.intrinsics.width == 16 and len(ds.test) == 0
    assert ds.config["trajectory"]["kind"] == "sequence" and ds.config["trajectory"]["steps_per_frame"] == 2
    np.testing.assert_allclose(ds.gt.images[0], next(src.frames([0])), atol=2e-3)
    assert "exposure spans 100 steps, more than the 12-step path" in capsys.readouterr().err
    err = _fails(capsys, ["simulate", "--sequence", str(seq), "--radius", "3", "--out", str(tmp_path / "x")])
    assert "--radius" in err and "not used with --sequence" in err


def test_elevation_sweep_moves_the_camera_up_and_down(tmp_path: Path, capsys) -> None:
    out = tmp_path / "ds"
    _simulate(out, "--elevation-sweep", "30", "--test-views", "0")
    ds = load_dataset(out)
    eyes = ds.trajectory.poses[:, :3, 3]
    elevation = np.degrees(np.arcsin(eyes[:, 2] / np.linalg.norm(eyes, axis=1)))
    assert elevation.max() == pytest.approx(45.0, abs=0.1) and elevation.min() == pytest.approx(15.0, abs=0.1)
    assert elevation[12] > 44.0 and elevation[38] < 16.0  # one sine period: up first, then down
    assert ds.config["trajectory"]["elevation_sweep_deg"] == 30.0
    forward = -ds.trajectory.poses[:, :3, 2]  # still looking at the centre
    np.testing.assert_allclose(np.einsum("ij,ij->i", forward, -eyes / 4.0), 1.0, atol=1e-6)
    for bad in ("-5", "140", "nan"):
        err = _fails(capsys, ["simulate", "--scene", "analytic-orbs", "--out", str(tmp_path / "x"),
                              "--elevation-sweep", bad])  # fmt: skip
        assert "--elevation-sweep" in err and not (tmp_path / "x").exists()


@pytest.mark.parametrize(("views", "count"), [("all", 12), ("5", 5)])
def test_resource_estimate_counts_the_blur_views(tmp_path: Path, capsys, monkeypatch, views, count) -> None:
    import spikenerf.capture.simulate as simulate

    seen = {}

    def estimate(*args, **kwargs):
        seen.update(kwargs)
        raise InputError("stop here")

    monkeypatch.setattr(simulate, "check_simulate_resources", estimate)
    args = ["--scene", "analytic-orbs", "--frames", 12, "--blur-views", views, "--out", tmp_path / "ds"]
    with pytest.raises(SystemExit):
        main(["simulate", *map(str, args)])
    assert seen["blur_frames"] == count


class _BrightSource:
    """A frame source whose second frame holds ``value`` in one pixel (what a linear .npy or EXR image
    sequence may hold)."""

    name, parallel_render = "bright", False

    def __init__(self, value: float) -> None:
        self.intrinsics = Intrinsics.from_fov(8, 8, 0.6)
        self.trajectory = orbit(4.0, 30.0, duration=3 / 40000)
        self.value = value

    def frames(self, steps: Sequence[int]) -> Iterator[np.ndarray]:
        for step in steps:
            frame = np.full((8, 8, 3), 0.5, np.float32)
            frame[0, 0] = self.value if step == 1 else 0.5
            yield frame

    def test_views(self) -> tuple[np.ndarray, np.ndarray]:
        return np.eye(4)[None], np.zeros((1, 8, 8, 3), np.float32)


def test_frames_the_camera_cannot_take_are_refused_and_negative_light_is_none(tmp_path: Path) -> None:
    """A linear intensity past float16's range would cache as inf and fire at every step: refused in one
    line naming the step. A negative one (a denoiser's −1e-4) would be a charge debt that silences its
    pixel: it is read as no light."""
    with pytest.raises(InputError, match=r"intensity of 100000 for step 1; the camera takes at most 65504"):
        render_missing(_BrightSource(1e5), tmp_path / "cache", progress=False)
    assert render_missing(_BrightSource(65504.0), tmp_path / "ok", progress=False) == 3
    assert render_missing(_BrightSource(-5.0), tmp_path / "dark", progress=False) == 3
    assert np.load(tmp_path / "dark" / "00001.npy")[0, 0].tolist() == [0.0, 0.0, 0.0]


def test_simulate_refuses_a_blur_camera_faster_than_the_spikes_and_records_the_realised_rate(
    tmp_path: Path, capsys
) -> None:
    argv = ["simulate", "--scene", "analytic-orbs", "--out", str(tmp_path / "fast"), *ARGS]
    assert "exceeds the spike rate" in _fails(capsys, [*argv, "--blur-fps", "50000"])
    assert not (tmp_path / "fast").exists()
    _simulate(tmp_path / "ds", "--blur-fps", "3000", "--frames", "40")  # exposures of round(13.3) = 13 steps
    blur = json.loads((tmp_path / "ds" / "transforms_blur.json").read_text())
    assert blur["fps"] == pytest.approx(40000 / 13)


def test_simulate_refuses_a_raw_width_no_camera_has_before_rendering(tmp_path: Path, capsys) -> None:
    argv = ["simulate", "--scene", "analytic-orbs", "--out", str(tmp_path / "raw"), *ARGS]
    err = _fails(capsys, [*argv, "--raw-width", "99999999999999999999"])
    assert "--raw-width" in err and "from the image width 16 to 80" in err
    assert not (tmp_path / "raw").exists() and not (tmp_path / "raw.partial").exists()
    assert "--warmup" in _fails(capsys, [*argv, "--warmup", "100001"])


def test_render_workers_start_with_ctrl_c_ignored_and_the_parent_keeps_its_handler() -> None:
    import signal

    from spikenerf.capture import render_workers

    before = signal.getsignal(signal.SIGINT)
    with render_workers._sigint_ignored():
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN  # what the spawned workers inherit
    assert signal.getsignal(signal.SIGINT) is before


def test_a_blur_exposure_longer_than_the_path_is_warned_of(tmp_path: Path, capsys) -> None:
    from helpers import run_cli

    argv = ["simulate", "--scene", "analytic-orbs", "--width", 8, "--height", 8, "--test-views", 0]
    code, out, err = run_cli(capsys, *argv, "--frames", 40, "--out", tmp_path / "short", "--no-progress")
    assert code == 0 and err.strip() == (
        "spikenerf: warning: one --blur-fps 400 exposure spans 100 steps, more than the 40-step path: every "
        "blur view is the mean of the whole path"
    )
    code, out, err = run_cli(capsys, *argv, "--frames", 100, "--out", tmp_path / "whole", "--no-progress")
    assert code == 0 and err == ""
    code, out, _ = run_cli(capsys, "info", tmp_path / "whole")
    assert "blur frames: 1 at 400 fps (100 steps of exposure each)" in out and "(every 10 steps)" in out


def test_a_camera_inside_the_scene_box_and_a_rounded_spp_are_named(tmp_path: Path, capsys) -> None:
    from helpers import run_cli

    base = ["simulate", "--scene", "analytic-orbs", "--width", 8, "--height", 8, "--frames", 4,
            "--blur-fps", 0, "--no-progress"]  # fmt: skip
    code, _, err = run_cli(capsys, *base, "--radius", 0.5, "--spp", 2, "--out", tmp_path / "in")
    lines = err.strip().splitlines()
    assert code == 0 and lines[0] == "spikenerf: warning: --spp 2 renders 1 sample per pixel (a k × k grid)"
    inside = "inside the scene box [-1.0, -1.0, -1.0] to [1.0, 1.0, 1.0] (--radius 0.5)"
    assert [line.split(" lies")[0] for line in lines[1:]] == [
        "spikenerf: warning: the orbit",
        "spikenerf: warning: a test view",
    ] and all(inside in line for line in lines[1:])
    code, _, err = run_cli(capsys, *base, "--spp", 4, "--out", tmp_path / "out")  # the default radius 4
    assert code == 0 and err.strip() == ""


def test_simulate_options_read_a_colour_string_as_a_list() -> None:
    """``SimulateOptions(colors="gray")`` was the modes g, r, a, y (refused as such)."""
    from spikenerf.capture.options import SimulateOptions, check_options
    from spikenerf.core.errors import InputError

    assert SimulateOptions(colors="gray").colors == ("gray",)
    assert SimulateOptions(colors="gray, rgb").colors == ("gray", "rgb")
    assert SimulateOptions(colors="all").colors == ("gray", "rgb", "bayer")
    assert SimulateOptions(colors=["rgb"]).colors == ("rgb",)  # type: ignore[arg-type]
    with pytest.raises(InputError, match="colors: expected gray, rgb, bayer or all, found grey"):
        check_options(SimulateOptions(colors="grey"))
