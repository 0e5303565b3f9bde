"""Edge inputs of the public API: a wrong type or shape is an ``InputError`` naming the parameter, not an
AttributeError or a silent wrong answer; and the selections that ``tfp`` takes, the others take too."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

import spikenerf
from spikenerf.camera.dat_codec import frame_bytes
from spikenerf.camera.reconstruct import tfp
from spikenerf.camera.simulation import simulate
from spikenerf.core.color import rgb_to_gray
from spikenerf.core.errors import InputError
from spikenerf.core.psnr import mse_to_psnr
from spikenerf.recon.infer import reconstruct_learned
from spikenerf.scenes.trajectory import orbit


def test_wrong_types_and_shapes_are_input_errors_naming_the_parameter() -> None:
    frames = np.ones((2, 4, 4), np.float32)
    with pytest.raises(InputError, match="CameraConfig") as err:
        simulate(frames, 4, 4, config="rgb")  # type: ignore[arg-type]
    assert err.value.params == ("config",)
    with pytest.raises(InputError, match="positive integers") as err:
        frame_bytes(4.0, 16)  # type: ignore[arg-type]
    assert err.value.params == ("height", "width")
    with pytest.raises(InputError, match="3 colour channels") as err:
        rgb_to_gray(np.ones((4, 2, 2)))
    assert err.value.params == ("rgb",)
    assert rgb_to_gray(torch.ones(2, 2, 3), channel_axis=-1).shape == (2, 2)
    for bad in ({"radius": math.nan}, {"duration": math.inf}, {"fps": math.nan}):
        with pytest.raises(InputError, match="must be finite"):
            orbit(**{"radius": 4.0, "elevation_deg": 30.0, **bad})


def test_psnr_of_numbers_of_any_kind_and_of_tensors_agree() -> None:
    assert mse_to_psnr(np.float32(0.01)) == pytest.approx(20.0, abs=1e-5)
    assert mse_to_psnr(0) == math.inf and math.isnan(mse_to_psnr(-1.0)) and math.isnan(mse_to_psnr(math.nan))
    assert torch.isnan(mse_to_psnr(torch.tensor([-1.0])))[0]


def test_the_learned_reconstruction_selects_frames_as_tfp_does() -> None:
    spikes = np.random.default_rng(0).random((60, 16, 16)) < 0.3
    for frames in (5, slice(10, 14), -1):
        assert reconstruct_learned(spikes, frames=frames).shape == tfp(spikes, frames=frames).shape
    with pytest.raises(InputError, match="outside"):
        reconstruct_learned(spikes, frames=60)


def test_dir_lists_the_packages_own_names_too() -> None:
    names = dir(spikenerf)
    assert "__version__" in names and "simulate" in names and names == sorted(names)
