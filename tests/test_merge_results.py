"""Several benchmark folders' cells (a seed each) as one set of tables (``results.merged_markdown``, the
library behind ``benchmarks/tools/merge_results.py``)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from helpers import load_benchmark
from spikenerf.core.errors import InputError
from spikenerf.pipelines.benchmark.results import merged_markdown, read_results

CONFIG = {"scenes": ["a", "b"], "size": 16, "frames": 40, "iters": 2, "field_kind": "grid", "seed": 0,
          "test_views": 1, "blur_views": "all", "extra_train_args": []}  # fmt: skip


def _results(path: Path, seed: int, config: dict = CONFIG) -> Path:
    cells = [
        {"scene": scene, "variant": variant, "color": "gray", "psnr": psnr + 0.05 * seed, "ssim": 0.9,
         "lpips": None, "seconds": 1.0, "seed": seed}
        for scene, base in (("a", 20.0), ("b", 22.0))
        for variant, psnr in (("nerf-recon", base),
                              ("spike-nerf", base + 1.0 + 0.1 * (scene == "b") + 0.02 * seed))  # seeds differ
    ]  # fmt: skip
    path.write_text(json.dumps({"config": config, "cells": cells, "trained_on": {"spike-nerf": "9 poses"}}))
    return path


def _main(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], *paths: Path) -> str:
    """The script's output (a thin wrapper: it prints :func:`merged_markdown`)."""
    monkeypatch.setattr(sys, "argv", ["merge_results", *map(str, paths)])
    load_benchmark("tools/merge_results").main()
    out = capsys.readouterr().out
    assert out == merged_markdown(list(paths)) + "\n"
    return out


def test_two_seeds_from_two_folders_give_error_bars_and_a_verdict(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    out = _main(monkeypatch, capsys, _results(tmp_path / "0.json", 0), _results(tmp_path / "1.json", 1))
    assert "8 cells from 2 folders; Mean ± sample standard deviation over 2 training seeds (0, 1)." in out
    assert "| Spike-NeRF (paper) | 9 poses |" in out
    row = next(line for line in out.splitlines() if line.startswith("| Spike-NeRF (paper) − NeRF + TFP"))
    assert "| gray | PSNR ↑ | 4 | +1.06 ± 0.06 |" in row and row.endswith("**shown** |")
    one = _main(monkeypatch, capsys, tmp_path / "0.json")
    assert "One training seed (0)" in one and "not shown (one seed)" in one


def test_duplicate_cells_and_other_settings_are_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    first = _results(tmp_path / "0.json", 0)
    with pytest.raises(InputError, match=r"cell a/gray/nerf-recon/0 is also in an earlier file"):
        read_results([first, _results(tmp_path / "again.json", 0)])
    with pytest.raises(InputError, match=r"differs from .*0.json in iters"):
        read_results([first, _results(tmp_path / "1.json", 1, {**CONFIG, "iters": 3})])
    monkeypatch.setattr(sys, "argv", ["merge_results", str(first), str(tmp_path / "again.json")])
    with pytest.raises(SystemExit, match=r"again.json: cell a/gray/nerf-recon/0 is also in an earlier file"):
        load_benchmark("tools/merge_results").main()  # the script exits with the one line


def test_an_unreadable_or_foreign_results_file_is_one_line_naming_it(tmp_path: Path) -> None:
    """A missing file, bad JSON, or a JSON that is not a benchmark's results: an InputError naming the file
    (the script printed a traceback); an old file's ``seconds`` reads as the evaluation's."""
    bad, other = tmp_path / "bad.json", tmp_path / "other.json"
    bad.write_text("{not json")
    other.write_text(json.dumps({"cells": []}))
    for path, words in ((tmp_path / "missing.json", "cannot read"), (bad, "not a benchmark's results.json"),
                        (other, r"not a benchmark's results.json \(KeyError")):  # fmt: skip
        with pytest.raises(InputError, match=words) as err:
            read_results([path])
        assert err.value.path == str(path)
    cells = read_results([_results(tmp_path / "0.json", 0)])[1]
    assert cells[0].eval_seconds == 1.0 and cells[0].train_seconds is None
