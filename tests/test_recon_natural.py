"""Natural-image pairs for the learned reconstructor (recon/natural.py): shapes, motion, splits, errors."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from helpers import run_cli
from spikenerf.core.errors import InputError
from spikenerf.recon.generate import write_pairs
from spikenerf.recon.natural import (
    NATURAL_HELDOUT,
    NATURAL_TRAIN,
    load_images,
    motion_grids,
    natural_pairs,
    render_motion,
)
from spikenerf.recon.pairs import PairConfig
from spikenerf.recon.store import load_split

pytest.importorskip("skimage")  # the [natural] extra; CI installs it
CFG = PairConfig(size=24, window=9)


def test_photographs_load_as_linear_rgb_and_the_splits_are_disjoint() -> None:
    images = load_images(("camera", "chelsea"))
    for image in images.values():
        assert image.dtype == np.float32 and image.ndim == 3 and image.shape[2] == 3
        assert image.min() >= 0.0 and image.max() <= 1.0
    assert not set(NATURAL_TRAIN) & set(NATURAL_HELDOUT)
    with pytest.raises(InputError, match="no photograph 'nope'"):
        load_images(("nope",))


def test_pairs_have_each_colour_mode_shape_and_are_deterministic() -> None:
    images = load_images(("coins",))
    for mode, count, side in (("gray", 1, 24), ("rgb", 3, 24), ("bayer", 4, 24)):
        cfg = PairConfig(size=24, window=9, modes=(mode,))
        samples = list(natural_pairs(images, range(2), cfg, seed=3))
        assert len(samples) == 2 * count
        for s in samples:
            assert s.window.shape == (9, side, side) and s.window.dtype == bool
            assert s.target.shape == (side, side) and np.isfinite(s.target).all()
            assert s.info["scene"] == "natural:coins"
    again = list(natural_pairs(images, range(2), CFG, seed=3))
    first = list(natural_pairs(images, range(2), CFG, seed=3))
    assert all(np.array_equal(a.window, b.window) for a, b in zip(again, first, strict=True))


@pytest.mark.parametrize("draw", range(12))
def test_motion_is_a_pan_or_a_roll_zoom_about_the_middle_step(draw: int) -> None:
    rng = np.random.default_rng([0, draw])
    grids, info = motion_grids(rng, (400, 500), 16, 9, 1.5, 2)
    assert grids.shape == (9, 32, 32, 2)
    steps = grids[1:] - grids[:-1]
    if info["motion"] == "still":
        assert torch.allclose(steps, torch.zeros_like(steps))
    elif info["motion"] == "pan":  # the same shift for every pixel and every step
        assert torch.allclose(steps, steps[:1, :1, :1].expand_as(steps), atol=1e-5)
        assert steps.abs().max() > 0
    else:  # roll-zoom: the view's centre stays put and its corners move
        centre = grids[:, 15:17, 15:17].mean(dim=(1, 2))
        assert torch.allclose(centre, centre[:1].expand_as(centre), atol=1e-5)
        assert (grids[-1, 0, 0] - grids[0, 0, 0]).abs().max() > 0


def test_a_still_view_renders_the_same_frame_at_every_step() -> None:
    image = np.random.default_rng(0).random((50, 60, 3), dtype=np.float32)
    rng = next(np.random.default_rng([0, i]) for i in range(100) if _motion(i) == "still")
    grids, info = motion_grids(rng, (50, 60), 16, 5, 1.0, 2)
    frames = render_motion(image, grids, 2)
    assert info["motion"] == "still" and frames.shape == (5, 3, 16, 16)
    assert np.allclose(frames, frames[:1])


def _motion(i: int) -> str:
    return motion_grids(np.random.default_rng([0, i]), (50, 60), 16, 5, 1.0, 2)[1]["motion"]


def test_pair_folder_trains_on_training_photographs_and_validates_on_held_out_ones(tmp_path: Path) -> None:
    manifest = write_pairs(tmp_path / "p", CFG, 2, 8, seed=0, natural_draws=4, progress=False)
    assert manifest["natural_draws"] == 4 and "natural:camera" in manifest["val_scenes"]
    scenes = {
        split: {i["scene"] for i in load_split(tmp_path / "p", split).info} for split in ("train", "val")
    }
    train_photos = {s for s in scenes["train"] if s.startswith("natural:")}
    val_photos = {s for s in scenes["val"] if s.startswith("natural:")}
    assert train_photos and val_photos
    assert {s.split(":")[1] for s in train_photos} <= set(NATURAL_TRAIN)
    assert {s.split(":")[1] for s in val_photos} <= set(NATURAL_HELDOUT)
    assert json.loads((tmp_path / "p" / "manifest.json").read_text())["natural_draws"] == 4


def test_missing_scikit_image_is_one_line_with_the_install_hint_and_writes_nothing(
    capsys, monkeypatch, tmp_path: Path
) -> None:
    monkeypatch.setitem(sys.modules, "skimage", None)
    monkeypatch.setitem(sys.modules, "skimage.data", None)
    code, _, err = run_cli(capsys, "recon-data", "--out", tmp_path / "p", "--natural", 4)
    assert code == 2 and err.count("\n") == 1, err
    assert "--natural" in err and "pip install 'spikenerf[natural]'" in err
    assert not (tmp_path / "p").exists()
