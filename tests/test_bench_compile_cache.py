"""``benchmarks/tools/bench_compile_cache.py``: which cache each child finds, and the compile seconds it
reports (the timings themselves are measurements, docs/performance.md)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from helpers import load_benchmark

TOOL = load_benchmark("tools/bench_compile_cache")


def test_compile_seconds_are_the_time_beyond_the_median_steps() -> None:
    assert TOOL.compile_seconds([0.1, 0.1, 30.1, 0.1, 5.1]) == pytest.approx(35.0)
    assert TOOL.compile_seconds([0.2] * 4) == pytest.approx(0.0)


def test_the_warm_child_finds_the_first_childs_cache_and_the_two_graph_child_a_cold_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[tuple[list[str], str]] = []
    steps = {"1": [[60.0, 0.1, 0.1], [8.0, 0.1, 0.1]], "2": [[40.0, 0.1, 30.0, 0.1, 0.1]]}

    def fake_run(argv: list[str], env: dict | None = None, **_: object) -> subprocess.CompletedProcess:
        calls.append((argv, (env or {}).get("TORCHINDUCTOR_CACHE_DIR", "")))
        graphs = argv[argv.index("--graphs") + 1]
        out = json.dumps({"steps": steps[graphs].pop(0)}) + "\n"
        return subprocess.CompletedProcess(argv, 0, stdout=out, stderr="")

    monkeypatch.setattr(TOOL.subprocess, "run", fake_run)
    monkeypatch.setattr(sys, "argv", ["bench_compile_cache", "--dataset", str(tmp_path), "--iters", "3"])
    TOOL.main()
    (_, cold), (_, warm), (argv, other) = calls
    assert cold == warm != other and argv[argv.index("--graphs") + 1] == "2"
    out = capsys.readouterr().out
    assert "one graph, cold cache: compiling 59.9 s (step 0: 60.0 s)" in out
    assert "two graphs, cold cache: compiling 69.8 s" in out  # 70.3 s less 5 × 0.1 s
    assert "two graphs / one graph (cold): 1.17×; one graph, cold / warm cache: 7.6×" in out


def test_a_failing_child_stops_the_run_with_its_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def failing(argv: list[str], **_: object) -> subprocess.CompletedProcess:
        return subprocess.CompletedProcess(argv, 1, stdout="", stderr="Traceback …\nRuntimeError: no CUDA\n")

    monkeypatch.setattr(TOOL.subprocess, "run", failing)
    monkeypatch.setattr(sys, "argv", ["bench_compile_cache", "--dataset", str(tmp_path)])
    failed = r"(?s)one graph, cold cache: the child failed \(exit 1\):\n.*no CUDA"
    with pytest.raises(SystemExit, match=failed):
        TOOL.main()
