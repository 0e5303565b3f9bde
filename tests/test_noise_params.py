"""`simulate --noise-param` / ``SimulateOptions.noise_params``: the realistic preset with some parameters
replaced (camera/noise.py ``noise_with``), used by the camera, recorded in ``config.yaml`` and named by
``info``; bad names, values and combinations are one line with exit 2."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from helpers import load_benchmark, run_cli
from spikenerf.camera.io import read_dat
from spikenerf.camera.noise import RealisticNoise, noise_with
from spikenerf.capture.options import SimulateOptions, check_options
from spikenerf.core.errors import InputError

SIM = ["simulate", "--scene", "analytic-orbs", "--width", 12, "--height", 10, "--frames", 30, "--blur-fps", 0,
       "--test-views", 0, "--no-progress"]  # fmt: skip


def test_noise_with_replaces_only_the_named_parameters() -> None:
    assert noise_with(None) == RealisticNoise() == noise_with({})
    params = noise_with({"dark_mean": 0, "photons_per_white": math.inf})
    assert params.dark_mean == 0.0 and math.isinf(params.photons_per_white)
    assert params.prnu_std == RealisticNoise().prnu_std and params.dark_std == RealisticNoise().dark_std


@pytest.mark.parametrize(
    ("overrides", "param", "words"),
    [
        ({"dark_mea": 0}, "noise_params", "unknown noise parameter dark_mea"),
        ({"dark_mean": -1}, "dark_mean", "must lie within [0, 100]"),
        ({"readout_delay": float("nan")}, "readout_delay", "readout_delay must lie within"),
        ({"jitter_std": "x"}, "jitter_std", "jitter_std must lie within"),
        ([("dark_mean", 0)], "noise_params", "must be a mapping"),
    ],
)
def test_noise_with_names_the_bad_parameter(overrides: object, param: str, words: str) -> None:
    with pytest.raises(InputError, match=words.replace("[", r"\[")) as err:
        noise_with(overrides)  # type: ignore[arg-type]
    assert param in err.value.params


def test_options_refuse_noise_params_without_realistic_noise() -> None:
    check_options(SimulateOptions(noise="realistic", noise_params={"dark_mean": 0.0}))
    with pytest.raises(InputError, match="realistic") as err:
        check_options(SimulateOptions(noise="ideal", noise_params={"dark_mean": 0.0}))
    assert "noise_params" in err.value.params


def test_simulate_uses_records_and_shows_the_replaced_parameters(capsys, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    args = [
        "--noise",
        "realistic",
        "--noise-param",
        "dark_mean=0.2",
        "--noise-param",
        "photons_per_white=inf",
    ]
    code, _, err = run_cli(capsys, *SIM, *args, "--out", tmp_path / "a")
    assert code == 0, err
    assert run_cli(capsys, *SIM, "--noise", "realistic", "--out", tmp_path / "b")[0] == 0
    config = yaml.safe_load((tmp_path / "a" / "config.yaml").read_text())
    assert config["noise_params"] == {"dark_mean": 0.2, "photons_per_white": math.inf}
    assert "noise_params" not in yaml.safe_load((tmp_path / "b" / "config.yaml").read_text())
    replaced, preset = (read_dat(tmp_path / d / "spikes_gray.dat", 10, 12) for d in "ab")
    assert replaced.sum() > preset.sum()  # 40× the preset's dark current fires more
    code, out, _ = run_cli(capsys, "info", tmp_path / "a")
    assert code == 0 and "(dark_mean=0.2, photons_per_white=inf)" in out


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--noise", "realistic", "--noise-param", "dark_mea=0"], "--noise-param: unknown noise parameter"),
        (
            ["--noise", "realistic", "--noise-param", "dark_mean=-1"],
            "--noise-param dark_mean must lie within",
        ),
        (["--noise", "realistic", "--noise-param", "dark_mean"], "--noise-param expects NAME=VALUE"),
        (["--noise", "realistic", "--noise-param", "dark_mean=x"], "expected a number"),
        (["--noise", "realistic", "--noise-param", "dark_mean=0", "--noise-param", "dark_mean=1"], "twice"),
        (["--noise-param", "dark_mean=0"], "--noise is 'ideal'"),
    ],
)
def test_bad_noise_params_are_one_line_and_write_nothing(
    capsys, tmp_path: Path, args: list, words: str
) -> None:  # type: ignore[no-untyped-def]
    code, _, err = run_cli(capsys, *SIM, *args, "--out", tmp_path / "o")
    assert code == 2 and len(err.strip().splitlines()) == 1 and words in err, err
    assert not (tmp_path / "o").exists()


def test_the_ablation_variants_are_valid_noise_parameters() -> None:
    variants = load_benchmark("experiments/bench_noise_ablation").VARIANTS
    params = {name: noise_with(v) for name, v in variants.items() if v is not None}
    assert params["no-dark"].dark_mean == 0 and params["no-fixed"].prnu_std == 0
    assert math.isinf(params["dark-only"].photons_per_white) and params["dark-only"].dark_mean > 0


def test_numpy_values_through_the_python_api_are_recorded_as_numbers(tmp_path: Path) -> None:
    """``noise_params`` of numpy numbers (a sweep over ``np.linspace``) were written raw into config.yaml:
    a RepresenterError after the whole simulation, the dataset left as a ``.partial`` folder."""
    import numpy as np

    from spikenerf.capture.simulate import simulate_dataset
    from spikenerf.scenes.analytic import AnalyticSource
    from spikenerf.scenes.trajectory import novel_views, orbit

    source = AnalyticSource("analytic-orbs", 8, 8, orbit(4.0, 30.0, duration=20 / 40000), novel_views(4.0, 1))
    params = {"dark_mean": np.float64(0.1), "readout_delay": np.int64(2)}
    options = SimulateOptions(noise="realistic", noise_params=params, blur_fps=0.0)
    root = simulate_dataset(source, tmp_path / "ds", options, progress=False)
    config = yaml.safe_load((root / "config.yaml").read_text())
    assert config["noise_params"] == {"dark_mean": 0.1, "readout_delay": 2.0}


def test_the_pixel_gain_benchmark_draws_the_datasets_own_patterns(tmp_path: Path) -> None:
    """``bench_pixel_gain`` compares a learned map with the true per-pixel response drawn again from the
    dataset's seed: with the recorded ``noise_params`` (it drew the preset's, a pattern the camera never
    had, for a dataset simulated with ``--noise-param``)."""
    import numpy as np

    bench = load_benchmark("experiments/bench_pixel_gain")
    flat = {"threshold_std": 0.0, "capacitance_std": 0.0, "prnu_std": 0.0}
    config = {"seed": 3, "threshold": 1.0, "noise": "realistic", "noise_params": flat}
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(config))
    assert np.abs(bench.true_log_response(tmp_path, (6, 5))).max() == 0.0  # no pattern to learn
    (tmp_path / "config.yaml").write_text(yaml.safe_dump({**config, "noise_params": {}}))
    assert bench.true_log_response(tmp_path, (6, 5)).std() > 0.01  # the preset's


def test_benchmark_simulates_its_noise_params_and_refuses_a_dataset_with_others(
    capsys, tmp_path: Path
) -> None:  # type: ignore[no-untyped-def]
    """``benchmark --noise-param`` passes the replaced parameters to its datasets' ``simulate``; a dataset in
    OUT/datasets simulated with other ones (or with some where the benchmark asks for none) is refused in
    one line naming --noise-param, before any training; its tables name them."""
    from spikenerf.pipelines.benchmark import BenchmarkConfig
    from spikenerf.pipelines.benchmark.cells import dataset_command
    from spikenerf.pipelines.benchmark.results import noise_note
    from spikenerf.pipelines.benchmark.run import dataset_mismatch

    cfg = BenchmarkConfig(["analytic-orbs"], ["nerf-gt"], ["gray"], tmp_path / "b", size=12, frames=30,
                          iters=2, device="cpu", test_views=1, render=False, noise="realistic",
                          noise_params={"excess_carry": 0.0})  # fmt: skip
    simulate = dataset_command(cfg, "analytic-orbs")[3:]  # (after `python -m spikenerf`)
    assert simulate[simulate.index("--noise-param") :][:2] == ["--noise-param", "excess_carry=0.0"]
    from fractions import Fraction  # (a number whose repr is no float, as numpy 2's np.float64(0.0))

    other_number = BenchmarkConfig(**{**vars(cfg), "noise_params": {"excess_carry": Fraction(0)}})
    assert dataset_command(other_number, "analytic-orbs")[3:] == simulate
    assert run_cli(capsys, *simulate, "--no-progress")[0] == 0
    assert dataset_mismatch(cfg, "analytic-orbs") is None  # simulated as the benchmark asks
    config = yaml.safe_load((cfg.out / "datasets" / "analytic-orbs" / "config.yaml").read_text())
    assert config["noise_params"] == {"excess_carry": 0.0}
    preset = BenchmarkConfig(**{**vars(cfg), "noise_params": {}})
    problem = dataset_mismatch(preset, "analytic-orbs")
    assert problem is not None and "excess_carry=0.0, but the benchmark asks for none" in problem.message
    args = ["benchmark", "--scenes", "analytic-orbs", "--methods", "nerf-gt", "--color", "gray", "--size", 12,
            "--frames", 30, "--iters", 2, "--test-views", 1, "--no-render", "--device", "cpu", "--noise",
            "realistic", "--out", cfg.out]  # fmt: skip
    code, _, err = run_cli(capsys, *args, "--noise-param", "dark_mean=0.2")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "--noise-param:" in err, err
    assert "dark_mean=0.2" in err and not (cfg.out / "runs").exists()
    assert "the preset's excess_carry=0" in noise_note("realistic", {"excess_carry": 0.0})


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--noise-param", "dark_mean=0"], "--noise is 'ideal'"),
        (["--noise", "realistic", "--noise-param", "dark_mea=0"], "--noise-param: unknown noise parameter"),
        (["--noise", "realistic", "--noise-param", "excess_carry=2"], "--noise-param excess_carry must lie"),
    ],
)
def test_benchmark_refuses_bad_noise_params_before_anything(
    capsys, tmp_path: Path, args: list, words: str
) -> None:  # type: ignore[no-untyped-def]
    code, _, err = run_cli(capsys, "benchmark", "--scenes", "analytic-orbs", "--methods", "nerf-gt", "--size",
                           12, "--frames", 30, "--no-render", *args, "--out", tmp_path / "b")  # fmt: skip
    assert code == 2 and len(err.strip().splitlines()) == 1 and words in err, err
    assert not (tmp_path / "b").exists()


def test_the_ablation_resumes_a_training_stopped_before_its_result(tmp_path: Path) -> None:
    """A training of bench_noise_ablation stopped after a checkpoint but before its result.json (written
    atomically) continues on the next call, where it was refused ("already holds a training run") and the
    whole benchmark stopped."""
    import argparse

    bench = load_benchmark("experiments/bench_noise_ablation")
    args = argparse.Namespace(out=tmp_path, scene="analytic-orbs", size=12, frames=30, test_views=1,
                              method="spike-integral", iters=2, set=[], tag="", threshold=1.0,
                              true_pattern=False)  # fmt: skip
    dataset = bench.simulate(args, "no-dark")
    assert yaml.safe_load((dataset / "config.yaml").read_text())["noise_params"]["dark_mean"] == 0.0
    first = bench.train(("no-dark", dataset, 0, args))
    (tmp_path / "run-no-dark-0" / "result.json").unlink()  # stopped before the result
    assert bench.train(("no-dark", dataset, 0, args)) == first


def test_the_ablations_true_response_follows_the_datasets_noise_params(capsys, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    ablation = load_benchmark("experiments/bench_noise_ablation")
    flat = [arg for name in ("threshold_std", "capacitance_std", "prnu_std")
            for arg in ("--noise-param", f"{name}=0")]  # fmt: skip
    assert run_cli(capsys, *SIM, "--noise", "realistic", *flat, "--out", tmp_path / "flat")[0] == 0
    preset = ["--noise", "realistic", "--threshold", 1.25]
    assert run_cli(capsys, *SIM, *preset, "--out", tmp_path / "preset")[0] == 0
    assert np.array_equal(ablation.true_response(tmp_path / "flat"), np.ones((10, 12), np.float32))
    response = ablation.true_response(tmp_path / "preset")
    assert response.shape == (10, 12) and 0.03 < float(np.log(response).std()) < 0.15  # the preset's 7.4 %


def test_the_ablation_keeps_true_pattern_and_set_runs_apart(  # type: ignore[no-untyped-def]
    capsys, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``--set`` without ``--tag`` is refused before anything is simulated (its runs would reuse the untagged
    runs' results); ``--true-pattern`` trains in folders of its own, not the learned map's under the same
    tag; an ideal stream's true response is 1; the learned map's match with the truth is measured."""
    import argparse
    import sys

    from spikenerf.train.sensor_response import SENSOR_MAP, SensorResponse

    bench = load_benchmark("experiments/bench_noise_ablation")
    simulate = bench.simulate
    monkeypatch.setattr(sys, "argv", ["ablation", "--out", str(tmp_path / "x"), "--set", "iters=3"])
    monkeypatch.setattr(bench, "simulate", lambda *a: pytest.fail("simulated"))
    with pytest.raises(SystemExit) as exit_:
        bench.main()
    assert exit_.value.code == 2 and "--set needs --tag" in capsys.readouterr().err
    monkeypatch.setattr(SensorResponse, "factor", SensorResponse.factor)  # (--true-pattern replaces it)
    args = argparse.Namespace(out=tmp_path, scene="analytic-orbs", size=12, frames=30, test_views=1,
                              method="spike-integral", iters=2, set=["integral.pixel_gain=true"], tag="-x",
                              threshold=1.0, true_pattern=True)  # fmt: skip
    realistic = simulate(args, "realistic")
    learned = tmp_path / "run-realistic-x-0"  # a run that learned the map under the same tag
    learned.mkdir()
    (learned / "result.json").write_text('{"psnr": 99.0}')
    assert bench.train(("realistic", realistic, 0, args))[2] != 99.0
    assert (tmp_path / "run-realistic-x-true-0" / "result.json").exists()
    ideal = simulate(args, "ideal")
    assert np.array_equal(bench.true_response(ideal), np.ones((12, 12), np.float32))
    np.save(learned / SENSOR_MAP, bench.true_response(realistic))
    assert bench.map_match(learned, realistic) == pytest.approx((1.0, 1.0))
    assert bench.map_match(learned, ideal) is None and bench.map_match(tmp_path, realistic) is None


