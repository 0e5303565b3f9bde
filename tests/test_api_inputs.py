"""Library-level input checks: bad input to the camera, .dat I/O, renderers, targets and scenes is an
InputError that names the Python parameter (``param=``), raised before any work, and valid input keeps its
results."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from spikenerf.camera.io import read_dat, read_dat_rgb, write_dat, write_dat_rgb
from spikenerf.camera.masks import spike_masks
from spikenerf.camera.model import CameraConfig, SpikeCamera
from spikenerf.camera.reconstruct import reconstruct_frames, tfi, tfp, window_sum
from spikenerf.camera.simulation import simulate, simulate_iter
from spikenerf.capture.options import SimulateOptions
from spikenerf.capture.simulate import simulate_dataset
from spikenerf.core.errors import InputError
from spikenerf.data.dataset import load_dataset
from spikenerf.data.rays import as_poses
from spikenerf.data.targets import build_spike_targets, stream_targets
from spikenerf.fields import GridFieldConfig
from spikenerf.render import build_model, iter_spike_states, render_image, render_spike_stream
from spikenerf.render.model import check_poses, render_mean
from spikenerf.scenes.analytic import AnalyticSource
from spikenerf.scenes.registry import make_scene_source
from spikenerf.scenes.trajectory import Intrinsics, novel_views, orbit

RNG = np.random.default_rng(0)
SPIKES = RNG.random((12, 4, 5)) < 0.4  # (T, H, W)
RGB_SPIKES = RNG.random((12, 3, 4, 5)) < 0.4  # (T, 3, H, W)


def _params(call, *params: str, match: str | None = None) -> InputError:  # type: ignore[no-untyped-def]
    """The InputError of ``call()``, checked to list ``params`` and to name the first in its message."""
    with pytest.raises(InputError, match=match) as err:
        call()
    assert err.value.params == params, (err.value.params, str(err.value))
    assert params[0] in err.value.message
    return err.value


# --- camera/reconstruct.py, camera/masks.py ----------------------------------------------------------------


@pytest.mark.parametrize("recon", [tfp, tfi, spike_masks, lambda s: window_sum(s, 1)])
def test_a_stream_must_be_in_the_camera_layout(recon) -> None:  # type: ignore[no-untyped-def]
    _params(lambda: recon(SPIKES[0]), "spikes", match=r"one frame\?")  # (H, W): was read as T = H
    channels_last = np.moveaxis(RGB_SPIKES, 1, -1)  # (T, H, W, 3)
    _params(lambda: recon(channels_last), "spikes", match=r"channels last\?")
    _params(lambda: recon(SPIKES[..., None, None]), "spikes")  # 5-D
    recon(SPIKES), recon(RGB_SPIKES), recon(torch.from_numpy(SPIKES))  # the valid layouts still work


def test_float_spikes_must_be_zero_or_one() -> None:
    for recon in (tfp, tfi, spike_masks):
        _params(lambda r=recon: r(np.full((6, 2, 2), 0.3)), "spikes", match=r"0/1.*0\.3")
        _params(lambda r=recon: r(torch.full((6, 2, 2), 0.5)), "spikes", match=r"0\.5")
        as_float = SPIKES.astype(np.float32)  # 0.0 / 1.0 floats are spikes: the same results as bool
        np.testing.assert_array_equal(recon(as_float), recon(SPIKES))
    counts = SPIKES.astype(np.uint8) * 3  # integers: any non-zero is a spike (documented, not checked)
    np.testing.assert_array_equal(tfp(counts, 3), tfp(SPIKES, 3))


@pytest.mark.parametrize("threshold", ["1", None, [1.0, 2.0]])
def test_a_threshold_that_is_not_a_number_is_an_input_error(threshold) -> None:  # type: ignore[no-untyped-def]
    _params(lambda: tfp(SPIKES, threshold=threshold), "threshold")
    _params(lambda: tfi(SPIKES, threshold=threshold), "threshold")


def test_reconstruction_errors_list_their_parameter() -> None:
    _params(lambda: spike_masks(SPIKES, n=-1), "n")
    _params(lambda: tfp(SPIKES, frames=slice(0, 100)), "frames", match="empty or outside the 12-frame")
    _params(lambda: tfi(SPIKES, frames=99), "frames", match="frame 99 is outside")
    _params(lambda: spike_masks(SPIKES, frames="0:3"), "frames")
    read = lambda a, b: SPIKES[a:b]  # noqa: E731
    _params(
        lambda: reconstruct_frames(read, 12, 5, 5), "start", "stop", match="0 <= start < stop <= total = 12"
    )
    np.testing.assert_array_equal(reconstruct_frames(read, 12, 2, 5, "tfp", 3), tfp(SPIKES, 3)[2:5])


# --- camera/model.py ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf, -5.0])
@pytest.mark.parametrize("device", [None, "cpu"])
def test_camera_refuses_non_finite_or_negative_intensity(bad: float, device: str | None) -> None:
    """Found in the accumulator (a NaN silenced its pixel for good): by ``simulate``'s end, by ``step`` every
    CHECK_EVERY steps, or by ``check``; not by a pass over each step's input (the simulator's speed)."""
    from spikenerf.camera.model import CHECK_EVERY

    frame = np.full((4, 4), 0.5, np.float32)
    bad_frame = frame.copy()
    bad_frame[1, 2] = bad
    for frames in ([bad_frame], [frame, bad_frame, frame], [torch.from_numpy(bad_frame)]):
        _params(lambda frames=frames: simulate(frames, 4, 4, device=device), "intensity", match="steps 0..")
    camera = SpikeCamera(4, 4, device=device)
    camera.step(bad_frame)
    _params(camera.check, "intensity")
    camera = SpikeCamera(4, 4, device=device)
    for _ in range(CHECK_EVERY - 2):
        camera.step(frame)
    camera.step(bad_frame)
    _params(lambda: camera.step(frame), "intensity", match=f"steps 0..{CHECK_EVERY - 1}")
    camera = SpikeCamera(4, 4, device=device)
    for _ in range(CHECK_EVERY):
        camera.step(frame)
    camera.check()  # a clean stream passes
    for _ in range(CHECK_EVERY + 35):  # the NaN at step 163: after the checks at 64 and 128
        camera.step(frame)
    camera.step(bad_frame)
    _params(camera.check, "intensity", match=rf"steps {2 * CHECK_EVERY}\.\.{3 * CHECK_EVERY - 29}")
    with pytest.raises(InputError, match=r"steps 0\.\.2"):  # simulate_iter checks at its end too
        list(simulate_iter([frame, bad_frame, frame], 4, 4, device=device))


def test_camera_refuses_an_8_bit_image_and_takes_0_1_integers() -> None:
    camera = SpikeCamera(4, 4, CameraConfig(color="rgb"))
    _params(lambda: camera.step(np.full((3, 4, 4), 200, np.uint8)), "intensity", match=r"8-bit.*\[0, 1\]")
    _params(lambda: camera.step(torch.full((3, 4, 4), 255, dtype=torch.uint8)), "intensity")
    ones = SpikeCamera(4, 4, CameraConfig(color="rgb")).step(np.ones((3, 4, 4), np.int64))
    assert ones.all()  # integer 0/1 (white) is linear radiance: every pixel fires
    assert SpikeCamera(4, 4).step(np.full((4, 4), 7.5, np.float32)).all()  # float > 1: saturates (allowed)


def test_camera_takes_numpy_views_with_negative_strides_on_torch() -> None:
    frames = RNG.random((6, 5, 4), dtype=np.float32)
    on_numpy, on_torch = SpikeCamera(5, 4), SpikeCamera(5, 4, device="cpu")
    for f in frames:
        view = f[::-1, ::-1]  # negative strides: torch.from_numpy refused it
        np.testing.assert_array_equal(on_torch.step(view).numpy(), on_numpy.step(view))


def test_camera_shape_errors_list_their_parameter() -> None:
    camera = SpikeCamera(4, 4, CameraConfig(color="rgb"))
    _params(lambda: camera.step(np.ones((5, 4))), "intensity")
    _params(lambda: camera.step(np.ones((2, 2, 4, 4))), "intensity", match="sub-frames")
    _params(lambda: camera.step(np.ones((4, 4))), "intensity", match="needs RGB intensity")
    _params(lambda: camera.step(np.ones((3, 4, 4)), out=np.zeros((4, 4), bool)), "out")


# --- camera/io.py ------------------------------------------------------------------------------------------


def test_write_dat_rgb_drops_a_dat_suffix_and_takes_array_likes(tmp_path: Path) -> None:
    spikes = (RNG.random((3, 3, 4, 8)) < 0.5).astype(np.uint8)
    paths = write_dat_rgb(tmp_path / "rgb.dat", list(spikes))  # a list of (3, H, W) steps
    assert [p.name for p in paths] == ["rgb_r.dat", "rgb_g.dat", "rgb_b.dat"]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in paths)
    np.testing.assert_array_equal(read_dat_rgb(tmp_path / "rgb.dat", 4, 8), spikes)
    np.testing.assert_array_equal(read_dat_rgb(tmp_path / "rgb", 4, 8), spikes)
    ragged = [spikes[0], spikes[1, :, :2]]
    _params(lambda: write_dat_rgb(tmp_path / "bad", ragged), "spikes")
    _params(lambda: write_dat_rgb(tmp_path / "bad", spikes[:, :2]), "spikes", match=r"\(T, 3, H, W\)")


def test_read_dat_errors_list_their_parameter(tmp_path: Path) -> None:
    path = tmp_path / "a.dat"
    write_dat(path, np.zeros((2, 8, 8), bool))
    _params(lambda: read_dat(path, 8, 8, raw_width="16"), "raw_width")  # was a TypeError
    _params(lambda: read_dat(path, 8, 8, raw_width=4.5), "raw_width")
    _params(lambda: read_dat(path, 8, 8, frames=slice(0, 10)), "frames", match="empty or outside")
    _params(lambda: read_dat(path, 8, 8, frames="0:1"), "frames", match="must be a slice")
    _params(lambda: read_dat(path, 8, 8, frames=slice("a", None)), "frames")
    _params(lambda: read_dat(path, 8, 8, layout="x"), "layout")


# --- render/model.py, render/spiking.py, data/rays.py ------------------------------------------------------

INTR = Intrinsics.from_fov(6, 5, 0.9)
GRID = GridFieldConfig(n_voxels_init=8**3, n_voxels_final=8**3, upsample_steps=(), density_components=2,
                       app_components=2, app_dim=4, hidden=8)  # fmt: skip
POSES = orbit(4.0, 30.0, duration=3.0, fps=1.0).poses  # (3, 4, 4)


@pytest.fixture(scope="module")
def model():  # type: ignore[no-untyped-def]
    torch.manual_seed(0)
    return build_model("grid", 1, np.array([[-1.0] * 3, [1.0] * 3]), GRID)


def test_render_image_checks_its_pose_bounds_and_chunk(model) -> None:  # type: ignore[no-untyped-def]
    nan = POSES[0].copy()
    nan[0, 3] = np.nan
    _params(lambda: render_image(model, nan, INTR), "c2w", match="NaN")
    _params(lambda: render_image(model, torch.from_numpy(nan), INTR), "c2w", match="NaN")
    for shape in ((1, 4, 4), (2, 4, 4), (4, 3)):
        _params(lambda s=shape: render_image(model, np.zeros(s), INTR), "c2w", match=r"\(4, 4\)")
    _params(lambda: render_image(model, POSES[0], INTR, near=5.0, far=3.0), "near", "far")
    _params(lambda: render_image(model, POSES[0], INTR, near=float("nan")), "near")
    _params(lambda: render_image(model, POSES[0], INTR, chunk=-1), "chunk")
    _params(lambda: render_image(model, POSES[0], INTR, chunk=2.5), "chunk")
    auto = render_image(model, POSES[0], INTR, chunk=0).color  # 0 = automatic, as eval's --chunk 0
    torch.testing.assert_close(auto, render_image(model, POSES[0], INTR).color, rtol=0, atol=0)
    _params(lambda: render_mean(model, POSES[0], INTR), "poses", match=r"poses\[None\]")
    _params(lambda: render_mean(model, POSES[:0], INTR), "poses")
    mean = render_mean(model, POSES[::-1], INTR, chunk=0)  # a reversed view: negative strides
    torch.testing.assert_close(mean, render_mean(model, POSES[::-1].copy(), INTR), rtol=0, atol=0)
    listed = [torch.as_tensor(p) for p in POSES[::-1]]
    torch.testing.assert_close(mean, render_mean(model, listed, INTR), rtol=0, atol=0)

    class OnDevice(torch.Tensor):  # as a CUDA tensor: no numpy view (np.shape of a list of them raised)
        def __array__(self, *args: object, **kwargs: object) -> np.ndarray:
            raise TypeError("can't convert cuda:0 device type tensor to numpy")

    check_poses([p.as_subclass(OnDevice) for p in listed], "poses")
    _params(lambda: check_poses([listed[0], listed[0][:3]], "poses"), "poses", match="different shapes")


def test_as_poses_takes_negative_strides() -> None:
    np.testing.assert_array_equal(as_poses(POSES[::-1], "cpu").numpy(), POSES[::-1].astype(np.float32))


def test_spike_streams_check_threshold_poses_and_start(model) -> None:  # type: ignore[no-untyped-def]
    for phi in (0.0, -1.0, float("nan"), float("inf")):
        _params(lambda p=phi: render_spike_stream(model, POSES, INTR, threshold=p), "threshold")
        _params(lambda p=phi: iter_spike_states(model, POSES, INTR, threshold=p), "threshold")  # at the call
    _params(lambda: render_spike_stream(model, POSES[0], INTR), "poses", match=r"\(N, 4, 4\)")
    _params(lambda: iter_spike_states(model, POSES, INTR, chunk=-1), "chunk")
    start = np.full((5, 6), 0.25, np.float32)  # the camera layout (H, W) of a gray model
    from_numpy = render_spike_stream(model, POSES, INTR, start_accumulator=start)
    from_torch = render_spike_stream(model, POSES, INTR, start_accumulator=torch.from_numpy(start))
    assert torch.equal(from_numpy, from_torch) and from_numpy.shape == (3, 5, 6)
    wrong = np.zeros((6, 5), np.float32)
    _params(lambda: render_spike_stream(model, POSES, INTR, start_accumulator=wrong), "start_accumulator")


# --- data/targets.py, data/dataset.py ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    traj = orbit(4.0, 30.0, duration=16 / 40000)
    source = AnalyticSource("analytic-orbs", 8, 8, traj, novel_views(4.0, 1), supersample=1)
    out = tmp_path_factory.mktemp("data") / "tiny"
    options = SimulateOptions(colors=("gray",), gt_every=8, blur_fps=10000.0)
    return load_dataset(simulate_dataset(source, out, options, progress=False))


def test_given_spikes_must_fit_the_dataset(dataset) -> None:  # type: ignore[no-untyped-def]
    stream = dataset.spikes("gray")
    plain = stream_targets(dataset, "gray", window=3, spikes=stream)
    torch.testing.assert_close(plain.images, stream_targets(dataset, "gray", window=3).images)
    for bad in (stream[:-1], stream[:, None].repeat(3, axis=1), stream[:, :4]):
        _params(lambda b=bad: stream_targets(dataset, "gray", window=3, spikes=b), "spikes")
        _params(lambda b=bad: build_spike_targets(dataset, "gray", b), "spikes")
    _params(
        lambda: stream_targets(dataset, "rgb", window=3, spikes=stream), "spikes", match=r"\(T, 3, H, W\)"
    )


def test_a_missing_spike_mode_names_the_mode(dataset) -> None:  # type: ignore[no-untyped-def]
    _params(lambda: dataset.spikes("bayer"), "mode", match="'bayer' is not in this dataset")


# --- scenes/registry.py, scenes/trajectory.py --------------------------------------------------------------


def test_scene_source_checks_test_poses_up_front() -> None:
    traj = orbit(4.0, 30.0, duration=3.0, fps=1.0)
    _params(lambda: make_scene_source("analytic-orbs", 8, 8, traj, np.eye(4)), "test_poses")
    bad = np.eye(4)[None].repeat(2, 0)
    bad[1, 0, 0] = np.nan
    _params(lambda: make_scene_source("analytic-orbs", 8, 8, traj, bad), "test_poses", match="NaN")
    source = make_scene_source("analytic-orbs", 8, 8, traj, None)
    assert source.test_views()[0].shape == (0, 4, 4)


def test_orbit_errors_name_their_parameter() -> None:
    _params(lambda: orbit(-1.0, 30.0), "radius")
    _params(lambda: orbit(float("nan"), 30.0), "radius")
    _params(lambda: orbit(4.0, 30.0, fps=-5.0), "fps")
    _params(lambda: orbit(4.0, 30.0, duration=1e-9), "duration", "fps")
    _params(lambda: orbit(4.0, 100.0), "elevation_deg")  # (was ("elevation", "turns"): not its names)
    _params(lambda: orbit(4.0, 30.0, turns=1e9), "turns")


def test_a_threshold_must_be_one_number() -> None:
    """``CameraConfig(threshold=[2.0])`` was accepted (numpy's isfinite takes a list) and kept the list."""
    for bad in ([2.0], np.array(2.0), np.array([2.0]), True, 1e-300):
        _params(lambda bad=bad: CameraConfig(threshold=bad), "threshold")
    assert CameraConfig(threshold=np.float32(2)).threshold == 2


def test_train_eval_and_loaders_name_a_wrong_argument(tmp_path: Path) -> None:
    """A dict config, a None folder, a path for the loaded dataset, ``stop_after=0`` (which left a run folder
    without a checkpoint) were AttributeErrors, TypeErrors or accepted; a Trainer made alone wrote into a
    dataset folder and destroyed it."""
    from spikenerf.core.marker import mark
    from spikenerf.data.dataset import load_dataset
    from spikenerf.eval.evaluate import evaluate_run
    from spikenerf.train.config import TrainConfig
    from spikenerf.train.run import load_run
    from spikenerf.train.trainer import Trainer, train

    config = TrainConfig(dataset=str(tmp_path / "ds"), iters=2, device="cpu")
    _params(lambda: train({"iters": 2}, tmp_path / "r"), "config")  # type: ignore[arg-type]
    _params(lambda: train(config, None), "out")  # type: ignore[arg-type]
    _params(lambda: train(config, tmp_path / "r", dataset=str(tmp_path)), "dataset")  # type: ignore[arg-type]
    _params(lambda: train(config, tmp_path / "r", stop_after=0), "stop_after")
    _params(lambda: load_run(None), "run_dir")  # type: ignore[arg-type]
    _params(lambda: load_dataset(""), "root")
    _params(lambda: evaluate_run(5), "run_dir")  # type: ignore[arg-type]
    # its own parameter names (were the CLI's: mode, test_pose_lr), checked before the run is opened
    missing = tmp_path / "no-run"
    _params(lambda: evaluate_run(missing, noref="yes"), "noref", match="noref must be one of auto, on, off")
    _params(lambda: evaluate_run(missing, test_pose=5), "test_pose")  # type: ignore[arg-type]
    _params(lambda: evaluate_run(missing, test_pose=(-1, 1e-3)), "test_pose", match="iterations must be")
    _params(lambda: evaluate_run(missing, test_pose=(2, 0.0)), "test_pose", match="learning rate must be")
    assert not missing.exists()
    (tmp_path / "ds").mkdir()
    mark(tmp_path / "ds", "dataset")
    _params(lambda: Trainer(config, tmp_path / "ds"), "out", match="this is a dataset folder")
    assert not (tmp_path / "r").exists() and [p.name for p in (tmp_path / "ds").iterdir()] == [".spikenerf"]


def test_numpy_scalars_in_a_train_config_are_numbers() -> None:
    """A sweep's values (``np.linspace``, ``np.arange``) in a TrainConfig were refused ("lr must be a
    number, found 0.001 (float32)"); they are the Python numbers they hold, also in what the run records."""
    import yaml

    from spikenerf.train.config import TrainConfig

    for lr in np.linspace(1e-3, 1e-2, 2, dtype=np.float32):
        config = TrainConfig(
            dataset="ds", lr=lr, iters=np.int64(100), field_config={"n_voxels_final": np.int64(8)}
        )
        config.integral.lengths = [np.int64(3)]
        config.validate()
        assert type(config.lr) is float and config.lr == float(lr) and type(config.iters) is int
        assert type(config.integral.lengths[0]) is int and type(config.field_config["n_voxels_final"]) is int
        yaml.safe_dump(config.to_dict())  # (a numpy scalar is no YAML the run could record)
    _params(lambda: TrainConfig(dataset="ds", lr=np.array([1e-3])).validate(), "lr")  # an array stays refused
    _params(lambda: TrainConfig(dataset="ds", iters=np.int64(-1)).validate(), "iters")  # and is still checked
