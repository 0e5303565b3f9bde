"""Time to quality (issue 9, item 2; issue 27, item 6 on a GPU): test PSNR against training time.

Each (method, schedule) trains in its own process (``--threads`` threads each, ``--jobs`` at a time) with the
project's ``Trainer`` for up to ``--budget`` seconds of training; every ``--eval-seconds`` of training the
test PSNR on a fixed set of held-out views is measured (evaluation and the trainer's checkpoint writes are
excluded from both clocks). Each point records the training wall seconds and the process CPU seconds
(``time.process_time``, the clock that a shared, loaded machine distorts least) and the 1-minute load average.
``--clock`` picks which of the two the budget and the evaluation spacing count.

``--iters`` is the schedule length (learning-rate decay, grid upsampling, occupancy and spike-loss ramp all
rescale to it); a schedule that ends before the budget simply stops there. Several schedules may be given.

Prints, per run, the time to each ``--thresholds`` PSNR (25 and 28 dB unless given; the first evaluation at
or above, so an upper bound within one evaluation spacing) and the best PSNR, and per schedule the ratio of
every other method to ``nerf-gt`` (the reference) of the speed to each threshold (on ``--clock``) and of
the PSNR at the latest time both runs reached. ``--device cuda``, ``--compile`` and ``--field-option
KEY=VALUE`` go to every run (``train``'s options of the same names).

    spikenerf --threads 1 simulate --scene bricks --out data/bricks200       # 200×200 gray, needs Blender
    python -m benchmarks.experiments.bench_time_to_quality --dataset data/bricks200 --iters 1500,6000 \\
        --jobs 4 --budget 1800 --csv ttq.csv --plot ttq.png
    python -m benchmarks.experiments.bench_time_to_quality --summarize ttq.csv  # tables (and --plot) of a CSV
    # on a GPU: the oracle and the default spike method at 400×400, PSNR every 20 s of training
    python -m benchmarks.experiments.bench_time_to_quality --dataset orbs400 --device cuda --jobs 1 \\
        --runs nerf-gt:20000,spike-integral:20000 --batch 16384 --budget 240 --eval-seconds 20 \\
        --thresholds 28,30
"""

from __future__ import annotations

import argparse
import csv
import itertools
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import torch

from benchmarks._table import Row, format_table
from benchmarks.suites.bench_time_to_psnr import first_time_at
from benchmarks.tools.profile_cuda_step import field_option
from spikenerf.train.config import TrainConfig
from spikenerf.train.trainer import Trainer

METHODS = ("nerf-gt", "spike-nerf")
REFERENCE = "nerf-gt"
THRESHOLDS = (25.0, 28.0)


@dataclass
class Point:
    """One evaluation: the run (method, schedule length), its progress on both clocks, the test PSNR."""

    method: str
    iters: int
    iteration: int
    train_s: float
    cpu_s: float
    psnr: float
    load1: float


@dataclass
class Options:
    """What one worker trains and how long."""

    dataset: str
    budget: float
    eval_seconds: float
    clock: str  # "wall" | "cpu": the clock of the budget and of the evaluation spacing
    eval_views: int
    batch: int | None
    seed: int
    wall_limit: float  # stop (after the next evaluation) once this many seconds of wall time have passed
    device: str = "cpu"
    compile: bool = False
    field_options: tuple[str, ...] = ()  # train's --field-option KEY=VALUE texts, passed on as given


