"""The differences beyond the paper's claims (``benchmarks/tools/learned_differences.py``): each scene's
paired PSNR differences, seed by seed."""

from __future__ import annotations

from spikenerf.pipelines.benchmark.tables import Cell, per_scene_table


def test_per_scene_rows_pair_the_same_seed_and_skip_missing_rows() -> None:
    cells = [Cell(scene, variant, "gray", psnr, 0.9, seed=seed) for scene, variant, seed, psnr in (
        ("toy", "spike-nerf", 0, 21.0), ("toy", "nerf-recon", 0, 20.5),
        ("toy", "spike-nerf", 1, 22.0), ("toy", "nerf-recon", 1, 22.3),
        ("food", "spike-nerf", 0, 30.0),  # no baseline cell: no pair
    )]  # fmt: skip
    table = per_scene_table(cells, (("spike-nerf", "nerf-recon"),)).splitlines()
    assert table[0] == "| scene | spike-nerf − nerf-recon |"
    assert table[2] == "| toy | +0.10 (+0.50, -0.30) |"  # mean of +0.50 and −0.30, seed 0 first
    assert table[3] == "| food | — |"