@pytest.mark.parametrize("device", ["numpy", "torch"])
def test_excess_carry_zero_drops_what_a_saturated_pixel_holds_beyond_one_spike_a_step(device: str) -> None:
    """Light 1.5 φ a step for 10 steps, then 0.2 φ for 20: keeping the excess (1, the default) fires every
    step long after the light dimmed (5 thresholds stored); dropping it (0) fires at the dim rate at once.
    With no other noise, carry 1 is the ideal camera bit for bit."""
    import torch

    from spikenerf.camera.model import CameraConfig, SpikeCamera

    quiet = {"dark_mean": 0, "dark_std": 0, "threshold_std": 0, "capacitance_std": 0, "prnu_std": 0,
             "jitter_std": 0, "photons_per_white": math.inf, "readout_delay": 0}  # fmt: skip
    light = [1.5] * 10 + [0.2] * 20

    def stream(noise: str, **params: float) -> np.ndarray:
        camera = SpikeCamera(2, 3, CameraConfig(1.0, "gray", noise, 0), None if device == "numpy" else "cpu",
                             noise_with({**quiet, **params}) if noise == "realistic" else None)  # fmt: skip
        frames = [camera.step(np.full((2, 3), v, np.float32)) for v in light]
        return np.stack([f.cpu().numpy() if isinstance(f, torch.Tensor) else f for f in frames])

    kept, dropped = stream("realistic"), stream("realistic", excess_carry=0.0)
    assert np.array_equal(kept, stream("ideal"))
    assert kept[:10].all() and dropped[:10].all()  # saturated: once a step either way
    assert kept[10:15].all()  # the stored excess fires on
    assert dropped[10:].sum(axis=0).max() <= 5 and dropped[10:].sum(axis=0).min() >= 3  # 0.2 × 20 = 4 ± 1


def test_a_benchmark_folder_resumes_only_with_its_noise_params(tmp_path: Path) -> None:
    """``benchmark.json`` records ``noise_params``: a resume that asks for other ones is refused naming the
    setting; a folder recorded before the setting existed reads as none replaced."""
    import json

    from spikenerf.pipelines.benchmark import BenchmarkConfig
    from spikenerf.pipelines.benchmark.settings import NAME, check_settings, write_settings

    cfg = BenchmarkConfig(["analytic-orbs"], ["nerf-gt"], ["gray"], tmp_path, size=12, frames=30, iters=2,
                          noise="realistic", noise_params={"excess_carry": 0.0})  # fmt: skip
    write_settings(cfg, None)
    check_settings(cfg)
    other = BenchmarkConfig(**{**vars(cfg), "noise_params": {}})
    with pytest.raises(InputError, match="noise_params"):
        check_settings(other)
    stored = json.loads((tmp_path / NAME).read_text())
    del stored["settings"]["noise_params"]  # as written before the setting
    (tmp_path / NAME).write_text(json.dumps(stored))
    check_settings(other)
    with pytest.raises(InputError, match="noise_params"):
        check_settings(cfg)
