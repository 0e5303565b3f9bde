"""``benchmarks/tools/bench_march.py``: a CPU smoke run at a tiny size. Every march it times gives the packed
march's samples (the timings it prints are measurements, docs/performance.md); the Triton rows appear where
the kernels run compiled (here forced, in Triton's CPU interpreter, to check their rows) and not otherwise."""

from __future__ import annotations

import re
import sys

import pytest

from helpers import load_benchmark
from spikenerf.fields import vm_triton

TOOL = load_benchmark("tools/bench_march")


def _rows(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> tuple[dict[str, str], str]:
    argv = ["bench_march", "--device", "cpu", "--rays", "96", "--resolution", "24", "--samples", "8"]
    monkeypatch.setattr(sys, "argv", [*argv, "--repeats", "1", "--rounds", "1"])
    TOOL.main()
    out = capsys.readouterr().out
    return dict(re.findall(r"^\| ([a-z ]+) \| [\d.]+ \| [\d.]+× \| ([\w ]+) \|$", out, flags=re.M)), out


def test_the_torch_marches_are_timed_against_the_packed_one_and_agree_with_it(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    rows, out = _rows(monkeypatch, capsys)
    assert rows == {"packed": "yes", "static": "yes"}, out
    assert "triton: not timed here" in out
    kept = float(re.search(r"([\d.]+) kept samples a ray of ([\d.]+) steps", out).group(1))
    assert 0 < kept < 8  # the shell culls most steps, and the budget holds the rest


@pytest.mark.skipif(not vm_triton.installed() or not vm_triton.interpreted(), reason="Triton's interpreter")
def test_the_triton_marches_give_the_same_samples(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(TOOL, "compiled", lambda x: True)
    rows, out = _rows(monkeypatch, capsys)
    assert rows == dict.fromkeys(("packed", "static", "triton packed", "triton static"), "yes"), out


def test_the_agreement_check_says_yes_only_for_the_whole_run_of_samples() -> None:
    torch = TOOL.torch
    ray, k = torch.tensor([0, 0, 1, 2, 2]), torch.tensor([1, 3, 0, 2, 5])
    assert TOOL.agreement((ray, k), (ray, k), 10) == "yes"
    assert TOOL.agreement((ray[:4], k[:4]), (ray, k), 10) == "first 4 of 5"  # a packed march that lost one
    assert TOOL.agreement((ray, k.flip(0)), (ray, k), 10) == "NO"
    keep = torch.tensor([True, True, True, False])
    budget = (torch.tensor([0, 0, 1, 3]), torch.tensor([1, 3, 0, 0]), keep)
    assert TOOL.agreement(budget, (ray, k), 3) == "yes"  # a budget of 3 slots: the first 3 samples
    assert TOOL.agreement(budget, (ray, k), 4) == "first 3 of 4"
