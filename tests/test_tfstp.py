"""TFSTP (texture from short-term plasticity): calibration, shapes, parameters, frame subsets, the CLI."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from helpers import run_cli
from spikenerf.camera.firing import fire
from spikenerf.camera.io import write_dat
from spikenerf.camera.reconstruct import reconstruct_frames, tfi, tfp
from spikenerf.camera.tfstp import tfstp
from spikenerf.core.errors import InputError


def _constant(levels: list[float], steps: int = 400, rows: int = 3, seed: int = 0) -> np.ndarray:
    """An ideal camera over a (len(levels), rows) image of constant intensities (one level a row), random
    initial accumulators: bool (steps, L, rows)."""
    rng = np.random.default_rng(seed)
    intensity = np.repeat(np.asarray(levels, np.float64)[:, None], rows, axis=1)
    acc, out = rng.uniform(0.0, 1.0, intensity.shape), []
    for _ in range(steps):
        spikes, acc = fire(acc, intensity)
        out.append(spikes)
    return np.array(out)


def test_smoke_values_lie_in_zero_to_phi() -> None:
    spikes = np.random.default_rng(0).random((60, 5, 7)) < 0.3
    image = tfstp(spikes, threshold=2.0)
    assert image.shape == (60, 5, 7) and image.dtype == np.float32
    assert np.isfinite(image).all() and image.min() > 0 and image.max() <= 2.0 + 1e-6
    assert not np.array_equal(image, tfi(spikes, 2.0))  # its own estimate, not TFI's


@pytest.mark.parametrize("period", [1, 2, 3, 7, 25])
def test_periodic_firing_is_exact_at_every_frame(period: int) -> None:
    """The steady-state inversion: a pixel firing every m steps reads φ/m, edges included."""
    spikes = np.zeros((200, 2, 2), np.uint8)
    for phase in range(min(period, 4)):
        spikes[phase::period, phase % 2, phase // 2] = 1
    image = tfstp(spikes, threshold=1.5)
    fired = spikes.any(axis=0)
    np.testing.assert_allclose(image[:, fired], 1.5 / period, rtol=1e-5)


def test_constant_intensities_are_calibrated() -> None:
    """An ideal camera over constant intensities (non-integer periods included): the mean over the frames
    is the intensity within 3 % (the STP state mixes neighbouring intervals of ⌊1/I⌋ and ⌈1/I⌉ steps)."""
    levels = [0.02, 0.05, 0.13, 0.3, 0.37, 0.5, 0.7, 0.9]
    image = tfstp(_constant(levels))
    means = image.mean(axis=(0, 2))
    np.testing.assert_allclose(means, levels, rtol=0.03)
    assert np.abs(means / levels - 1).max() > 1e-4  # not TFI's exact frame-weighted mean: the check bites


def test_a_silent_pixel_is_zero_and_shapes_follow_the_stream() -> None:
    spikes = np.random.default_rng(1).random((40, 3, 4, 5)) < 0.2
    spikes[:, 1, 2, 3] = False
    rgb = tfstp(spikes)
    assert rgb.shape == (40, 3, 4, 5) and (rgb[:, 1, 2, 3] == 0).all()
    np.testing.assert_array_equal(rgb[:, 2], tfstp(spikes[:, 2]))  # channels are independent
    tensor = tfstp(torch.from_numpy(spikes.astype(np.float32)))
    assert isinstance(tensor, torch.Tensor) and torch.equal(tensor, torch.from_numpy(rgb))
    for bad in (spikes[0, 0], spikes.transpose(0, 2, 3, 1)):  # one frame; channels last
        with pytest.raises(InputError) as err:
            tfstp(bad)
        assert err.value.params == ("spikes",)


@pytest.mark.parametrize(
    ("kwargs", "param"),
    [({"u0": 0.0}, "u0"), ({"u0": 1.0}, "u0"), ({"f": -0.1}, "f"), ({"f": "0.2"}, "f"), ({"D": 0}, "D"),
     ({"D": float("inf")}, "D"), ({"F": -1.0}, "F"), ({"F": None}, "F"), ({"threshold": 0}, "threshold")],
)  # fmt: skip
def test_bad_parameters_name_themselves(kwargs: dict, param: str) -> None:
    with pytest.raises(InputError) as err:
        tfstp(np.zeros((5, 2, 2), bool), **kwargs)
    assert err.value.params == (param,)


def test_frame_subsets_and_readers_equal_the_whole_run() -> None:
    spikes = np.random.default_rng(2).random((300, 4, 6)) < 0.08
    spikes[:, 0, 0] = False  # a silent pixel: the reader must reach the stream's end
    full = tfstp(spikes, u0=0.2, F=5.0)
    np.testing.assert_array_equal(tfstp(spikes, frames=slice(10, 250, 9), u0=0.2, F=5.0), full[10:250:9])
    np.testing.assert_array_equal(tfstp(spikes, frames=299, u0=0.2, F=5.0), full[299:])
    full = tfstp(spikes)
    reads: list[tuple[int, int]] = []
    read = lambda a, b: reads.append((a, b)) or spikes[a:b]  # noqa: E731
    np.testing.assert_array_equal(reconstruct_frames(read, 300, 40, 90, "tfstp", step=3), full[40:90:3])
    assert reads[-1][0] == 0  # the state carries the history: read from frame 0


def test_cli_reconstruct_method_tfstp(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    spikes = np.random.default_rng(3).random((120, 6, 8)) < 0.25
    path = tmp_path / "rec.dat"
    write_dat(path, spikes)
    base = ["reconstruct", path, "--height", 6, "--width", 8, "--method", "tfstp"]
    code, stdout, err = run_cli(
        capsys, *base, "--frames", "10:100", "--stride", 7, "--out", tmp_path / "r.npy"
    )
    assert code == 0, err
    assert "(13 frames, tfstp)" in stdout
    np.testing.assert_array_equal(np.load(tmp_path / "r.npy"), tfstp(spikes)[10:100:7])
    assert run_cli(capsys, *base, "--frame", 5, "--out", tmp_path / "f.png")[0] == 0
    assert (tmp_path / "f.png").stat().st_size > 0
    code, _, err = run_cli(capsys, *base, "--window", 21, "--out", tmp_path / "w.npy")
    assert code == 2 and "--window applies to --method tfp and learned (tfstp" in err
    assert not (tmp_path / "w.npy").exists()


def test_the_state_reaches_past_a_holdout_band_unless_the_hold_out_cuts_it() -> None:
    """Spikes inside a held-out band change TFSTP targets of the whole stream beyond the default guard
    radius after it (the state carries the history): the hold-out therefore reconstructs the stream cut at
    the bands' edges, and docs/metrics.md says so beside TFI."""
    from spikenerf.data.holdout import Holdout, guard_radius
    from spikenerf.data.reconstruction import reconstruct_cut

    rng = np.random.default_rng(4)
    spikes = rng.random((400, 8, 8)) < 0.1
    changed = spikes.copy()
    changed[150:171] = rng.random((21, 8, 8)) < 0.5  # a band's spikes (centre 160, radius 10)
    after = 170 + guard_radius(41, 5, 1)  # a training target past the default band of a TFP window 41
    assert np.abs(tfstp(spikes)[after] - tfstp(changed)[after]).max() > 1e-3
    assert np.array_equal(tfi(spikes)[after + 40 :], tfi(changed)[after + 40 :])  # TFI forgets at a spike
    hold = Holdout(np.array([160]), radius=10, total=400, source="test", recon="tfstp")
    outside = ~hold.band()
    for recon in ("tfstp", "tfi"):
        cut = [reconstruct_cut(s, recon, 41, 1.0, hold.cuts())[outside] for s in (spikes, changed)]
        np.testing.assert_array_equal(cut[0], cut[1])
    page = (Path(__file__).resolve().parents[1] / "docs" / "metrics.md").read_text(encoding="utf-8")
    held = " ".join(page.split("**Held-out steps.**", 1)[1].split()[:400])
    assert "`--recon tfstp`" in held and "cut" in held


def test_an_index_list_is_one_scan_equal_to_the_whole_run() -> None:
    """Scattered frames (recon-eval's GT steps) in one call: the same values as the whole run there (and
    likewise TFP, TFI and the masks, which share the frame selection)."""
    from spikenerf.camera.masks import spike_masks

    spikes = np.random.default_rng(4).random((200, 3, 5)) < 0.1
    full = tfstp(spikes, 0.5)
    idx = np.array([0, 7, 8, 120, 199])
    np.testing.assert_array_equal(tfstp(spikes, 0.5, idx), full[idx])
    np.testing.assert_array_equal(tfstp(spikes, 0.5, [7, 120]), full[[7, 120]])
    np.testing.assert_array_equal(spike_masks(spikes, 2, idx), spike_masks(spikes, 2)[idx])
    np.testing.assert_array_equal(tfp(spikes, 9, 0.5, idx), tfp(spikes, 9, 0.5)[idx])
    np.testing.assert_array_equal(tfi(spikes, 0.5, idx), tfi(spikes, 0.5)[idx])
