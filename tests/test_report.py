"""The HTML report: tables with best/second marks, every section, missing pieces as "–", offline loading."""

from __future__ import annotations

import base64
import re
import subprocess
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from spikenerf.cli import main
from spikenerf.pipelines import figures
from spikenerf.pipelines.benchmark import BenchmarkConfig, read_cell, run_dir
from spikenerf.pipelines.benchmark.tables import Cell
from spikenerf.pipelines.report import SECTIONS, build_report, table1_html, table2_html

SCENE, SIZE = "analytic-orbs", 20
CHROMIUM = Path("/usr/bin/chromium")
IMG = re.compile(r"<img\b[^>]*\bsrc=\"([^\"]*)\"")


def _cli(*args: object) -> None:
    main([str(a) for a in args])


def data_uri_pngs(page: str) -> list[np.ndarray]:
    """Every <img> of the page, decoded; fails unless each one is a base64 PNG data URI."""
    images = []
    for src in IMG.findall(page):
        assert src.startswith("data:image/png;base64,"), src[:60]
        raw = base64.b64decode(src.split(",", 1)[1], validate=True)
        assert raw[:8] == b"\x89PNG\r\n\x1a\n"
        images.append(np.asarray(iio.imread(raw, extension=".png")))
    return images


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> BenchmarkConfig:
    """A benchmark folder: one dataset, a finished nerf-gt cell (trained 4 iterations), spike-nerf missing."""
    out = tmp_path_factory.mktemp("bench")
    cfg = BenchmarkConfig([SCENE], ["spike-nerf", "nerf-gt"], ["gray"], out, size=SIZE, test_views=1)
    ds, run = out / "datasets" / SCENE, run_dir(cfg, SCENE, "gray", "nerf-gt")
    _cli("simulate", "--scene", SCENE, "--width", SIZE, "--height", SIZE, "--frames", 60, "--test-views", 1,
         "--no-progress", "--out", ds)  # fmt: skip
    _cli("train", ds, "--method", "nerf-gt", "--iters", 4, "--batch", 128, "--eval-every", 2,
         "--eval-views", 1, "--device", "cpu", "--quiet", "--out", run)  # fmt: skip
    _cli("eval", run, "--device", "cpu", "--quiet")
    _cli("render", run, "--out", run / "render", "--device", "cpu", "--quiet")
    return cfg


@pytest.fixture(scope="module")
def report(bench: BenchmarkConfig) -> str:
    cells = [read_cell(run_dir(bench, SCENE, "gray", "nerf-gt"), SCENE, "gray", "nerf-gt")]
    path = build_report(bench, [c for c in cells if c is not None], progress=False)
    assert path == bench.out / "report.html"
    return path.read_text(encoding="utf-8")


def test_table1_marks_best_and_second_and_dashes() -> None:
    cells = [Cell("s", "nerf-gt", "gray", 30.0, 0.95), Cell("s", "nerf-blur", "gray", 20.0, 0.7),
             Cell("s", "spike-nerf", "gray", 25.0, 0.9)]  # fmt: skip
    page = table1_html(cells, ["nerf-gt", "nerf-blur", "spike-nerf", "nerf-recon"], ["s"], "gray")
    rows = {r.split("</td>")[0]: r for r in page.split("<tr><td>")[1:]}
    assert '<td class="n best">30.00</td>' in rows["NeRF on sharp GT (oracle)"]
    assert '<td class="n second">25.00</td>' in rows["Spike-NeRF (paper)"]
    assert '<td class="n ">20.00</td>' in rows["NeRF on 400 fps blur"]
    assert rows["NeRF + TFP reconstruction"].count("–") == 4  # missing scene and average, SSIM and PSNR
    rgb = table1_html(cells, ["nerf-gt"], ["s"], "rgb")  # no rgb cells: dashes, never a mark
    assert "best" not in rgb and rgb.count("–") == 4


def test_table2_lpips_direction() -> None:
    lpips = {"spike-nerf": 0.1, "spike-nerf-no-mask": 0.3, "spike-nerf-no-spike-loss": 0.2}
    cells = [Cell("s", v, "gray", 28.0, 0.9, lp) for v, lp in lpips.items()]
    page = table2_html(cells, "gray")
    assert '<td class="n best">0.100</td>' in page and '<td class="n second">0.200</td>' in page


