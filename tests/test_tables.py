"""Table I / Table II formatting: averages, best and second-best marks."""

from __future__ import annotations

from spikenerf.pipelines.benchmark.tables import Cell, cells_csv, rank_marks, table1_markdown, table2_markdown


def test_rank_marks_respects_metric_direction() -> None:
    assert rank_marks({"a": 30.0, "b": 25.0, "c": 28.0}, "psnr") == {"a": "best", "b": "", "c": "second"}
    assert rank_marks({"a": 0.3, "b": 0.1, "c": None}, "lpips") == {"a": "second", "b": "best", "c": ""}


def test_table1_averages_and_marks() -> None:
    cells = [
        Cell("s1", "spike-nerf", "gray", psnr=30.0, ssim=0.9),
        Cell("s2", "spike-nerf", "gray", psnr=26.0, ssim=0.8),
        Cell("s1", "nerf-blur", "gray", psnr=20.0, ssim=0.6),
        Cell("s2", "nerf-blur", "gray", psnr=22.0, ssim=0.7),
        Cell("s1", "nerf-blur", "rgb", psnr=99.0, ssim=0.99),  # other colour: ignored
    ]
    md = table1_markdown(cells, ["nerf-blur", "spike-nerf"], ["s1", "s2"], "gray")
    spike_row = next(line for line in md.splitlines() if line.startswith("| Spike-NeRF"))
    assert "**28.00**" in spike_row and "**0.850**" in spike_row
    blur_row = next(line for line in md.splitlines() if line.startswith("| NeRF on 400 fps blur"))
    assert "_21.00_" in blur_row


def test_table2_missing_lpips_shows_dash() -> None:
    cells = [
        Cell("s", v, "rgb", psnr=p, ssim=0.9)
        for v, p in [("spike-nerf", 29.0), ("spike-nerf-no-mask", 28.0), ("spike-nerf-no-spike-loss", 28.5)]
    ]
    md = table2_markdown(cells, "rgb")
    assert "| Spike-NeRF (paper) | **0.900** | **29.00** | – |" in md
    assert cells_csv(cells).splitlines()[0].startswith("scene,variant,color,psnr")


def test_values_that_print_the_same_get_the_same_mark() -> None:
    marks = rank_marks({"a": 12.793000, "b": 12.793295, "c": 12.70}, "psnr")  # both print 12.79
    assert marks == {"a": "best", "b": "best", "c": "second"}
