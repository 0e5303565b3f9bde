"""Review findings on `simulate --sequence`: duplicate JSON keys, untrustworthy scene boxes, symlinks found by
an added extension, a spikenerf dataset given as a sequence, a .npy that is no image, and the CLI's lines."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from helpers import edit_json, run_cli
from spikenerf.core.errors import InputError
from spikenerf.scenes import transforms
from spikenerf.scenes.scene_box import estimate_scene_box
from spikenerf.scenes.sequence import SequenceSource
from spikenerf.scenes.trajectory import orbit

W, H, N = 32, 24, 4


def _sequence(root: Path, n: int = N, **extra: object) -> Path:
    """n gray 32×24 PNGs in root/f and orbit poses; file_path without extension ("./f/0")."""
    (root / "f").mkdir(parents=True, exist_ok=True)
    poses = orbit(4.0, 30.0, duration=n / 40000.0).poses
    frames = []
    for i in range(n):
        iio.imwrite(root / "f" / f"{i}.png", np.full((H, W), 40 * i + 20, np.uint8))
        frames.append({"file_path": f"./f/{i}", "transform_matrix": poses[i].tolist()})
    path = root / "transforms.json"
    path.write_text(json.dumps({"camera_angle_x": 0.6, "frames": frames, **extra}))
    return path


@pytest.fixture
def seq(tmp_path: Path) -> Path:
    return _sequence(tmp_path / "seq")


# ------------------------------------------------------------------------------------ 1: duplicate keys
def test_a_key_given_twice_is_refused_naming_it(seq: Path) -> None:
    text = seq.read_text()
    seq.write_text('{"camera_angle_x": 0.1, ' + text[1:])  # a second camera_angle_x would win silently
    with pytest.raises(InputError, match=r"key 'camera_angle_x' given twice in one object") as err:
        transforms.read_transforms(seq)
    assert err.value.path == str(seq) and "\n" not in str(err.value)
    with pytest.raises(InputError, match="'camera_angle_x' given twice"):
        SequenceSource(seq)
    inner = text.replace('"file_path": "./f/2"', '"file_path": "./f/2", "file_path": "./f/3"')
    seq.write_text(inner)  # in a nested object too
    with pytest.raises(InputError, match="key 'file_path' given twice"):
        transforms.read_transforms(seq)
    seq.write_text(text)  # unchanged otherwise: the same objects as plain json.loads
    assert transforms.read_transforms(seq) == json.loads(text)


# ---------------------------------------------------------------------------------- 2: scene-box warnings
def test_a_far_camera_or_cameras_that_do_not_move_are_warned_of(seq: Path) -> None:
    poses = orbit(4.0, 30.0, duration=6 / 40000.0).poses
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an orbit: no warning
        box = estimate_scene_box(poses)
        SequenceSource(seq)
    far = poses.copy()
    far[1, 0, 3] = 1e30
    with pytest.warns(UserWarning, match=r"frames\[1\] lies 1e\+30 .* a wrong transform_matrix") as caught:
        estimate_scene_box(far)
    assert len(caught) == 1 and "\n" not in str(caught[0].message)
    still = np.repeat(poses[:1], 6, axis=0)
    with pytest.warns(UserWarning, match="the 6 cameras do not move .* no parallax"):
        estimate_scene_box(still)
    np.testing.assert_allclose(box, [[-2, -2, -2], [2, 2, 2]], atol=1e-9)  # the estimate is unchanged
    huge = poses.copy()
    huge[2, 1, 3] = -1e300  # no finite box comes out
    with pytest.raises(InputError, match=r"cannot estimate a scene box: .*frames\[2\]"):
        estimate_scene_box(huge)
    edit_json(seq, lambda m: m["frames"][3]["transform_matrix"][2].__setitem__(3, 1e30))
    with pytest.warns(UserWarning, match=r"transforms.json: the camera of frames\[3\]"):
        SequenceSource(seq)
    edit_json(
        seq, lambda m: m.update(scene_box=[[-1, -1, -1], [1, 1, 1]])
    )  # a given box: nothing to estimate
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        SequenceSource(seq)


def test_a_video_that_starts_at_rest_is_no_far_camera_and_parallel_axes_no_still_one() -> None:
    """30 frames at rest (pose noise 1e-6) then 10 moving 0.05–1: the moving ones were "over 1000× their
    typical" offset. A forward-facing dolly (parallel axes: the distance to what they face is a guess)
    is no still camera either."""
    rng = np.random.default_rng(0)
    poses = np.repeat(orbit(4.0, 30.0, duration=1 / 40000.0).poses[:1], 40, axis=0)
    poses[:30, :3, 3] += rng.normal(0, 1e-6, (30, 3))
    poses[30:, 0, 3] += np.linspace(0.05, 1.0, 10)
    dolly = np.repeat(poses[:1], 5, axis=0)
    dolly[:, 0, 3] += np.linspace(0, 1e-3, 5)  # 1 mm steps of a camera facing one way
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        estimate_scene_box(poses)
        estimate_scene_box(dolly)


# ---------------------------------------------------------------------- 3: a symlink out, no extension
def test_a_symlink_out_found_by_an_added_extension_is_named(seq: Path, tmp_path: Path) -> None:
    outside = tmp_path / "elsewhere.png"
    iio.imwrite(outside, np.zeros((H, W), np.uint8))
    (seq.parent / "f" / "out.png").symlink_to(outside)
    edit_json(seq, lambda m: m["frames"][1].update(file_path="./f/out"))
    with pytest.raises(InputError, match=r"frames\[1\].file_path: './f/out' \(out.png\) points outside"):
        SequenceSource(seq)
    edit_json(seq, lambda m: m["frames"][1].update(file_path="./f/out.png"))
    with pytest.raises(InputError, match=r"'./f/out.png' points outside"):
        SequenceSource(seq)


# -------------------------------------------------------------------------- 4: a spikenerf dataset's JSON
def test_a_spikenerf_datasets_transforms_json_gets_the_gt_every_hint(
    seq: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    def dataset(meta: dict) -> None:  # an image every 2 steps, as `simulate --gt-every 2` writes
        for i, frame in enumerate(meta["frames"]):
            frame["step"] = i
            if i % 2:
                del frame["file_path"]

    edit_json(seq, dataset)
    with pytest.raises(InputError, match=r"frames\[1\]: missing field 'file_path': a spikenerf data") as err:
        SequenceSource(seq)
    assert err.value.message.endswith("simulate it with gt_every 1") and err.value.params == ("gt_every",)
    code, _, out = run_cli(capsys, "simulate", "--sequence", seq, "--out", seq.parent.parent / "o")
    assert code == 2 and out.strip().endswith("simulate it with --gt-every 1"), out
    assert out.count("\n") == 1
    edit_json(seq, lambda m: [f.pop("step") for f in m["frames"]])  # not a dataset: the plain message
    with pytest.raises(InputError, match=r"frames\[1\]: missing field 'file_path'$"):
        SequenceSource(seq)
    (seq.parent / "config.yaml").write_text("spike_h: 24\nspikenerf_version: 0.1.0\n")  # ... or beside one
    with pytest.raises(InputError, match=r"gt_every 1$"):
        SequenceSource(seq)
    (seq.parent / "config.yaml").write_text("spike_h: 24\nnoise: recorded\nimported:\n  range: [0, 8]\n")
    with pytest.raises(InputError, match="an imported recording's dataset, spikes without images") as err:
        SequenceSource(seq)  # (a recording cannot be simulated again with gt_every 1)
    assert "gt_every" not in err.value.message


# --------------------------------------------------------------------------- 5: a .npy that is no image
def test_a_misshapen_npy_is_named_before_sizes_are_compared(seq: Path) -> None:
    np.save(seq.parent / "f" / "bad.npy", np.zeros((2, H, W, 3), np.float32))
    edit_json(seq, lambda m: m["frames"][0].update(file_path="./f/bad.npy"))
    with pytest.raises(InputError, match=r"expected an \(H, W\) or \(H, W, 1-4\) image, found shape") as err:
        SequenceSource(seq)
    assert err.value.path.endswith("bad.npy")
    np.save(seq.parent / "f" / "bad.npy", np.zeros((H, W, 7), np.float32))  # 7 channels: no image either
    with pytest.raises(InputError, match=r"found shape \(24, 32, 7\)"):
        SequenceSource(seq)


# ------------------------------------------------------------------------------------------ 6: the CLI
def test_cli_warns_of_a_stretch_and_says_one_step(
    seq: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    base = ["simulate", "--sequence", seq, "--blur-fps", "0", "--no-progress", "--sequence-range", "0:1"]
    code, out, err = run_cli(capsys, *base, "--width", 16, "--height", 100, "--out", tmp_path / "a")
    assert code == 0 and out.startswith(f"wrote {tmp_path / 'a'}: 1 step at 40000 Hz, 16×100"), out
    lines = [line for line in err.splitlines() if line]
    assert len(lines) == 1 and lines[0].startswith("spikenerf: warning: --width 16 --height 100 stretches")
    assert "32×24" in lines[0]
    code, out, err = run_cli(capsys, *base, "--width", 16, "--height", 12, "--out", tmp_path / "b")
    assert code == 0 and "warning" not in err, err  # the images' own aspect ratio
    code, _, err = run_cli(
        capsys, "simulate", "--sequence", seq, "--sequence-range", "-9:", "--out", tmp_path / "c"
    )
    assert code == 2 and "::" not in err, err
    assert err.strip().endswith("--sequence-range '-9:': -9 is outside the 4 listed frames (-4 to 4)"), err


# ------------------------------------------------------------- 6: a nerfstudio view's held-out frames
def test_a_nerfstudio_views_held_out_frames_stay_off_the_path(seq: Path) -> None:
    """A dataset's transforms_gt.json (what the gt_every hint points to) lists its test views among the
    frames, far from the path: only the frames of ``train_filenames`` make the path; as eval views, all."""
    far = np.eye(4)
    far[:3, 3] = [0.0, -4.0, 0.0]  # a test camera on the other side of the scene
    iio.imwrite(seq.parent / "f" / "t.png", np.full((H, W), 200, np.uint8))

    def nerfstudio_view(meta: dict) -> None:
        meta["train_filenames"] = [f["file_path"] for f in meta["frames"]]
        meta["frames"].append({"file_path": "./f/t", "transform_matrix": far.tolist()})

    edit_json(seq, nerfstudio_view)
    source = SequenceSource(seq, eval_views=seq)
    assert len(source.trajectory) == N and not np.allclose(source.trajectory.poses, far)
    assert len(source.test_views()[0]) == N + 1  # the eval views keep every listed frame
    edit_json(seq, lambda m: m.update(train_filenames=["./f/none"]))
    with pytest.raises(InputError, match="'train_filenames' lists none of the 5 frames' file_path"):
        SequenceSource(seq)


def test_a_nerfstudio_views_frames_keep_their_places_in_the_file(seq: Path) -> None:
    """With a held-out frame listed before the path's frames, the path's frames (``frame_indices``) and an
    error about one of them are named by their place in the file's ``frames``, not among the path's."""
    far = np.eye(4)
    far[:3, 3] = [0.0, -4.0, 0.0]
    iio.imwrite(seq.parent / "f" / "t.png", np.full((H, W), 200, np.uint8))

    def held_out_first(meta: dict) -> None:
        meta["train_filenames"] = [f["file_path"] for f in meta["frames"]]
        meta["frames"].insert(0, {"file_path": "./f/t", "transform_matrix": far.tolist()})

    edit_json(seq, held_out_first)
    source = SequenceSource(seq, frame_range="1:3")
    assert source.frame_indices.tolist() == [2, 3]  # the path's 2nd and 3rd frames, after the held-out one
    second = json.loads(seq.read_text())["frames"][2]["file_path"]
    iio.imwrite(seq.parent / f"{second}.png", np.full((H + 2, W), 50, np.uint8))  # another size
    with pytest.raises(InputError, match=r"frames\[2\]\.file_path: image is .* but frames\[1\] is"):
        SequenceSource(seq)
