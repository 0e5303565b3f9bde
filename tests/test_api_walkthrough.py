"""Findings of a researcher's walk through the Python API (docs/python-api.md and beyond): runs trained from
Python reload from anywhere, argument errors name the Python parameter, and values the camera, the
reconstructions and the losses would read wrongly are refused or read as the docs say."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

import test_train
from spikenerf.core.errors import InputError
from spikenerf.data.dataset import load_dataset
from spikenerf.scenes.trajectory import Intrinsics
from spikenerf.train.config import TrainConfig
from spikenerf.train.run import load_run
from spikenerf.train.trainer import train

dataset_dir = test_train.dataset_dir  # the module's fixture (16×16 analytic-orbs)
TINY = {"n_voxels_init": 8**3, "n_voxels_final": 12**3}


def _error(call, *params: str, match: str | None = None) -> InputError:  # type: ignore[no-untyped-def]
    with pytest.raises(InputError, match=match) as err:
        call()
    assert err.value.params == params, (err.value.params, str(err.value))
    return err.value


def _config(dataset: object = "", **kw) -> TrainConfig:  # type: ignore[no-untyped-def]
    kw = {"method": "nerf-gt", "iters": 2, "batch": 32, "eval_every": 0, "device": "cpu", **kw}
    return TrainConfig(dataset=dataset, field_config=dict(TINY), **kw)  # type: ignore[arg-type]


# --- train/trainer.py, train/run.py -----------------------------------------------------------------------


def test_a_run_trained_from_python_records_its_dataset_and_reloads_from_anywhere(
    dataset_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``train`` kept ``config.dataset`` as given: a relative path (or a ``dataset=`` object's folder not
    recorded at all) made ``load_run`` say "the run's data folder ... is not there any more" from any other
    folder; a ``Path`` was refused ("dataset must be a string")."""
    monkeypatch.chdir(dataset_dir.parent)
    train(_config(Path(dataset_dir.name)), tmp_path / "relative", progress=False)  # a relative Path
    stored = yaml.safe_load((tmp_path / "relative" / "config.yaml").read_text())["dataset"]
    assert stored == str(dataset_dir.resolve())
    train(_config(), tmp_path / "given", dataset=load_dataset(dataset_dir), progress=False)
    monkeypatch.chdir(tmp_path)
    for run in ("relative", "given"):
        assert load_run(tmp_path / run)[2].root.resolve() == dataset_dir.resolve()
    train(_config(Path(dataset_dir)), tmp_path / "relative", resume=True, progress=False)  # same folder
    other = tmp_path / "elsewhere"
    other.mkdir()
    _error(
        lambda: train(_config(str(other)), tmp_path / "both", dataset=load_dataset(dataset_dir)),
        "dataset",
        "config.dataset",
        match="config.dataset names .* but the dataset given was loaded from",
    )
    assert not (tmp_path / "both").exists()


def test_load_run_names_its_own_parameter_for_a_moved_dataset(dataset_dir: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    train(_config(str(dataset_dir)), run, progress=False)
    config = run / "config.yaml"
    config.write_text(config.read_text().replace(str(dataset_dir.resolve()), str(tmp_path / "gone")))
    err = _error(lambda: load_run(run), "dataset_root", match="give its new folder with dataset_root")
    assert "--" not in err.message
    assert load_run(run, dataset_root=dataset_dir)[2].root == dataset_dir


# --- scenes -----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "param"),
    [
        ({"fl_x": float("nan")}, "fl_x"),  # rendered an all-white image
        ({"fl_y": 0.0}, "fl_y"),
        ({"cx": float("inf")}, "cx"),
        ({"width": 24.0}, "width"),  # a deep torch error (meshgrid dtypes)
        ({"height": 0}, "height"),
        ({"width": -4}, "width"),
    ],
)
def test_intrinsics_check_their_fields(kwargs: dict, param: str) -> None:
    values = {"width": 24, "height": 24, "fl_x": 20.0, "fl_y": 20.0, "cx": 12.0, "cy": 12.0, **kwargs}
    _error(lambda: Intrinsics(**values), param, match=f"^{param} must be")
    Intrinsics(np.int64(24), 24, np.float32(20), 20.0, 12, 12.0)  # numpy numbers and integer centres are fine


def test_negative_float_pixels_are_no_light_before_resampling(tmp_path: Path) -> None:
    """docs/sequence.md: negative .npy values become 0; they were kept and darkened a downscaled pixel
    (−0.3, −0.01, 0.5, 0.5 averaged to 0.1725, not 0.25)."""
    from spikenerf.scenes.sequence import SequenceSource

    frame = np.full((8, 8, 3), 0.5, np.float32)
    frame[0, 0], frame[0, 1] = -0.3, -0.01
    pose = np.eye(4)
    pose[2, 3] = 4.0
    for i in range(2):
        np.save(tmp_path / f"f{i}.npy", frame)
    meta = {
        "fl_x": 8.0,
        "frames": [{"file_path": f"f{i}.npy", "transform_matrix": pose.tolist()} for i in range(2)],
    }
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    native = next(iter(SequenceSource(tmp_path / "transforms.json").frames([0])))
    assert native.min() == 0.0 and native[0, 0].tolist() == [0.0, 0.0, 0.0]
    half = next(iter(SequenceSource(tmp_path / "transforms.json", width=4).frames([0])))
    assert half[0, 0] == pytest.approx(0.25, abs=1e-6)
    for bad, message in [(np.full((4, 4), 1e39), "beyond float32's range"), (np.full((4, 4), np.nan), "NaN")]:
        from spikenerf.scenes.image_io import to_linear_rgba

        _error(lambda bad=bad: to_linear_rgba(bad, "x.npy"), match=message)


