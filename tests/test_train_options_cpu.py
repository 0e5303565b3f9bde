"""``benchmarks/tools/train_options_cpu.py``: how a run's spec becomes its config (the timings it prints are
measurements, docs/performance.md)."""

from __future__ import annotations

from pathlib import Path

from helpers import load_benchmark

TOOL = load_benchmark("tools/train_options_cpu")


def test_a_spec_gives_field_options_and_compile_goes_to_the_train_config() -> None:
    name, options = TOOL.parse("compiled:static_samples=64,static_colors=16,compile=true")
    assert name == "compiled" and options == {"static_samples": 64, "static_colors": 16, "compile": True}
    cfg = TOOL.train_config(Path("DS"), "nerf-gt", 30, options)
    assert cfg.compile and cfg.field_config == {"static_samples": 64, "static_colors": 16}
    name, options = TOOL.parse("default:")
    cfg = TOOL.train_config(Path("DS"), "nerf-gt", 30, options)
    assert name == "default" and not cfg.compile and cfg.field_config == {} and cfg.iters == 30