def write_points(path: Path, points: list[Point]) -> None:
    """Rewrite the CSV (one row per :class:`Point`) through a temporary file, so a reader never sees half."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow([f.name for f in fields(Point)])
        writer.writerows(list(asdict(p).values()) for p in points)
    tmp.replace(path)


def read_points(path: Path) -> list[Point]:
    with open(path, newline="", encoding="utf-8") as fh:
        return [
            Point(
                r["method"],
                int(r["iters"]),
                int(r["iteration"]),
                float(r["train_s"]),
                float(r["cpu_s"]),
                float(r["psnr"]),
                float(r["load1"]),
            )
            for r in csv.DictReader(fh)
        ]


def drain(device: torch.device) -> float:
    """Seconds spent waiting for ``device`` to finish its queued work (0 off CUDA)."""
    if device.type != "cuda":
        return 0.0
    t0 = time.perf_counter()
    torch.cuda.synchronize(device)
    return time.perf_counter() - t0


def train_curve(method: str, iters: int, opts: Options, out: Path, csv_path: Path) -> list[Point]:
    """Train one run, evaluating every ``opts.eval_seconds`` on ``opts.clock``; the CSV grows as it goes."""
    config = TrainConfig(
        dataset=opts.dataset,
        method=method,
        iters=iters,
        batch=opts.batch,
        seed=opts.seed,
        device=opts.device,
        eval_every=0,
        eval_views=opts.eval_views,
        ckpt_every=10**9,
        compile=opts.compile,
    )
    config.field_config = {**config.field_config, **dict(map(field_option, opts.field_options))}
    trainer = Trainer(config, out, progress=False)
    trainer.checkpoint = lambda: None  # type: ignore[method-assign]  # time training, not checkpoint writes
    views, trainer.test_views = trainer.test_views, None  # the trainer's own final evaluation is skipped
    if views is None:
        raise SystemExit(f"{opts.dataset}: the dataset has no test views")
    start, cpu, points = time.monotonic(), 0.0, []
    rate, next_eval, chunk = 0.0, opts.eval_seconds, 10

    def now() -> float:
        return cpu if opts.clock == "cpu" else trainer.elapsed

    while trainer.iteration < iters and now() < opts.budget:
        goal = min(next_eval, opts.budget)
        # the measured rate sizes the chunk; at most doubling it keeps a sudden load change from overshooting
        chunk = min(2 * chunk, max(1, round((goal - now()) * rate))) if rate > 0 else chunk
        before, c0, it0 = now(), time.process_time(), trainer.iteration
        trainer.train(stop_after=chunk)
        trainer.elapsed += drain(trainer.device)  # the GPU's queued steps count as training time
        cpu += time.process_time() - c0
        rate = (trainer.iteration - it0) / max(now() - before, 1e-9)
        out_of_time = time.monotonic() - start >= opts.wall_limit
        if now() >= next_eval or trainer.iteration >= iters or now() >= opts.budget or out_of_time:
            trainer.test_views = views
            psnr = trainer.evaluate()
            trainer.test_views = None
            point = Point(method, iters, trainer.iteration, trainer.elapsed, cpu, psnr, os.getloadavg()[0])
            points.append(point)
            write_points(csv_path, points)
            print(
                f"{method} ({iters} iters): it {point.iteration}, {point.train_s:.0f} s train, "
                f"{point.cpu_s:.0f} CPU s, {psnr:.2f} dB, load {point.load1:.1f}",
                flush=True,
            )
            while next_eval <= now():
                next_eval += opts.eval_seconds
            if out_of_time:
                break
    return points


def worker_options(opts: Options, threads: int) -> list[str]:
    """The command-line options that give a worker process ``opts`` (and ``threads`` threads)."""
    return [
        "--dataset",
        opts.dataset,
        "--budget",
        str(opts.budget),
        "--eval-seconds",
        str(opts.eval_seconds),
        "--clock",
        opts.clock,
        "--eval-views",
        str(opts.eval_views),
        *(("--batch", str(opts.batch)) if opts.batch is not None else ()),
        "--seed",
        str(opts.seed),
        "--wall-limit",
        str(opts.wall_limit),
        "--threads",
        str(threads),
        "--device",
        opts.device,
        *(("--compile",) if opts.compile else ()),
        *(a for text in opts.field_options for a in ("--field-option", text)),
    ]


def run_all(runs: list[tuple[str, int]], opts: Options, jobs: int, threads: int, csv_path: Path) -> None:
    """One worker process per run, ``jobs`` at a time, each with ``threads`` threads; merges their CSVs."""
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "MKL_NUM_THREADS": str(threads)}
    parts = [csv_path.with_name(f"{csv_path.stem}.{m}-{n}.csv") for m, n in runs]
    common = worker_options(opts, threads)
    pending = list(zip(runs, parts, strict=True))
    active: list[subprocess.Popen] = []
    while pending or active:
        while pending and len(active) < jobs:
            (method, iters), part = pending.pop(0)
            cmd = [
                sys.executable,
                "-m",
                "benchmarks.experiments.bench_time_to_quality",
                *common,
                "--worker",
                f"{method}:{iters}",
                "--csv",
                str(part),
            ]
            active.append(subprocess.Popen(cmd, env=env))
        time.sleep(1.0)
        for p in [p for p in active if p.poll() is not None]:
            active.remove(p)
            if p.returncode:
                raise SystemExit(f"a worker failed (exit {p.returncode}): {' '.join(map(str, p.args))}")
    write_points(csv_path, [pt for part in parts if part.exists() for pt in read_points(part)])


def summarize(points: list[Point], thresholds: tuple[float, ...] = THRESHOLDS, clock: str = "cpu") -> str:
    """Per run: times to the ``thresholds`` and best PSNR; per schedule: each method against nerf-gt, on
    ``clock`` ("cpu": process CPU seconds, "wall": training seconds)."""
    lines = [
        "| method | iters | iterations run | train s | CPU s | "
        + " | ".join(f"to {t:g} dB (train s / CPU s)" for t in thresholds)
        + " | best PSNR (at train s / CPU s) |"
    ]
    lines.append("|---|---:|---:|---:|---:|" + "---:|" * len(thresholds) + "---:|")
    rows: list[Row] = []
    methods = list(dict.fromkeys(p.method for p in points))  # in the order they ran
    for iters in sorted({p.iters for p in points}):
        runs = {m: [p for p in points if p.iters == iters and p.method == m] for m in methods}
        for method, pts in runs.items():
            if not pts:
                continue
            last, best = pts[-1], max(pts, key=lambda p: p.psnr)
            cells = []
            for t in thresholds:
                wall = first_time_at([(p.train_s, p.psnr) for p in pts], t)
                cpu = first_time_at([(p.cpu_s, p.psnr) for p in pts], t)
                cells.append("not reached" if wall is None else f"{wall:.0f} / {cpu:.0f}")
            lines.append(
                f"| {method} | {iters} | {last.iteration} | {last.train_s:.0f} | {last.cpu_s:.0f} | "
                + " | ".join(cells)
                + f" | {best.psnr:.2f} ({best.train_s:.0f} / {best.cpu_s:.0f}) |"
            )
        for method in methods:
            if method != REFERENCE:
                rows += ratio_rows(runs[method], runs.get(REFERENCE, []), iters, thresholds, clock)
    return "\n".join(lines) + ("\n\n" + format_table(rows) if rows else "")


def ratio_rows(
    ours: list[Point],
    ref: list[Point],
    iters: int,
    thresholds: tuple[float, ...] = THRESHOLDS,
    clock: str = "cpu",
) -> list[Row]:
    """A method (``ours``) against nerf-gt (``ref``): speed (1/s on ``clock``) to each threshold both
    reached, PSNR at equal time."""
    if not ours or not ref:
        return []

    def time_of(p: Point) -> float:
        return p.cpu_s if clock == "cpu" else p.train_s

    unit, rows, name = ("CPU s" if clock == "cpu" else "train s"), [], ours[0].method
    for t in thresholds:
        a = first_time_at([(time_of(p), p.psnr) for p in ours], t)
        b = first_time_at([(time_of(p), p.psnr) for p in ref], t)
        if a is not None and b is not None:
            rows.append(
                Row(f"{name}: speed to {t:g} dB, {iters} iters", 1 / a, 1 / b, f"1/{unit}", REFERENCE)
            )
    common = min(time_of(ours[-1]), time_of(ref[-1]))

    def at(pts: list[Point]) -> float:
        return max((p for p in pts if time_of(p) <= common), key=time_of, default=pts[0]).psnr

    rows.append(
        Row(f"{name}: PSNR at {common:.0f} {unit}, {iters} iters", at(ours), at(ref), "dB", REFERENCE)
    )
    return rows


def plot(
    points: list[Point],
    path: Path,
    thresholds: tuple[float, ...] = THRESHOLDS,
    clock: str = "cpu",
    title: str = "",
) -> None:
    """PSNR against time on ``clock``, one line per run, as a small PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.6), dpi=80)
    for (method, iters), pts in itertools.groupby(points, key=lambda p: (p.method, p.iters)):
        pts = list(pts)
        x = [(p.cpu_s if clock == "cpu" else p.train_s) / 60 for p in pts]
        ax.plot(x, [p.psnr for p in pts], marker=".", label=f"{method}, {iters} it")
    for t in thresholds:
        ax.axhline(t, color="gray", lw=0.6, ls="--")
    xlabel = "training CPU minutes" if clock == "cpu" else "training minutes (wall)"
    ax.set(xlabel=xlabel, ylabel="test PSNR (dB)", title=title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)