def test_report_has_every_section_and_only_inline_png(report: str, bench: BenchmarkConfig) -> None:
    for section in SECTIONS:
        assert f"<section id='{section}'>" in report
    images = data_uri_pngs(report)
    # views (GT + nerf-gt + missing spike-nerf), raster, TFP/mask, curves, novel spikes
    assert len(images) == 5 and all(im.ndim == 3 and min(im.shape[:2]) > 50 for im in images)
    saved = sorted(p.name for p in (bench.out / "figures").glob("*.png"))
    assert saved == [
        f"{s}-{SCENE}{x}.png"
        for s, x in [
            ("curves", "-gray"),
            ("novel-spikes", "-gray"),
            ("spikes", "-1"),
            ("spikes", "-2"),
            ("views", "-gray"),
        ]
    ]
    assert "<script" not in report and "http://" not in report and "https://" not in report
    assert "<link" not in report and "@import" not in report and "url(" not in report


def test_report_notes_missing_pieces(report: str) -> None:
    assert "Spike-NeRF (paper): no result (the cell has not finished)" in report
    assert "LPIPS – (images 20×20 are smaller than LPIPS-alex" in report
    assert "– no rendered test view for: Spike-NeRF (paper)." in report
    assert "figure not available" not in report
    assert "spikenerf render " in report and "spikenerf simulate --scene analytic-orbs" in report
    assert "spikenerf reconstruct " in report and "--method tfp --window 41" in report
    novel = report.split("<section id='novel-spikes'>")[1].split("</section>")[0]
    assert "PSNR between the two TFP images" in novel and "novel_spikes(" in novel


def test_the_spike_figures_reconstruct_commands_name_files_the_dataset_holds(tmp_path: Path) -> None:
    """An RGB dataset holds ``spikes_rgb_{r,g,b}.dat``: one command per channel file (it named a
    ``spikes_rgb.dat`` that nothing writes)."""
    from spikenerf.data.dataset import load_dataset
    from spikenerf.pipelines.report import _spikes_figs

    ds = tmp_path / "rgb"
    _cli("simulate", "--scene", SCENE, "--width", 12, "--height", 12, "--frames", 40, "--test-views", 1,
         "--color", "rgb", "--no-progress", "--out", ds)  # fmt: skip
    cfg = BenchmarkConfig([SCENE], ["nerf-gt"], ["rgb"], tmp_path, size=12, test_views=1)
    commands = [c for fig in _spikes_figs(cfg, load_dataset(ds), SCENE) for c in fig.commands]
    named = [Path(c.split()[2]) for c in commands if c.startswith("spikenerf reconstruct ")]
    assert [p.name for p in named] == ["spikes_rgb_r.dat", "spikes_rgb_g.dat", "spikes_rgb_b.dat"]
    assert all(p.is_file() for p in named)


