"""``benchmark --seeds``: parsing, mean ± std tables, the paired differences table, a tiny 2-seed run."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import pytest

from spikenerf.cli import main
from spikenerf.core.errors import InputError
from spikenerf.pipelines.benchmark import BenchmarkConfig, cell_keys, parse_seeds, run_benchmark, run_dir
from spikenerf.pipelines.benchmark.stats import differences, summarize
from spikenerf.pipelines.benchmark.tables import (
    Cell,
    differences_table,
    table1_markdown,
    table2_markdown,
    to_markdown,
)
from spikenerf.pipelines.suite import benchmark_with_report

#: t(0.975, dof) from printed tables (independent of scipy)
T975 = {2: 4.302653, 3: 3.182446}


def test_parse_seeds_and_bad_seeds(capsys: pytest.CaptureFixture[str]) -> None:
    assert parse_seeds("0,1,2") == [0, 1, 2] and parse_seeds(" 7 ") == [7]
    ints = "expected comma-separated integers"
    for bad, words in [("0,1,1", "seed 1 is given twice"), ("0,x", ints), ("1.5", ints), ("", ints),
                       ("-1", "non-negative")]:  # fmt: skip
        with pytest.raises(InputError, match=words):
            parse_seeds(bad)
    for bad in ("0,0", "a,b", "0,,1"):
        with pytest.raises(SystemExit) as exit_:
            main(["benchmark", "--scenes", "analytic-orbs", "--out", "never", "--seeds", bad])
        err = capsys.readouterr().err.strip()
        assert exit_.value.code == 2 and len(err.splitlines()) == 1 and "--seeds" in err, err
    assert not Path("never").exists()


def _cells(diffs: list[float], metric: str = "psnr") -> list[Cell]:
    """spike-nerf and nerf-recon on 2 scenes × 2 seeds whose paired PSNR differences are ``diffs``."""
    keys = [("s1", 0), ("s1", 1), ("s2", 0), ("s2", 1)][: len(diffs)]
    cells = []
    for (scene, seed), d in zip(keys, diffs, strict=True):
        base = 20.0 + seed + (scene == "s2")
        cells += [Cell(scene, "nerf-recon", "gray", base, 0.8, 0.2, seed=seed),
                  Cell(scene, "spike-nerf", "gray", base + d, 0.8, 0.2 - d / 10, seed=seed)]  # fmt: skip
    return cells


def test_differences_known_interval_and_verdicts() -> None:
    shown = {(d.metric): d for d in differences(_cells([1.0, 1.2, 0.8, 1.1]), ["gray"])}
    psnr = shown["psnr"]
    half = T975[3] * math.sqrt(0.0875 / 3) / 2  # sd of the four differences = sqrt(0.0875 / 3)
    assert (psnr.ours, psnr.baseline, psnr.n) == ("spike-nerf", "nerf-recon", 4)
    assert psnr.mean == pytest.approx(1.025) and psnr.low == pytest.approx(1.025 - half, abs=1e-5)
    assert psnr.high == pytest.approx(1.025 + half, abs=1e-5)
    # per-seed means 0.9 and 1.15: sd 0.25/√2, one degree of freedom → the seed-level interval contains 0
    seed_half = 12.706205 * 0.25 / 2
    assert psnr.seed_low == pytest.approx(1.025 - seed_half, abs=1e-5) and psnr.seed_low < 0 < psnr.low
    assert psnr.seed_high == pytest.approx(1.025 + seed_half, abs=1e-5) and psnr.verdict == "not shown"
    tight = {d.metric: d for d in differences(_cells([1.0, 1.0, 1.2, 1.21]), ["gray"])}  # seeds 1.1, 1.105
    assert tight["psnr"].seed_low == pytest.approx(1.1025 - 12.706205 * 0.0025, abs=1e-5)
    assert tight["psnr"].verdict == "shown" and tight["lpips"].verdict == "shown"
    assert tight["lpips"].mean < 0  # lower LPIPS is the claimed side
    assert shown["ssim"].verdict == "not shown" and shown["ssim"].low == 0 == shown["ssim"].high  # ties
    wide = differences(_cells([1.0, 2.0, 3.0]), ["gray"], metrics=["psnr"])[0]
    assert wide.low == pytest.approx(2 - T975[2] / math.sqrt(3), abs=1e-5) and wide.low < 0 < wide.high
    assert wide.verdict == "not shown"
    worse = differences(_cells([-1.0, -1.2, -0.8, -1.1]), ["gray"], metrics=["psnr"])[0]
    assert worse.verdict == "not shown (reversed)"
    single = differences(_cells([5.0]), ["gray"], metrics=["psnr"])[0]
    assert single.n == 1 and single.low is None and single.verdict == "not shown"
    assert differences(_cells([1.0, 2.0]), ["rgb"]) == []  # no rgb cells
    one_seed = [Cell(s, v, "gray", 20.0 + i + (v == "spike-nerf") * d, 0.8, 0.2, seed=0)
                for i, (s, d) in enumerate([("s1", 1.0), ("s2", 1.2), ("s3", 1.1)])
                for v in ("nerf-recon", "spike-nerf")]  # fmt: skip
    scenes_only = differences(one_seed, ["gray"], metrics=["psnr"])[0]  # 3 scenes, one training seed
    assert scenes_only.low is not None and scenes_only.low > 0  # the interval excludes 0 across scenes …
    assert scenes_only.verdict == "not shown (one seed)"  # … but seed noise is not in it
    md = to_markdown(differences_table([psnr, tight["psnr"], wide]))
    row = "| Spike-NeRF (paper) − NeRF + TFP reconstruction | gray | PSNR ↑ | 4 |"
    assert f"{row} +1.03 ± 0.17 | [+0.75, +1.30] | [-0.56, +2.61] | not shown |" in md
    assert f"{row} +1.10 ± 0.12 | [+0.91, +1.29] | [+1.07, +1.13] | **shown** |" in md
    assert "**shown**" in md and md.rstrip().endswith("| not shown |")


def test_a_difference_without_spread_or_with_infinite_scores_claims_nothing() -> None:
    same = differences(_cells([1.0, 1.0, 1.0, 1.0]), ["gray"], metrics=["psnr"])[0]
    assert same.low == same.high == pytest.approx(1.0) and same.verdict == "not shown"  # no spread measured
    cells = _cells([1.0, 1.2, 0.8, 1.1])
    perfect = [  # both variants of scene s1, seed 0 render it exactly
        c if c.scene != "s1" or c.seed else dataclasses.replace(c, psnr=math.inf) for c in cells
    ]
    psnr = differences(perfect, ["gray"], metrics=["psnr"])[0]  # inf − inf is no difference: left out
    assert psnr.n == 3 and math.isfinite(psnr.mean)


def test_tables_show_mean_and_std_over_seeds() -> None:
    cells = _cells([1.0, 1.2, 0.8, 1.1])
    md = table1_markdown(
        cells, ["nerf-recon", "spike-nerf"], ["s1", "s2"], "gray", {"spike-nerf": "40 poses"}
    )
    row = next(line for line in md.splitlines() if line.startswith("| Spike-NeRF"))
    s1 = summarize([21.0, 22.2])  # seeds 0 and 1 on s1
    avg = summarize([(21.0 + 21.8) / 2, (22.2 + 23.1) / 2])  # per seed, the mean over scenes
    assert s1 is not None and avg is not None
    assert f"**{s1.mean:.2f} ± {s1.std:.2f}**" in row and f"**{avg.mean:.2f} ± {avg.std:.2f}**" in row
    assert row.startswith("| Spike-NeRF (paper) | 40 poses |") and "| method | trained on |" in md
    table2_markdown(cells, "gray")  # ablation rows missing: dashes, no error
    one = [c for c in cells if c.seed == 0]
    assert "±" not in table1_markdown(one, ["spike-nerf"], ["s1", "s2"], "gray")


def test_tiny_two_seed_benchmark(tmp_path: Path) -> None:
    train = [
        "--batch",
        "32",
        "--eval-every",
        "2",
        "--eval-views",
        "1",
        "--spike-window",
        "4",
        "--spike-pixels",
        "4",
    ]
    cfg = BenchmarkConfig(["analytic-orbs"], ["nerf-blur", "spike-nerf"], ["gray"], tmp_path / "b", size=16,
                          frames=40, iters=2, device="cpu", test_views=1, render=False,
                          extra_train_args=train, seeds=[0, 1], blur_views="all")  # fmt: skip
    assert len(cell_keys(cfg)) == 4
    cells = benchmark_with_report(cfg)
    assert sorted((c.variant, c.seed) for c in cells) == [("nerf-blur", 0), ("nerf-blur", 1),
                                                          ("spike-nerf", 0), ("spike-nerf", 1)]  # fmt: skip
    assert (
        run_dir(cfg, "analytic-orbs", "gray", "spike-nerf", 0)
        == cfg.out / "runs/analytic-orbs/gray/spike-nerf"
    )
    seed1 = cfg.out / "runs/analytic-orbs/gray/spike-nerf-seed1"
    assert (seed1 / "metrics.json").is_file() and "seed: 1" in (seed1 / "config.yaml").read_text()
    results = json.loads((cfg.out / "results.json").read_text())
    assert results["trained_on"] == {"nerf-blur": "40 blur views", "spike-nerf": "40 poses"}
    assert [(d["baseline"], d["metric"], d["n"]) for d in results["differences"]][:2] == [
        ("nerf-blur", "psnr", 2), ("nerf-blur", "ssim", 2)]  # fmt: skip
    assert "analytic-orbs/gray/spike-nerf/seed1" in results["commands"]["cells"]
    table = (cfg.out / "table1.md").read_text()
    assert "±" in table and "| NeRF on 400 fps blur | 40 blur views |" in table
    assert "Spike-NeRF (paper) − NeRF on 400 fps blur" in (cfg.out / "differences.md").read_text()
    page = (cfg.out / "report.html").read_text()
    assert "id='differences'" in page and "trained on" in page and "± " in page
    assert run_benchmark(cfg) == cells  # every seed's cell is reused on resume
    cfg.blur_views = "frames"
    with pytest.raises(InputError, match="blur_views 'all' → 'frames'"):
        run_benchmark(cfg)


def test_tiny_differences_print_their_digits_and_unfinished_cells_do_not_mix_scenes() -> None:
    """A difference too small for the table's precision shows 2 significant digits (not "+0.00 ± 0.00" next
    to "shown"); a seed missing a scene is averaged over the scenes every seed has."""
    tiny = differences(_cells([1.2e-4, 1.3e-4, 1.1e-4, 1.25e-4]), ["gray"], metrics=["psnr"])[0]
    row = to_markdown(differences_table([tiny])).splitlines()[-1]
    assert "| +0.00012 ± 8.5e-06 | [+0.00011, +0.00013] |" in row and row.endswith("| **shown** |")
    cells = _cells([1.0, 1.2, 0.8, 1.1])
    unfinished = [c for c in cells if not (c.scene == "s2" and c.seed == 1)]  # seed 1 lacks scene s2
    d = differences(unfinished, ["gray"], metrics=["psnr"])[0]
    assert d.n == 3 and d.seed_low is not None
    assert (d.seed_low + d.seed_high) / 2 == pytest.approx((1.0 + 1.2) / 2)  # s1 of both seeds only