def _checked_option(text: str) -> str:
    """``--field-option``: checked here, kept as given (re-printing a parsed value could change its type)."""
    field_option(text)
    return text


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--dataset", help="a dataset folder (e.g. 200×200 bricks)")
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--iters", default="1500", help="schedule lengths, comma-separated")
    parser.add_argument("--runs", help="explicit METHOD:ITERS runs, comma-separated (instead of the product)")
    parser.add_argument("--budget", type=float, default=1800.0, help="training seconds per run (on --clock)")
    parser.add_argument(
        "--eval-seconds", type=float, default=60.0, help="training seconds between evaluations"
    )
    parser.add_argument(
        "--clock",
        choices=("wall", "cpu"),
        help="the clock of the budget and the ratios [wall; cpu with --summarize]",
    )
    parser.add_argument("--eval-views", type=int, default=8, help="held-out views evaluated (evenly spaced)")
    parser.add_argument("--batch", type=int, default=None, help="rays per step (default: each method's own)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1, help="threads per training process")
    parser.add_argument("--jobs", type=int, default=2, help="training processes at a time")
    parser.add_argument(
        "--wall-limit", type=float, default=float("inf"), help="wall seconds per run, at most"
    )
    parser.add_argument("--csv", type=Path, help="where the points go [default: a temporary file]")
    parser.add_argument("--plot", type=Path, help="a PNG of PSNR against time on --clock")
    parser.add_argument(
        "--summarize", type=Path, nargs="+", help="only print the tables (and --plot) of CSVs"
    )
    parser.add_argument("--thresholds", default="25,28", help="PSNRs (dB) whose times are reported")
    parser.add_argument("--device", default="cpu", help="the training device (train's --device)")
    parser.add_argument("--compile", action="store_true", help="train's --compile")
    parser.add_argument("--field-option", type=_checked_option, action="append", default=[],
                        metavar="KEY=VALUE", help="train's --field-option, for every run")  # fmt: skip
    parser.add_argument("--worker", help=argparse.SUPPRESS)  # METHOD:ITERS, one run (used by the parent)
    args = parser.parse_args()
    clock = args.clock or ("cpu" if args.summarize else "wall")  # the summaries of old CSVs were on CPU time
    if args.summarize:
        points = [p for path in args.summarize for p in read_points(path)]
    else:
        if not args.dataset:
            parser.error("--dataset is required (or --summarize CSV)")
        opts = Options(
            args.dataset,
            args.budget,
            args.eval_seconds,
            clock,
            args.eval_views,
            args.batch,
            args.seed,
            args.wall_limit,
            args.device,
            args.compile,
            tuple(args.field_option),
        )
        with tempfile.TemporaryDirectory(prefix="ttq-") as tmp:
            csv_path = args.csv or Path(tmp) / "ttq.csv"
            if args.worker:
                torch.set_num_threads(args.threads)
                method, iters = args.worker.split(":")
                train_curve(method, int(iters), opts, Path(tmp) / "run", csv_path)
                return
            runs = [(m, int(n)) for n in args.iters.split(",") for m in args.methods.split(",")]
            if args.runs:
                runs = [(r.split(":")[0], int(r.split(":")[1])) for r in args.runs.split(",")]
            run_all(runs, opts, args.jobs, args.threads, csv_path)
            points = read_points(csv_path)
    thresholds = tuple(float(t) for t in args.thresholds.split(","))
    print(summarize(points, thresholds, clock))
    if args.plot:
        title = "" if args.summarize else Path(args.dataset).name
        plot(points, args.plot, thresholds, clock, title)


if __name__ == "__main__":
    main()
