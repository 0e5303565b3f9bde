"""``benchmarks/tools/profile_cuda_step.py``: its GPU-time sum and a CPU smoke run (the CUDA figures come from
a GPU host, docs/performance.md)."""

from __future__ import annotations

import argparse
from pathlib import Path
from types import SimpleNamespace

import pytest
from torch.autograd import DeviceType

from helpers import load_benchmark, run_cli

TOOL = load_benchmark("tools/profile_cuda_step")


def test_gpu_time_counts_each_kernel_once() -> None:
    # the profiler gives an op the device time of the kernels it launched, and the kernels their own
    op = SimpleNamespace(device_type=DeviceType.CPU, self_device_time_total=5.0)
    kernel = SimpleNamespace(device_type=DeviceType.CUDA, self_device_time_total=5.0)
    copy = SimpleNamespace(device_type=DeviceType.CUDA, self_device_time_total=1.5)
    assert TOOL.gpu_us([op, kernel, copy]) == 6.5
    assert TOOL.gpu_us([op]) == 0.0


def test_profile_case_on_the_cpu(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ds = tmp_path / "ds"
    code, _, err = run_cli(capsys, "simulate", "--scene", "analytic-orbs", "--width", 16, "--height", 16,
                           "--frames", 60, "--test-views", 1, "--out", ds)  # fmt: skip
    assert code == 0, err
    args = argparse.Namespace(
        device="cpu", warmup=1, steps=2, profile_steps=1, compile=False, compile_optimizer=False, start=[]
    )
    args.field_option = []
    out = TOOL.profile_case(ds, "nerf-gt", 64, args, tmp_path)
    assert out["rays_per_second"] > 0 and out["ms_per_step"] > 0
    assert out["gpu_kernel_ms_per_step"] == 0.0 and out["launches_per_step"] == 0.0
    assert out["top_host_ops"] and not out["top_device_ops"]
    assert "nerf-gt batch 64:" in capsys.readouterr().out
    args.field_option = [TOOL.field_option("static_samples=40")]
    out = TOOL.profile_case(ds, "nerf-gt", 64, args, tmp_path / "static")
    assert out["field_options"] == {"static_samples": 40} and out["rays_per_second"] > 0
    assert "nerf-gt batch 64 static_samples=40:" in capsys.readouterr().out
    with pytest.raises(argparse.ArgumentTypeError, match="expected KEY=VALUE"):
        TOOL.field_option("static_samples")


def test_a_profile_can_start_from_a_finished_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from spikenerf.train import compiled_step

    monkeypatch.setattr(compiled_step, "BACKEND", "eager")  # dynamo's trace, no code generation
    ds, run = tmp_path / "ds", tmp_path / "run"
    code, _, err = run_cli(capsys, "simulate", "--scene", "analytic-orbs", "--width", 16, "--height", 16,
                           "--frames", 60, "--test-views", 1, "--out", ds)  # fmt: skip
    assert code == 0, err
    code, _, err = run_cli(capsys, "train", ds, "--method", "nerf-gt", "--iters", 6, "--batch", 32,
                           "--eval-every", 0, "--quiet", "--device", "cpu", "--out", run)  # fmt: skip
    assert code == 0, err
    args = argparse.Namespace(
        device="cpu", warmup=1, steps=2, profile_steps=1, compile=True, compile_optimizer=False
    )
    args.field_option = [TOOL.field_option("static_samples=40")]
    args.start = [TOOL.method_run(f"nerf-gt={run}")]
    out = TOOL.profile_case(ds, "nerf-gt", 48, args, tmp_path / "profiles")
    assert out["rays_per_second"] > 0 and out["batch"] == 48
    assert out["static_samples"] == 40 and out["compiled_step"]  # the resumed model renders with the budget
    copy = tmp_path / "profiles" / "nerf-gt-48"
    assert "static_samples: 40" in (copy / "config.yaml").read_text()
    assert "static_samples" not in (run / "config.yaml").read_text()  # the finished run is untouched
    with pytest.raises(argparse.ArgumentTypeError, match="METHOD=RUN"):
        TOOL.method_run(f"nerf-gt={tmp_path / 'nowhere'}")
    args.start = [TOOL.method_run(f"spike-integral={run}")]
    with pytest.raises(SystemExit, match="that run trained nerf-gt"):
        TOOL.profile_case(ds, "spike-integral", 48, args, tmp_path / "profiles")
