"""The one spike layout convention (camera layout across packages, channels last per ray) and its one
conversion pair, ``camera.layout``: views, round trips, errors naming the parameter, and no other place."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import torch

from spikenerf.camera.layout import to_camera_layout, to_channels_last
from spikenerf.core.errors import InputError

SRC = Path(__file__).resolve().parents[1] / "src" / "spikenerf"
#: axis shuffles that are not the spike/frame layout, with why
OTHER_LAYOUTS = {
    "camera/layout.py": "the conversion itself",
    "eval/evaluate.py": "images as (C, H, W) for SSIM/LPIPS convolutions, C = 1 kept",
    "eval/lpips.py": "convolution kernels HWIO → OIHW",
    "fields/grid.py": "VM products (3, C, M) → (M, 3, C)",
    "fields/vm_ops.py": "grid factors (3, C, R, R) channels-last for the fused CPU and Triton kernels",
    "fields/vm_gather.py": "grid factors (3, C, R, R) as rows of channels (3·R·R, C) for index gathers",
    "scenes/poses.py": "quaternion components to the front",
}


@pytest.mark.parametrize("lib", ["numpy", "torch"])
@pytest.mark.parametrize("shape", [(5, 4, 6), (5, 3, 4, 6)])
def test_stream_round_trip_is_a_view(lib: str, shape: tuple[int, ...]) -> None:
    x = np.arange(int(np.prod(shape)), dtype=np.uint8).reshape(shape) % 2
    x = torch.from_numpy(x) if lib == "torch" else x
    last = to_channels_last(x)
    c = 1 if len(shape) == 3 else 3
    assert tuple(last.shape) == (5, 4, 6, c)
    for t, ch, h, w in [(0, 0, 0, 0), (4, c - 1, 3, 5), (2, c // 2, 1, 4)]:
        assert last[t, h, w, ch] == (x[t, h, w] if c == 1 else x[t, ch, h, w])
    back = to_camera_layout(last)
    assert type(back) is type(x) and tuple(back.shape) == shape and (back == x).all()
    if lib == "numpy":
        assert np.shares_memory(last, x) and np.shares_memory(back, x)
    else:
        assert last.data_ptr() == x.data_ptr() == back.data_ptr()


@pytest.mark.parametrize("shape", [(4, 6), (3, 4, 6)])
def test_frame_round_trip(shape: tuple[int, ...]) -> None:
    x = np.random.default_rng(0).random(shape, dtype=np.float32)
    last = to_channels_last(x, frame=True)
    assert last.shape == (4, 6, 1 if len(shape) == 2 else 3)
    np.testing.assert_array_equal(to_camera_layout(last, frame=True), x)


def test_wrong_shapes_name_the_parameter() -> None:
    with pytest.raises(
        InputError, match=r"^spikes must be \(T, H, W\) or \(T, 3, H, W\), found shape \(2, 4, 5, 6\)"
    ):
        to_channels_last(np.zeros((2, 4, 5, 6)))
    with pytest.raises(InputError, match=r"^start_accumulator must be \(H, W\) or \(3, H, W\)"):
        to_channels_last(np.zeros((5, 6, 1)), frame=True, name="start_accumulator")
    with pytest.raises(
        InputError, match=r"^spikes must be \(T, H, W, C\) with C = 1 or 3, found shape \(2, 4, 5, 2\)"
    ):
        to_camera_layout(np.zeros((2, 4, 5, 2)))


def test_no_other_module_reorders_channel_axes() -> None:
    """Spike streams and frames change layout only in ``camera/layout.py`` (the list says why the rest do)."""
    shuffle = re.compile(r"\.(transpose|permute)\((\d, ){2,3}\d\)|\b(moveaxis|movedim)\(")
    found = []
    for path in sorted(SRC.rglob("*.py")):
        rel = path.relative_to(SRC).as_posix()
        if rel in OTHER_LAYOUTS:
            continue
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if shuffle.search(line):
                found.append(f"{rel}:{n}: {line.strip()}")
    assert not found, (
        "use spikenerf.camera.layout (or list the module in OTHER_LAYOUTS with why):\n" + "\n".join(found)
    )
