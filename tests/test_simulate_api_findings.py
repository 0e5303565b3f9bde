"""Findings of a walk through the simulation API: each bad argument is one InputError naming its parameter,
before any NaN pose, overflow, huge allocation or numpy error (scenes/, camera/)."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from spikenerf.camera.model import CameraConfig, SpikeCamera
from spikenerf.camera.noise import RealisticNoise
from spikenerf.camera.simulation import simulate, simulate_iter
from spikenerf.core.errors import InputError
from spikenerf.core.limits import NO_LIMITS_ENV
from spikenerf.scenes.analytic import AnalyticSource
from spikenerf.scenes.poses import look_at
from spikenerf.scenes.registry import make_scene_source
from spikenerf.scenes.trajectory import MAX_LENGTH, ORBIT_RADIUS, Trajectory, novel_views, orbit
from spikenerf.scenes.transforms import read_transforms

NAN, INF = math.nan, math.inf
SHORT = {"duration": 4e-4}  # 16 steps at 40 kHz


def _params(call: Callable[[], object], *params: str, match: str | None = None) -> InputError:
    """The InputError of ``call``: it names ``params`` (the first ones; check_memory adds no_limits)."""
    with pytest.raises(InputError, match=match) as err:
        call()
    assert err.value.params[: len(params)] == params, err.value.params
    return err.value


@pytest.fixture
def limits_on(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(NO_LIMITS_ENV, raising=False)


@pytest.fixture(scope="module")
def traj() -> Trajectory:
    return orbit(4.0, 30.0, duration=3.0, fps=1.0)


# --- A: orbit, novel_views, look_at -----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "param"),
    [({"start_azimuth_deg": NAN}, "start_azimuth_deg"), ({"start_azimuth_deg": 1e300}, "start_azimuth_deg"),
     ({"elevation_sweep_deg": INF}, "elevation_sweep_deg"), ({"center": (NAN, 0.0, 0.0)}, "center"),
     ({"center": (1e300, 0.0, 0.0)}, "center"), ({"shake": NAN}, "shake"), ({"shake": 1e308}, "shake"),
     ({"shake_cycles": INF}, "shake_cycles"), ({"jitter": NAN}, "jitter"), ({"jitter": 1e308}, "jitter"),
     ({"jitter": -1.0}, "jitter"), ({"seed": -1}, "seed"), ({"radius": 1e308}, "radius"),
     ({"radius": 1e-9}, "radius"), ({"radius": "4"}, "radius"), ({"elevation_deg": "30"}, "elevation_deg")],
)  # fmt: skip
def test_orbit_refuses_a_non_finite_or_out_of_range_argument(kwargs: dict, param: str) -> None:
    call = {"radius": 4.0, "elevation_deg": 30.0, **SHORT, **kwargs}
    _params(lambda: orbit(**call), param)


def test_orbit_at_the_ends_of_its_ranges_gives_finite_poses() -> None:
    for radius in ORBIT_RADIUS:
        edge = orbit(radius, 30.0, center=(MAX_LENGTH, -MAX_LENGTH, 0.0), start_azimuth_deg=-1e6, **SHORT)
        assert np.isfinite(edge.poses).all()
    rough = orbit(4.0, 30.0, jitter=MAX_LENGTH, shake=MAX_LENGTH, elevation_sweep_deg=360.0, **SHORT)
    assert np.isfinite(rough.poses).all()
    assert np.isfinite(orbit(4.0, 90.0, **SHORT).poses).all()  # ±90° stays accepted (every pose the same)


def test_orbit_refuses_more_steps_than_memory_holds(limits_on: None, monkeypatch: pytest.MonkeyPatch) -> None:
    _params(lambda: orbit(4.0, 30.0, duration=1e5), "duration", "fps", match="memory")  # ~4 TiB
    monkeypatch.setenv(NO_LIMITS_ENV, "1")  # beyond any machine: refused even without limits
    _params(lambda: orbit(4.0, 30.0, duration=1.0, fps=1e300), "duration", "fps", match="at most")
    _params(lambda: orbit(4.0, 30.0, duration=1.0, fps=NAN), "fps", match="must be finite")


def test_novel_views_and_look_at_refuse_non_finite_arguments() -> None:
    _params(lambda: novel_views(NAN, 4), "radius")
    _params(lambda: novel_views(4.0, 2, (NAN, 45.0)), "elevations_deg")
    _params(lambda: novel_views(4.0, 2, ()), "elevations_deg")
    _params(lambda: novel_views(4.0, 2, center=(NAN, 0.0, 0.0)), "center")
    _params(lambda: novel_views(4.0, 2.5), "count")  # type: ignore[arg-type]
    _params(lambda: novel_views(4.0, 2, azimuth_offset_deg=INF), "azimuth_offset_deg")
    assert novel_views(4.0, 3).shape == (3, 4, 4) and novel_views(4.0, 0).shape == (0, 4, 4)
    _params(lambda: look_at([NAN, 0.0, 0.0], [0.0, 0.0, 0.0]), "eye")
    _params(lambda: look_at([1.0, 0.0, 0.0], [0.0, 0.0]), "target")
    _params(lambda: look_at([1.0, 0.0, 0.0], [0.0, 0.0, 0.0], up=[0.0, INF, 0.0]), "up")
    _params(lambda: look_at([1e200, 0.0, 0.0], [0.0, 0.0, 0.0]), "eye", "target", match="not finite")


# --- B: make_scene_source checks the trajectory as it checks test_poses -------------------------------------


def test_scene_source_refuses_a_trajectory_or_test_poses_the_loader_would_refuse(traj: Trajectory) -> None:
    poses = traj.poses.copy()
    poses[1, 0, 0] = NAN
    bad = Trajectory(poses, traj.times, traj.steps, traj.fps)
    _params(
        lambda: make_scene_source("analytic-orbs", 8, 8, bad, None), "trajectory", match=r"trajectory\[1\]"
    )
    _params(lambda: make_scene_source("analytic-orbs", 8, 8, None, None), "trajectory")  # type: ignore[arg-type]
    _params(lambda: AnalyticSource("analytic-orbs", 8, 8, bad), "trajectory")
    zeros = np.zeros((2, 4, 4))
    _params(lambda: make_scene_source("analytic-orbs", 8, 8, traj, zeros), "test_poses", match="last row")
    scaled = novel_views(4.0, 2)
    scaled[1, :3, :3] *= 2
    _params(lambda: make_scene_source("analytic-orbs", 8, 8, traj, scaled), "test_poses", match="rotation")
    source = make_scene_source("analytic-orbs", 8, 8, traj, novel_views(4.0, 2))
    assert source.test_views()[1].shape == (2, 8, 8, 3)


# --- C: read_transforms -------------------------------------------------------------------------------------


@pytest.mark.parametrize("text", ["[" * 100_000 + "]" * 100_000, '{"frames": ' + "1" * 5000 + "}"])
def test_json_nested_too_deep_or_with_a_huge_integer_is_malformed(tmp_path: Path, text: str) -> None:
    path = tmp_path / "transforms.json"
    path.write_text(text)
    with pytest.raises(InputError, match="malformed JSON") as err:
        read_transforms(path)
    assert err.value.path == str(path)


# --- D: sizes beyond the memory at hand ---------------------------------------------------------------------


def test_huge_sizes_are_refused_up_front(limits_on: None, traj: Trajectory) -> None:
    _params(lambda: SpikeCamera(10**6, 10**6), "height", "width", match="memory")
    _params(lambda: SpikeCamera(10**12, 10**12), "height", "width", match="memory")
    _params(lambda: make_scene_source("analytic-orbs", 10**7, 10**7, traj, None), "width", "height", "spp")
    _params(lambda: make_scene_source("analytic-orbs", 8, 8, traj, None, spp=10**9), "width", "height", "spp")
    _params(lambda: make_scene_source("analytic-orbs", 8, 8, traj, None, spp=2.5), "spp")  # type: ignore[arg-type]
    _params(lambda: AnalyticSource("analytic-orbs", 8, 8.5, traj), "height")  # type: ignore[arg-type]


# --- E: RealisticNoise's ranges -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "value"),
    [("prnu_std", 1e300), ("dark_mean", 1e308), ("jitter_std", 1e300), ("threshold_std", 1e40),
     ("capacitance_std", 1e40), ("photons_per_white", 1e-300), ("readout_delay", 1e300), ("dark_std", NAN)],
)  # fmt: skip
def test_noise_parameters_beyond_their_range_are_refused(name: str, value: float) -> None:
    _params(lambda: RealisticNoise(**{name: value}), name, match=name)


def test_noise_at_the_ends_of_its_ranges_keeps_the_camera_finite() -> None:
    from spikenerf.camera.modes import NOISE_RANGES

    ends = {name: high if math.isfinite(high) else low for name, (low, high, _) in NOISE_RANGES.items()}
    frames = np.full((80, 4, 4), 0.5, np.float32)
    spikes = simulate(frames, 4, 4, CameraConfig(noise="realistic"), noise_params=RealisticNoise(**ends))
    assert spikes.shape == (80, 4, 4)  # (simulate checks the accumulator at its end: no NaN, no inf)


# --- F: SpikeCamera.step, simulate --------------------------------------------------------------------------


def test_step_refuses_inputs_and_buffers_it_cannot_use() -> None:
    cam = SpikeCamera(8, 8)
    _params(lambda: cam.step(np.ones((8, 8), np.complex64)), "intensity", match="complex64")
    _params(lambda: cam.step(torch.ones(8, 8, dtype=torch.complex64)), "intensity", match="complex64")
    _params(lambda: cam.step("abc"), "intensity")  # type: ignore[arg-type]
    _params(lambda: cam.step(np.ones((8, 8), object)), "intensity", match="object")
    _params(lambda: cam.step(np.ones((8, 8)), out=[[False] * 8] * 8), "out", match="list")  # type: ignore[arg-type]
    read_only = cam.new_spikes()
    read_only.flags.writeable = False
    _params(lambda: cam.step(np.ones((8, 8)), out=read_only), "out", match="read-only")
    _params(lambda: cam.step(np.ones((8, 8)), out=np.zeros((8, 8), np.float32)), "out", match="float32")
    _params(lambda: cam.step(np.ones((8, 8)), out=torch.zeros(8, 8, dtype=torch.bool)), "out", match="tensor")
    on_torch = SpikeCamera(8, 8, device="cpu")
    _params(lambda: on_torch.step(np.ones((8, 8)), out=np.zeros((8, 8), bool)), "out", match="numpy")
    assert cam.step(np.ones((8, 8)), out=cam.new_spikes()).all()
    assert on_torch.step(np.ones((8, 8)), out=on_torch.new_spikes()).all()


def test_camera_and_simulate_name_a_wrong_noise_params_or_frames() -> None:
    _params(lambda: SpikeCamera(8, 8, CameraConfig(), None, "x"), "noise_params")  # type: ignore[arg-type]
    _params(lambda: simulate(None, 8, 8), "frames")  # type: ignore[arg-type]
    _params(lambda: simulate(np.float32(0.5), 8, 8), "frames")  # type: ignore[arg-type]
    _params(lambda: list(simulate_iter(None, 8, 8)), "frames")  # type: ignore[arg-type]


# --- G: AnalyticSource.render -------------------------------------------------------------------------------


def test_render_takes_one_finite_rigid_pose(traj: Trajectory) -> None:
    source = AnalyticSource("analytic-orbs", 8, 8, traj)
    for bad in (np.full((4, 4), INF), np.full((4, 4), NAN), np.zeros((3, 4)), np.stack([np.eye(4)] * 2)):
        _params(lambda b=bad: source.render(b), "c2w")
    assert source.render(traj.poses[0]).shape == (8, 8, 3)
    assert np.array_equal(source.render(traj.poses[0][:3]), source.render(traj.poses[0]))  # (3, 4) as before