def test_sequence_arguments_name_their_python_parameter(tmp_path: Path) -> None:
    from spikenerf.scenes.sequence import SequenceSource

    pose = np.eye(4)
    pose[2, 3] = 4.0
    frames = [{"file_path": f"f{i}.npy", "transform_matrix": pose.tolist()} for i in range(6)]
    for i in range(6):
        np.save(tmp_path / f"f{i}.npy", np.full((4, 4), 0.5, np.float32))
    path = tmp_path / "transforms.json"
    path.write_text(json.dumps({"fl_x": 4.0, "frames": frames}))
    assert SequenceSource(path, frame_range="1:4").frame_indices.tolist() == [1, 2, 3]  # as the CLI takes it
    _error(lambda: SequenceSource(path, frame_range=(5, 2)), "frame_range", match="frame_range '5:2'")
    _error(lambda: SequenceSource(path, frame_range=(1, 2, 3)), "frame_range", match="must be a slice")
    _error(lambda: SequenceSource(path, frame_range=slice(0, 6, 2)), "frame_range", match="a step")
    _error(lambda: SequenceSource(path, frame_range="0-5"), "frame_range", match="expected A:B")
    _error(lambda: SequenceSource(path, steps_per_frame=0), "steps_per_frame")


# --- recon ------------------------------------------------------------------------------------------------


def test_the_learned_reconstruction_reads_spikes_as_tfp_does() -> None:
    """0/255 frames gave intensities 255× too high and 0.5-valued "spikes" about 0; ``mode="RGB"`` blamed
    the weights file."""
    from spikenerf.camera import simulate
    from spikenerf.recon.infer import reconstruct_learned

    ramp = np.tile(np.linspace(0.1, 0.9, 16, dtype=np.float32), (8, 1))
    spikes = simulate([ramp] * 50, height=8, width=16)
    one = reconstruct_learned(spikes, frames=25)
    np.testing.assert_array_equal(reconstruct_learned(spikes.astype(np.uint8) * 255, frames=25), one)
    _error(lambda: reconstruct_learned(spikes * 0.5, frames=25), "spikes", match="0/1")
    _error(lambda: reconstruct_learned(spikes, "RGB"), "mode", match="mode must be one of gray, rgb, bayer")
    _error(lambda: reconstruct_learned(spikes, "rgb"), "spikes", "mode", match=r"\(T, 3, H, W\)")
    _error(lambda: reconstruct_learned(spikes[0]), "spikes", match="one frame")


# --- train/losses.py --------------------------------------------------------------------------------------


def test_spike_losses_read_spikes_as_tfp_does_and_name_bad_arguments() -> None:
    from spikenerf.train.losses import paper_spike_loss, spike_interval_loss, window_mean_loss

    rng = np.random.default_rng(0)
    spikes = rng.random((16, 20, 1)) < 0.4
    intensity = torch.rand(16, 20, 1)
    loss = spike_interval_loss(intensity, spikes, 1.0)
    torch.testing.assert_close(spike_interval_loss(intensity, spikes.astype(np.uint8) * 255, 1.0), loss)
    _error(lambda: spike_interval_loss(intensity, spikes * 0.5, 1.0), "spikes", match="0/1")
    _error(lambda: spike_interval_loss(intensity, spikes, torch.tensor(0.0)), "threshold")
    _error(lambda: spike_interval_loss(intensity, spikes, 1.0, max_intensity="1"), "max_intensity")  # type: ignore[arg-type]
    _error(lambda: spike_interval_loss(intensity.numpy(), spikes, 1.0), "intensity", match="torch tensor")  # type: ignore[arg-type]
    band = torch.full((8, 1), -1.0)
    _error(lambda: window_mean_loss(torch.full((8, 1, 1), 0.6), torch.full((8, 1), 0.5), band), "band")
    near = window_mean_loss(torch.full((8, 1, 1), 0.6), np.full((8, 1), 0.5), torch.full((8, 1), 0.05))
    assert float(near) == pytest.approx(0.05**2)  # a numpy target is read; beyond the band by 0.05
    _error(lambda: paper_spike_loss(intensity, spikes, 1.0, torch.rand(3)), "start_accumulator")
    _error(lambda: paper_spike_loss(intensity, spikes, 0.0, torch.rand(20, 1)), "threshold")


