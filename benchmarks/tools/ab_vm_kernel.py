"""The fused CPU VM kernel of two checkouts, forward and backward, in one process, interleaved (A/B).

Usage (from the repository root)::

    git worktree add /tmp/before HEAD~1
    .venv/bin/python -m benchmarks.tools.ab_vm_kernel /tmp/before/src/spikenerf/fields/vm_cpu.cpp \
        src/spikenerf/fields/vm_cpu.cpp [--points 100000] [--resolution 200] [--repeats 60] \
        [--threads 1,2]

Each file's C++ source (a ``vm_cpu.cpp``; in an older checkout the ``SOURCE`` string of its
``vm_cpu_source.py``, or the ``_SOURCE`` of its ``vm_kernel.py``) is built with this checkout's flags
(``--before-cflags`` gives the
before build others: to measure a flag change, pass the same file twice) under a name of its own (the
first build of a source takes about a minute, then it is cached), so both run in the same process on the
same tensors: the density's form (16 channels, summed, a zero gradient at every third point, as early ray
termination leaves them) and the appearance's (24 channels, (M, 3, C) out). Points lie along random rays,
64 samples a cell apart (``bench_lookup.ray_points``). For each thread count and form: ``--repeats`` backward
calls of each build, alternating which goes first, after 3 untimed; then as many forward calls. The points'
gradient (``point_backward``) too where both sources have it. Printed: the median ms of each, the median of
the per-call ratios before / after (above 1: after is faster) with its quartiles, and the largest difference
of the outputs and gradients.
"""

from __future__ import annotations

import argparse
import ast
import statistics
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import torch
from torch.utils.cpp_extension import load_inline

from benchmarks.tools.bench_lookup import ray_points
from spikenerf.fields import vm_build


def kernel_source(path: Path) -> str:
    """The text of a ``.cpp`` file; or, from an older checkout, the ``SOURCE`` string of a
    ``vm_cpu_source.py`` or the ``_SOURCE`` string of a ``vm_kernel.py`` (read, not imported: both would
    register one op)."""
    if path.suffix == ".cpp":
        return path.read_text(encoding="utf-8")
    for node in ast.parse(path.read_text()).body:
        names = {getattr(t, "id", "") for t in node.targets} if isinstance(node, ast.Assign) else set()
        if names & {"SOURCE", "_SOURCE"}:
            return ast.literal_eval(node.value)
    raise SystemExit(f"{path}: no SOURCE (or _SOURCE) string")


def build(source: str, tag: str, cflags: list[str] | None = None) -> Any:
    """The extension module of ``source``, built with this checkout's flags, or ``cflags`` in their place
    (cached by source and flags)."""
    flags = (vm_build._CFLAGS if cflags is None else cflags) + vm_build._OPENMP_CFLAGS
    ldflags = vm_build._OPENMP_LDFLAGS
    name = vm_build._name(flags, ldflags, source, prefix=f"ab_vm_{tag}_")
    return load_inline(name, cpp_sources=[source], extra_cflags=flags, extra_ldflags=ldflags, with_cuda=False)


def timed(calls: dict[str, Callable[[], Any]], repeats: int) -> dict[str, list[float]]:
    """Seconds of each call, ``repeats`` times, alternating which build goes first, after 3 untimed each."""
    for fn in calls.values():
        for _ in range(3):
            fn()
    times: dict[str, list[float]] = {name: [] for name in calls}
    for i in range(repeats):
        for name in list(calls) if i % 2 == 0 else list(calls)[::-1]:
            start = time.perf_counter()
            calls[name]()
            times[name].append(time.perf_counter() - start)
    return times


def report(what: str, times: dict[str, list[float]]) -> None:
    before, after = times["before"], times["after"]
    ratios = sorted(b / a for b, a in zip(before, after, strict=True))
    q = len(ratios) // 4
    print(
        f"| {what} | {1e3 * statistics.median(before):.2f} | {1e3 * statistics.median(after):.2f} | "
        f"{statistics.median(ratios):.3f}× ({ratios[q]:.3f}–{ratios[-q - 1]:.3f}) |",
        flush=True,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "before",
        type=Path,
        help="a checkout's src/spikenerf/fields/vm_cpu.cpp (vm_cpu_source.py, then vm_kernel.py, before it)",
    )
    parser.add_argument("after", type=Path, help="another (this checkout's, say)")
    parser.add_argument("--points", type=int, default=100_000)
    parser.add_argument("--resolution", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=60)
    parser.add_argument("--threads", default="1,2", help="thread counts, comma-separated")
    parser.add_argument(
        "--before-cflags",
        help="compiler flags of the before build instead of this checkout's (a flag change: give the same "
        "file twice), e.g. '-O3 -march=native'",
    )  # fmt: skip
    args = parser.parse_args()
    before_flags = None if args.before_cflags is None else args.before_cflags.split()
    modules = {
        "before": build(kernel_source(args.before), "before", before_flags),
        "after": build(kernel_source(args.after), "after"),
    }
    print(f"flags: before {' '.join(before_flags or vm_build._CFLAGS)}; after {' '.join(vm_build._CFLAGS)}")
    r, gen = args.resolution, torch.Generator().manual_seed(0)
    xyz = ray_points(args.points, r, torch.device("cpu"))
    print(f"{args.points} points along rays, R {r}; ms per call, median of {args.repeats}")
    print("| call | before ms | after ms | before / after (quartiles) |\n|---|---:|---:|---:|")
    for threads in (int(t) for t in args.threads.split(",")):
        torch.set_num_threads(threads)
        for c, summed in ((16, True), (24, False)):
            planes, lines = torch.randn(3, r, r, c, generator=gen), torch.randn(3, r, c, generator=gen)
            grad = torch.randn((xyz.shape[0],) if summed else (xyz.shape[0], 3, c), generator=gen)
            if summed:
                grad[::3] = 0.0
            form = f"{threads} thread(s), C {c}{' summed' if summed else ''}"
            back = {t: partial(m.backward, planes, lines, xyz, grad) for t, m in modules.items()}
            fwd = {t: partial(m.forward, planes, lines, xyz, summed) for t, m in modules.items()}
            report(f"backward, {form}", timed(back, args.repeats))
            report(f"forward, {form}", timed(fwd, args.repeats))
            outs = {t: [fwd[t](), *back[t]()] for t in modules}
            if all(hasattr(m, "point_backward") for m in modules.values()):  # (a kernel from stop 68 on)
                point = {t: partial(m.point_backward, planes, lines, xyz, grad) for t, m in modules.items()}
                report(f"points' gradient, {form}", timed(point, args.repeats))
                outs = {t: [*outs[t], point[t]()] for t in modules}
            diff = max((a - b).abs().max().item() for a, b in zip(outs["before"], outs["after"], strict=True))
            print(f"|   largest difference (output, gradients) | {diff:.1e} | | |")


if __name__ == "__main__":
    main()
