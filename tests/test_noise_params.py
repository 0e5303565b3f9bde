"""`simulate --noise-param` / ``SimulateOptions.noise_params``: the realistic preset with some parameters
replaced (camera/noise.py ``noise_with``), used by the camera, recorded in ``config.yaml`` and named by
``info``; bad names, values and combinations are one line with exit 2."""

from __future__ import annotations

import math
from pathlib import Path

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