def test_a_hand_made_trajectory_is_checked_before_anything_is_rendered(tmp_path: Path) -> None:
    """Lengths that differ failed in the writer after every frame was rendered; reversed steps or a
    negative fps wrote a dataset its own loader refused."""
    from spikenerf.capture import SimulateOptions, simulate_dataset
    from spikenerf.scenes import make_scene_source
    from spikenerf.scenes.trajectory import Trajectory, orbit

    o = orbit(4.0, 30.0, duration=16 / 40000)
    for bad, match in [
        (Trajectory(o.poses, o.times[:10], o.steps, o.fps), "must be"),
        (Trajectory(o.poses, o.times, o.steps[::-1].copy(), o.fps), "increasing integers"),
        (Trajectory(o.poses, o.times, o.steps.astype(float), o.fps), "increasing integers"),
        (Trajectory(o.poses, o.times, o.steps, -5.0), "fps must be"),
        (Trajectory(o.poses, np.zeros(len(o)), o.steps, o.fps), "times must increase"),
    ]:
        _error(
            lambda bad=bad: make_scene_source("analytic-orbs", 8, 8, bad, None, spp=1),
            "trajectory",
            match=match,
        )
    source = make_scene_source("analytic-orbs", 8, 8, o, None, spp=1)
    object.__setattr__(source, "trajectory", Trajectory(o.poses, o.times, o.steps, 0.0))  # changed after
    _error(
        lambda: simulate_dataset(source, tmp_path / "ds", SimulateOptions(), progress=False),
        "source.trajectory",
    )
    assert not (tmp_path / "ds").exists()


def test_metrics_refuse_8_bit_images_on_the_unit_range_and_name_their_arguments() -> None:
    """``psnr`` of uint8 images gave −21.8 dB with no word (``ssim`` a plausible 0.986)."""
    from spikenerf.eval.metrics import psnr, ssim

    a = torch.rand(3, 16, 16)
    b = (a + 0.05 * torch.randn(3, 16, 16)).clamp(0, 1)
    a8, b8 = (a * 255).round().byte(), (b * 255).round().byte()
    _error(lambda: psnr(a8, b8), "a", match="convert 8-bit images")
    _error(lambda: ssim(a8, b8), "a", match="convert 8-bit images")
    assert float(psnr(a8, b8, data_range=255)) == pytest.approx(
        float(psnr(a8.double() / 255, b8.double() / 255))
    )
    _error(lambda: psnr(a, b, data_range=0), "data_range")
    _error(lambda: psnr(a, b[:, :8]), "a", "b", match="shapes differ")
    _error(lambda: psnr(a[0], b[0]), "a", "b", match=r"\(N,C,H,W\) or \(C,H,W\)")
    assert float(psnr(a.numpy(), b.numpy())) == pytest.approx(float(psnr(a, b)))  # arrays are read


def test_spike_rendering_checks_pixels_start_and_trajectories() -> None:
    from spikenerf.fields import GridFieldConfig
    from spikenerf.render import build_model, render_spike_stream, render_spike_window
    from spikenerf.render.spiking import iter_spike_states
    from spikenerf.scenes.trajectory import orbit

    box = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    model = build_model("grid", 3, box, GridFieldConfig(n_voxels_init=8**3, n_voxels_final=8**3))
    k = Intrinsics(8, 8, 8.0, 8.0, 4.0, 4.0)
    path = orbit(4.0, 30.0, duration=3 / 40000)
    poses = path.poses
    pixels = torch.tensor([[1, 2], [3, 4], [5, 6]])
    start = torch.zeros(3, 3)
    render_spike_window(model, poses, k, pixels, start)  # valid
    _error(
        lambda: render_spike_window(model, poses, k, torch.tensor([[8, 0]]), start[:1]),
        "pixels",
        match="lie in",
    )
    _error(lambda: render_spike_window(model, poses, k, pixels.float(), start), "pixels", match="integer")
    _error(lambda: render_spike_window(model, poses, k, pixels, torch.zeros(3)), "start_accumulator")
    _error(lambda: render_spike_window(model, poses, k, pixels, start, threshold=0.0), "threshold")
    _error(lambda: render_spike_stream(model, path, k), "poses", match=r"trajectory\.poses")  # type: ignore[arg-type]
    nan = torch.full((3, 8, 8), float("nan"))
    _error(
        lambda: iter_spike_states(model, poses, k, start_accumulator=nan), "start_accumulator", match="NaN"
    )


def test_evaluate_run_checks_its_log_function(tmp_path: Path) -> None:
    from spikenerf.eval.evaluate import evaluate_run

    _error(lambda: evaluate_run(tmp_path / "no-run", log="x"), "log")  # type: ignore[arg-type]
    assert not (tmp_path / "no-run").exists()


def test_a_frame_beyond_float32_is_named_as_such() -> None:
    from spikenerf.camera import simulate

    _error(lambda: simulate([np.full((8, 8), 1e39)] * 3, 8, 8), "intensity", match="beyond float32")