def test_a_failing_figure_becomes_a_note(bench: BenchmarkConfig, monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(*args: object, **kwargs: object) -> bytes:
        raise RuntimeError("no raster today")

    monkeypatch.setattr(figures, "raster_figure", broken)
    page = build_report(bench, [], progress=False).read_text(encoding="utf-8")
    assert "figure not available: RuntimeError: no raster today" in page
    assert "<section id='curves'>" in page and len(data_uri_pngs(page)) == 3  # the scene's spike figures go


def test_raster_pixels_spread_over_rates() -> None:
    rates = np.array([1.0] * 90 + [0.0, 0.2, 0.4, 0.6, 0.8] + [1.0] * 5)
    picks = figures.raster_pixels(rates, 6)
    assert list(rates[picks]) == [0.0, 0.2, 0.4, 0.6, 0.8, 1.0]


def test_crop_box_and_error_map() -> None:
    gt = np.ones((10, 12, 3))
    gt[3:5, 4:9] = 0.2
    rows, cols = figures.crop_box(gt, pad=1)
    assert (rows, cols) == (slice(2, 6), slice(3, 10))
    assert figures.crop_box(np.ones((4, 4))) == (slice(0, 4), slice(0, 4))
    err = figures.error_map(np.zeros((2, 2, 3)), np.full((2, 2, 3), 0.5))
    assert err.shape == (2, 2) and np.allclose(err, 0.5)


# --------------------------------------------------------------------------------------- headless Chromium
CHECK = """<script>window.addEventListener("load", () => { const imgs = [...document.images];
document.body.setAttribute("data-imgs", imgs.length);
document.body.setAttribute("data-bad", imgs.filter(i => !(i.complete && i.naturalWidth > 0)).length); });
</script>"""


def chromium(page: Path, tmp: Path) -> tuple[str, str]:
    """(DOM after load, stderr with console messages) of ``page`` in headless Chromium."""
    command = [
        str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync",
        f"--user-data-dir={tmp / 'profile'}", "--enable-logging=stderr", "--v=0",
        "--virtual-time-budget=5000", "--dump-dom", page.resolve().as_uri(),
    ]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout, done.stderr


def load_check(report: Path, tmp: Path) -> tuple[int, int, list[str]]:
    """(images, images not loaded, console lines): the report as is, then a copy with a load check."""
    _, err = chromium(report, tmp)
    console = [line for line in err.splitlines() if ":CONSOLE" in line]
    probe = tmp / "probe.html"
    probe.write_text(report.read_text(encoding="utf-8").replace("</body>", CHECK + "</body>"), "utf-8")
    dom, _ = chromium(probe, tmp)
    found = re.search(r'data-imgs="(\d+)" data-bad="(\d+)"', dom)
    assert found, dom[:500]
    return int(found.group(1)), int(found.group(2)), console


needs_chromium = pytest.mark.skipif(
    not CHROMIUM.exists(), reason="/usr/bin/chromium not installed (apt-get install chromium; .ci/run does)"
)


@needs_chromium
def test_report_loads_in_headless_chromium(report: str, tmp_path: Path) -> None:
    page = tmp_path / "report.html"
    page.write_text(report, encoding="utf-8")
    images, bad, console = load_check(page, tmp_path)
    assert (images, bad, console) == (len(IMG.findall(report)), 0, [])


@needs_chromium
def test_chromium_check_catches_broken_images_and_console_errors(tmp_path: Path) -> None:
    page = tmp_path / "broken.html"
    page.write_text('<!DOCTYPE html><html><body><img src="data:image/png;base64,AAAA">'
                    '<script>console.error("boom")</script></body></html>')  # fmt: skip
    images, bad, console = load_check(page, tmp_path)
    assert (images, bad) == (1, 1) and any("boom" in line for line in console)


def test_report_command_rebuilds_a_moved_folder_with_other_calls_merged(
    bench: BenchmarkConfig, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``spikenerf report OUT [RESULTS…]``: the report of a finished benchmark folder, moved after it ran,
    its tables joined by another call's seed; a folder without results and a cell held twice are refused."""
    import dataclasses
    import json
    import shutil

    from spikenerf.pipelines.benchmark.results import write_all

    done = tmp_path / "done"
    shutil.copytree(bench.out, done)
    cfg = dataclasses.replace(bench, out=done)
    cells = [read_cell(run_dir(cfg, SCENE, "gray", "nerf-gt"), SCENE, "gray", "nerf-gt")]
    write_all(cfg, cells, [])  # type: ignore[arg-type]
    other = json.loads((done / "results.json").read_text())
    for cell in other["cells"]:
        cell.update(seed=1, psnr=cell["psnr"] + 0.5)
    (tmp_path / "seed1.json").write_text(json.dumps(other))
    moved = tmp_path / "moved"
    done.rename(moved)
    (moved / "report.html").unlink(missing_ok=True)
    _cli("report", moved, tmp_path / "seed1.json", "--no-progress")
    assert capsys.readouterr().out.strip() == f"wrote {moved / 'report.html'}"
    page = (moved / "report.html").read_text(encoding="utf-8")
    assert "over 2 training seeds (0, 1)" in page and "seed 1): LPIPS" not in page
    assert "± 0.35" in page  # nerf-gt's PSNR over the two seeds: std of x and x + 0.5
    assert "as recorded in results.json" in page
    figures = len(data_uri_pngs(page))
    assert figures >= 3  # the figures of the moved folder's own runs
    # the folder of the other call (--seeds 1: its runs are VARIANT-seed1) as OUT: its figures show its runs
    seed1 = tmp_path / "seed1"
    shutil.copytree(moved, seed1)
    (seed1 / "runs" / SCENE / "gray" / "nerf-gt").rename(seed1 / "runs" / SCENE / "gray" / "nerf-gt-seed1")
    (seed1 / "results.json").write_text(json.dumps({**other, "config": {**other["config"], "seeds": [1]}}))
    _cli("report", seed1, moved / "results.json", "--no-progress")
    page = (seed1 / "report.html").read_text(encoding="utf-8")
    assert len(data_uri_pngs(page)) == figures and "nerf-gt-seed1" in page  # not the missing seed-0 runs
    for args, words in (([tmp_path], "no results.json: not a finished benchmark folder"),
                        ([moved, moved / "results.json"], "is also in an earlier file")):  # fmt: skip
        with pytest.raises(SystemExit) as exit_:
            _cli("report", *args, "--no-progress")
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and words in err and err.count("\n") == 1
