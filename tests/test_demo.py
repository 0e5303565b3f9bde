"""``spikenerf demo --quick`` end to end at a tiny size, its report, and the benchmark's resume."""

from __future__ import annotations

import base64
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from spikenerf.pipelines.demo import PRESETS, DemoConfig, benchmark_config, train_args
from spikenerf.pipelines.report import SECTIONS

#: tiny: 16 px, 100 steps (one 400 fps blur frame), 6 iterations, one test view, two of the demo's methods
#: (each training run costs ~15 s of fixed set-up on a CPU, so the test keeps to two; see docs/report.md)
TINY = ["--quick", "--size", "16", "--iters", "6", "--frames", "100", "--test-views", "1", "--device", "cpu",
        "--methods", "nerf-blur,spike-nerf"]  # fmt: skip


def _png_images(page: str) -> int:
    """How many <img> the page has; fails unless every one is a base64 data URI of a PNG."""
    sources = re.findall(r"<img\b[^>]*\bsrc=\"([^\"]*)\"", page)
    for src in sources:
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1], validate=True)[:8] == b"\x89PNG\r\n\x1a\n"
    return len(sources)


def _demo(out: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "spikenerf", "demo", "--out", str(out), *TINY, *extra]
    return subprocess.run(command, capture_output=True, text=True, timeout=600, check=False)


def _commands(out: Path) -> list[str]:
    """The subcommands (simulate, train, eval, render) the last benchmark run executed."""
    log = json.loads((out / "results.json").read_text())["commands"]["this_run"]
    return [entry["command"][1] for entry in log]


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("demo") / "demo_out"
    done = _demo(out)
    assert done.returncode == 0, done.stderr[-3000:]
    return out, done.stdout


def test_quick_demo_runs_end_to_end(demo: tuple[Path, str]) -> None:
    out, stdout = demo
    assert _commands(out) == ["simulate"] + ["train", "eval", "render"] * 2
    for method in ("spike-nerf", "nerf-blur"):
        run = out / "runs" / "analytic-orbs" / "gray" / method
        assert (run / "metrics.json").is_file() and (run / "render" / "images" / "00000.png").is_file()
    assert "| Spike-NeRF (paper) |" in stdout and "| NeRF on 400 fps blur |" in stdout
    assert f"report: {(out / 'report.html').resolve()}" in stdout and "s CPU" in stdout
    cells = json.loads((out / "results.json").read_text())["cells"]
    assert len(cells) == 2 and all(c["lpips"] is None for c in cells)  # 16 px: below LPIPS' minimum


def test_quick_demo_report_has_every_section(demo: tuple[Path, str]) -> None:
    page = (demo[0] / "report.html").read_text(encoding="utf-8")
    for section in SECTIONS:
        assert f"<section id='{section}'>" in page
    assert _png_images(page) == 5  # views, raster, TFP + mask, curves, novel-view spikes
    assert "figure not available" not in page and "no rendered test view" not in page
    assert page.count('class="n best"') >= 2  # Table I marks the best SSIM and PSNR


def test_second_run_reuses_finished_cells(demo: tuple[Path, str]) -> None:
    out, stdout = demo
    ckpts = sorted((out / "runs").rglob("checkpoint.pt"))
    stamps = [p.stat().st_mtime_ns for p in ckpts]
    done = _demo(out)
    assert done.returncode == 0, done.stderr[-3000:]
    assert _commands(out) == []  # nothing simulated, trained, evaluated or rendered again
    assert [p.stat().st_mtime_ns for p in ckpts] == stamps and len(ckpts) == 2
    table = stdout.split("**GRAY**")[1].split("report:")[0]
    assert table in done.stdout  # the same numbers


def test_presets_and_train_args() -> None:
    assert PRESETS["quick"].iters < PRESETS["default"].iters and PRESETS["quick"].size < 64
    cfg = benchmark_config(DemoConfig(out=Path("x"), quick=True, iters=50))
    assert (cfg.scenes, cfg.colors, cfg.iters, cfg.size) == (["analytic-orbs"], ["gray"], 50, 32)
    args = train_args(DemoConfig(iters=50).preset())
    assert args[args.index("--spike-warmup") + 1] == "10" and args[args.index("--eval-every") + 1] == "8"
    assert "--quiet" not in args  # training shows its progress bar


def test_the_demos_records_name_its_folder_absolutely(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The default ``--out demo_out`` (relative) was recorded as ``demo_out/datasets/...`` in the commands of
    results.json, the dataset's config.yaml and the report: wrong read from any other folder."""
    from spikenerf.pipelines.benchmark.cells import dataset_command

    monkeypatch.chdir(tmp_path)
    cfg = benchmark_config(DemoConfig(quick=True))
    assert cfg.out == tmp_path / "demo_out"
    command = dataset_command(cfg, cfg.scenes[0])
    assert command[command.index("--out") + 1] == str(tmp_path / "demo_out" / "datasets" / cfg.scenes[0])
    assert benchmark_config(DemoConfig(out=Path("d/x/.."))).out == tmp_path / "d"


@pytest.mark.parametrize("size", ["4", "8", "10"])  # below SSIM's window (no cell could be tabulated); not ×4
def test_bad_size_is_one_line_exit_2(tmp_path: Path, size: str) -> None:
    command = [sys.executable, "-m", "spikenerf", "demo", "--out", str(tmp_path / "d"), "--size", size]
    done = subprocess.run(command, capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 2 and done.stderr.startswith("spikenerf: error: --size must be a multiple of 4")
    assert f"at least 12 (SSIM's 11-pixel window), found {size}" in done.stderr
    assert done.stderr.count("\n") == 1 and not (tmp_path / "d").exists()
