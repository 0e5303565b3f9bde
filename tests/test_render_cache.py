"""``render``'s resume cache (eval/render_cache.py) and the camera of a trajectory file
(data/camera_path.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from spikenerf.core.errors import InputError
from spikenerf.data.camera_path import read_camera_path
from spikenerf.eval.render_cache import CACHE, SPIKE_STATE_EVERY, RenderCache, digest_array, render_key

POSE = np.eye(4).tolist()


def _view(value: int, size: tuple[int, int] = (4, 5)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return np.full(size, value, np.uint8), np.full(size, 2.5, np.float32), np.full(size, 0.75, np.float32)


def test_views_are_kept_under_one_key_and_dropped_under_another(tmp_path: Path) -> None:
    cache = RenderCache.open(tmp_path, {"model": "a", "seed": 0})
    assert cache.view(0, (4, 5)) is None
    cache.put_view(0, *_view(9))
    kept = RenderCache.open(tmp_path, {"model": "a", "seed": 0}).view(0, (4, 5))
    assert kept is not None and all(np.array_equal(a, b) for a, b in zip(kept, _view(9), strict=True))
    assert RenderCache.open(tmp_path, {"model": "a", "seed": 1}).view(0, (4, 5)) is None
    assert not list((tmp_path / CACHE / "views").iterdir())  # the other key's views are gone


def test_a_damaged_or_mis_sized_view_is_rendered_again(tmp_path: Path) -> None:
    cache = RenderCache.open(tmp_path, {"k": 1})
    cache.put_view(0, *_view(9))
    cache.put_view(1, *_view(9))
    assert cache.view(0, (4, 6)) is None  # another image size
    path = tmp_path / CACHE / "views" / "00001.npz"
    path.write_bytes(path.read_bytes()[:40])  # cut short
    assert cache.view(1, (4, 5)) is None
    (tmp_path / CACHE / "views" / ".00002.npz.xa8b2c9q.tmp").write_bytes(b"half")  # a killed writer
    RenderCache.open(tmp_path, {"k": 1})
    assert not list((tmp_path / CACHE / "views").glob(".*.tmp"))


@pytest.mark.parametrize("shape", [(3, 5), (3, 3, 5)])
def test_the_spike_state_comes_back_at_its_last_save(tmp_path: Path, shape: tuple[int, ...]) -> None:
    cache = RenderCache.open(tmp_path, {"k": 1})
    assert cache.spike_state(shape) is None
    gen = np.random.default_rng(0)
    steps = [gen.random(shape) < 0.4 for _ in range(SPIKE_STATE_EVERY + 5)]
    cache.start_spikes(0, shape)
    for i, s in enumerate(steps, 1):
        cache.put_spike_step(i, s, torch.full(shape, float(i)))
    done, acc = cache.spike_state(shape)
    assert len(done) == SPIKE_STATE_EVERY and np.all(acc == SPIKE_STATE_EVERY)
    assert all(np.array_equal(a, b) for a, b in zip(done, steps, strict=False))
    cache.start_spikes(len(done), shape)  # the resumed stream appends after the saved steps
    assert (tmp_path / CACHE / "spikes.bits").stat().st_size == SPIKE_STATE_EVERY * (
        (np.prod(shape) + 7) // 8
    )
    assert cache.spike_state((5, 3)) is None  # another size
    (tmp_path / CACHE / "spikes.bits").write_bytes(b"\0")  # fewer bits than the state counts
    assert cache.spike_state(shape) is None
    cache.close()
    assert not (tmp_path / CACHE).exists()


def test_the_key_holds_digests_of_arrays_and_the_model() -> None:
    model = torch.nn.Linear(2, 1)
    poses = np.zeros((3, 4, 4))
    key = render_key(model, poses=poses, seed=1)
    assert key["poses"] == digest_array(poses) and json.dumps(key)
    assert render_key(model, poses=poses, seed=1) == key
    assert render_key(model, poses=poses + 1, seed=1)["poses"] != key["poses"]
    with torch.no_grad():
        model.bias.add_(1.0)
    assert render_key(model, poses=poses, seed=1)["model"] != key["model"]
    assert digest_array(torch.zeros(2, dtype=torch.bfloat16)) != digest_array(torch.zeros(2))


def _write(path: Path, **fields: object) -> Path:
    path.write_text(json.dumps({**fields, "frames": [{"transform_matrix": POSE}]}))
    return path


def test_a_trajectory_file_gives_its_camera_and_bounds(tmp_path: Path) -> None:
    bare = read_camera_path(_write(tmp_path / "a.json"), (16, 12))
    assert bare.poses.shape == (1, 4, 4) and bare.intrinsics is None and bare.bounds is None
    wide = read_camera_path(_write(tmp_path / "b.json", camera_angle_x=0.9, near=1, far=3), (16, 12))
    assert (wide.intrinsics.width, wide.intrinsics.height) == (16, 12) and wide.bounds == (1, 3)
    own = read_camera_path(_write(tmp_path / "c.json", fl_x=30, w=40, h=20), (16, 12)).intrinsics
    assert (own.width, own.height, own.fl_x, own.cx, own.cy) == (40, 20, 30, 20, 10)
    framed = {"frames": [{"transform_matrix": POSE, "fl_x": 30, "w": 40, "h": 20}]}  # the camera in the frame
    (tmp_path / "d.json").write_text(json.dumps(framed))
    assert read_camera_path(tmp_path / "d.json", (16, 12)).intrinsics == own
    mixed = {"w": 40, "h": 20, "frames": [{"transform_matrix": POSE, "fl_x": 30}]}  # size apart from it
    (tmp_path / "e.json").write_text(json.dumps(mixed))
    with pytest.raises(InputError, match="belong beside the camera"):
        read_camera_path(tmp_path / "e.json", (16, 12))


@pytest.mark.parametrize(
    ("fields", "needle"),
    [
        ({"w": 24, "h": 20}, "a camera needs 'camera_angle_x' or 'fl_x'"),
        ({"fl_x": 30, "w": 24}, "missing field 'h'"),
        ({"near": 3, "far": 2}, "expected near < far"),
        ({"far": 2}, "'near'"),
        ({"camera_angle_x": 4}, "camera_angle_x"),
    ],
)
def test_a_bad_trajectory_camera_is_one_error_naming_the_file(
    tmp_path: Path, fields: dict, needle: str
) -> None:
    path = _write(tmp_path / "t.json", **fields)
    with pytest.raises(InputError, match=needle) as err:
        read_camera_path(path, (16, 12))
    assert str(path) in str(err.value)


def test_pinned_values_are_the_first_starts_and_the_plan_is_the_latest(tmp_path: Path) -> None:
    first = RenderCache.open(tmp_path, {"k": 1}, pinned={"chunk": 65536}, plan=["orbit.mp4"])
    first.put_view(0, *_view(9))
    again = RenderCache.open(tmp_path, {"k": 1}, pinned={"chunk": 8192}, plan=["b.mp4"])
    assert again.pinned == {"chunk": 65536} and again.view(0, (4, 5)) is not None
    assert json.loads((tmp_path / CACHE / "key.json").read_text())["plan"] == ["b.mp4"]
    stored = json.loads((tmp_path / CACHE / "key.json").read_text())
    (tmp_path / CACHE / "key.json").write_text(json.dumps({**stored, "pinned": {"chunk": None}}))
    odd = RenderCache.open(tmp_path, {"k": 1}, pinned={"chunk": 8192})  # a pinned value of another type
    assert odd.pinned == {"chunk": 8192} and odd.view(0, (4, 5)) is None
