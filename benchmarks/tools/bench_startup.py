"""Wall time of the short commands (``info RUN``, ``eval RUN``) of this checkout against a reference build,
each a fresh process, interleaved: what a user waits for before anything is computed.

Usage (from the repository root)::

    .venv/bin/python -m benchmarks.tools.bench_startup RUN (--ref COMMIT | --ref-src PATH) [--rounds 5]
                                                       [--threads 1]

``--ref`` checks the commit out with ``git worktree add`` into a temporary folder (removed afterwards);
``--ref-src`` takes a ``src`` folder of another checkout instead. Each build runs on its own copy of RUN (eval
writes ``metrics.json`` into it), with its ``src`` first on ``PYTHONPATH``: ``spikenerf info COPY`` and
``spikenerf eval COPY --device cpu --lpips none --noref off --quiet`` (on every test view). Printed: every
time, the median of each command per build and the ratio reference / ours (above 1: ours starts faster).
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # the repository root
COMMANDS = {
    "info": ["info"],
    "eval": ["eval", "--device", "cpu", "--lpips", "none", "--noref", "off", "--quiet"],
}


def timed(src: Path, command: list[str], run: Path, threads: int) -> float:
    """Seconds of ``python -m spikenerf`` COMMAND RUN with ``src`` first on PYTHONPATH (must exit 0)."""
    env = {**os.environ, "PYTHONPATH": str(src), "OMP_NUM_THREADS": str(threads)}
    argv = [sys.executable, "-m", "spikenerf", command[0], str(run), *command[1:]]
    t0 = time.perf_counter()
    subprocess.run(argv, env=env, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def compare(run: Path, builds: dict[str, Path], rounds: int, threads: int, tmp: Path) -> dict[str, float]:
    """Time each command of each build ``rounds`` times, interleaved; print them; return the ratios
    reference / ours of the medians, per command."""
    copies = {name: tmp / f"run-{name}" for name in builds}
    for copy in copies.values():
        shutil.copytree(run, copy)
    for name, src in builds.items():  # untimed: the fused kernel built or found, caches warm
        timed(src, COMMANDS["info"], copies[name], threads)
    times: dict[tuple[str, str], list[float]] = {(c, b): [] for c in COMMANDS for b in builds}
    print("| round | command | build | seconds |")
    print("|---:|---|---|---:|")
    for r in range(rounds):
        for command, argv in COMMANDS.items():
            for name, src in builds.items():
                times[command, name].append(timed(src, argv, copies[name], threads))
                print(f"| {r} | {command} | {name} | {times[command, name][-1]:.2f} |", flush=True)
    ratios = {}
    for command in COMMANDS:
        ref, ours = (statistics.median(times[command, b]) for b in ("reference", "ours"))
        ratios[command] = ref / ours
        print(f"{command}: reference {ref:.2f} s, ours {ours:.2f} s (medians of {rounds}), "
              f"ratio {ratios[command]:.2f}×")  # fmt: skip
    return ratios


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a finished run folder")
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--ref", help="the reference commit (checked out into a temporary worktree)")
    which.add_argument("--ref-src", type=Path, help="the src folder of a reference checkout")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="bench_startup_") as tmp_name:
        tmp = Path(tmp_name)
        if args.ref_src is not None:
            return compare(args.run, {"reference": args.ref_src, "ours": ROOT / "src"}, args.rounds,
                           args.threads, tmp)  # fmt: skip
        ref = tmp / "ref"
        git = ["git", "-C", str(ROOT), "worktree"]
        subprocess.run([*git, "add", "--detach", str(ref), args.ref], check=True)
        try:
            return compare(args.run, {"reference": ref / "src", "ours": ROOT / "src"}, args.rounds,
                           args.threads, tmp)  # fmt: skip
        finally:
            subprocess.run([*git, "remove", "--force", str(ref)], check=False)


if __name__ == "__main__":
    main()
