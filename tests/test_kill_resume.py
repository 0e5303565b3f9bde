"""Kill and resume: SIGKILL ``simulate``, ``import``, ``train`` and ``render`` at three points each, resume,
compare with an uninterrupted run; two concurrent writers; a stale lock; a truncated cache frame
(docs/reliability.md).

Kills are real SIGKILLs delivered at named fail points (``SPIKENERF_KILL_AT``, see core/faults.py), so the
place of each kill is exact and the test is deterministic.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import torch
import yaml

from helpers import BENCHMARK_TRAIN
from spikenerf.camera.io import read_dat, write_dat
from spikenerf.cli import RESUME_HINTS, main
from spikenerf.core.faults import KILL_ENV
from spikenerf.core.lock import holder, lock_path
from spikenerf.core.marker import mark
from spikenerf.data.writer import work_dir
from spikenerf.eval.render_cache import CACHE
from spikenerf.pipelines.benchmark import BenchmarkConfig, run_benchmark

SIM = ["simulate", "--scene", "analytic-orbs", "--width", "16", "--height", "16", "--frames", "60",
       "--test-views", "2", "--gt-every", "7", "--blur-fps", "4000", "--no-progress"]  # fmt: skip
TRAIN = ["--iters", "6", "--batch", "32", "--eval-every", "3", "--eval-views", "1", "--ckpt-every", "2",
         "--spike-warmup", "1", "--spike-window", "4", "--spike-pixels", "4", "--device", "cpu", "--quiet",
         "--field-option", "n_voxels_init=512", "--field-option", "n_voxels_final=1000"]  # fmt: skip

#: an orbit pose source needs no COLMAP; 600 steps are three chunks of the spike copy (CHUNK_FRAMES 256)
IMPORT = ["--poses", "orbit", "--orbit", "4,30", "--fov", "40", "--keyframe-every", "100", "--window", "5",
          "--test-every", "2"]  # fmt: skip


def _cli(*args: object) -> None:
    main([str(a) for a in args])


def _spawn(args: list[object], point: str | None = None) -> subprocess.Popen[str]:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    if point:
        env[KILL_ENV] = point
    command = [sys.executable, "-m", "spikenerf", *map(str, args)]
    return subprocess.Popen(command, env=env, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _stat(proc: Path) -> list[str]:
    """Fields of ``/proc/PID/stat`` after the command name (state, ppid, pgrp, …); [] when it is gone."""
    try:
        return (proc / "stat").read_text().rpartition(")")[2].split()
    except OSError:
        return []


def _stopped(pid: int) -> bool:
    """Whether process ``pid`` is frozen by SIGSTOP (state ``T``)."""
    return _stat(Path(f"/proc/{pid}"))[:1] == ["T"]


def _killed_at(args: list[object], point: str) -> None:
    done = _spawn(args, point)
    _, err = done.communicate(timeout=120)
    assert done.returncode == -signal.SIGKILL, f"not killed at {point}: rc {done.returncode}\n{err}"


def _files(root: Path) -> dict[str, bytes]:
    """Every file's bytes; config.yaml without its ``command`` line (it records the --out path)."""
    files = {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}
    config = yaml.safe_load(files["config.yaml"])
    command = config.pop("command")
    assert command.startswith("spikenerf ") and f"--out {root}" in command, command
    files["config.yaml"] = yaml.safe_dump(config).encode()
    return files


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An uninterrupted dataset and run."""
    root = tmp_path_factory.mktemp("reference")
    _cli(*SIM, "--out", root / "ds")
    _cli("train", root / "ds", *TRAIN, "--out", root / "run")
    spikes = (np.random.default_rng(0).random((600, 16, 16)) < 0.3).astype(np.uint8)
    write_dat(root / "rec" / "stream.dat", spikes)
    (root / "rec" / "config.yaml").write_text("spike_h: 16\nspike_w: 16\nfps: 20000\n")
    _cli("import", root / "rec" / "stream.dat", *IMPORT, "--out", root / "imported")
    return root


@pytest.mark.parametrize(
    "point", ["simulate.render:5", "write:00003.npy:1", "simulate.spikes:30", "simulate.publish:1"]
)
def test_simulate_killed_then_resumed_is_bit_identical(reference: Path, tmp_path: Path, point: str) -> None:
    out = tmp_path / "ds"
    _killed_at([*SIM, "--out", out], point)
    assert not out.exists() and work_dir(out).is_dir()
    frames = sorted((work_dir(out) / ".frames").glob("*.npy"))
    if point == "simulate.render:5":  # a cache frame cut short (disk full, a copy interrupted) is re-rendered
        assert len(frames) == 5
        frames[-1].write_bytes(frames[-1].read_bytes()[:50])
    if point.startswith("write:"):  # killed inside a frame's atomic write: its temporary is left
        assert [p.name[:10] for p in (work_dir(out) / ".frames").glob(".*.tmp")] == [".00003.npy"]
    _cli(*SIM, "--out", out)
    assert _files(out) == _files(reference / "ds")
    assert not work_dir(out).exists() and not lock_path(out).exists()


@pytest.mark.parametrize("point", ["import.keyframe:3", "import.spikes:2", "import.publish:1"])
def test_import_killed_then_rerun_is_bit_identical(reference: Path, tmp_path: Path, point: str) -> None:
    out, rec = tmp_path / "ds", reference / "rec" / "stream.dat"
    _killed_at(["import", rec, *IMPORT, "--out", out], point)
    assert not out.exists() and work_dir(out).is_dir()
    if point == "import.spikes:2":  # killed mid-copy: a partial spike file is left in the work folder
        assert (work_dir(out) / "spikes_gray.dat").stat().st_size == 2 * 256 * 16 * 16 // 8
    _cli("import", rec, *IMPORT, "--out", out)
    assert _files(out) == _files(reference / "imported")
    assert not work_dir(out).exists() and not lock_path(out).exists()


def _state(run: Path) -> dict[str, torch.Tensor]:
    ckpt = torch.load(run / "checkpoint.pt", weights_only=True)
    flat = {f"model.{k}": v for k, v in ckpt["model"].items()}
    for i, group in ckpt["optimizer"]["state"].items():
        flat.update({f"adam.{i}.{k}": torch.as_tensor(v) for k, v in group.items()})
    return flat


def _curves(run: Path) -> list[tuple[str, str, str]]:
    with (run / "curves.csv").open() as fh:
        return [(r["iteration"], r["train_psnr"], r["test_psnr"]) for r in csv.DictReader(fh)]


@pytest.mark.parametrize("point", ["train.iteration:1", "write:checkpoint.pt:2", "train.iteration:5"])
def test_train_killed_then_resumed_is_bit_identical(reference: Path, tmp_path: Path, point: str) -> None:
    run = tmp_path / "run"
    _killed_at(["train", reference / "ds", *TRAIN, "--out", run], point)
    if point.startswith("write:"):  # killed mid-write: the finished temporary never replaced the checkpoint
        assert list(run.glob(".checkpoint.pt.*.tmp"))
    _cli("train", reference / "ds", *TRAIN, "--resume", "--out", run)
    want, got = _state(reference / "run"), _state(run)
    assert want.keys() == got.keys() and all(torch.equal(want[k], got[k]) for k in want)
    # the train PSNR of the evaluation after the restart counts the batches before the kill too
    assert _curves(run) == _curves(reference / "run")
    assert not list(run.glob(".*.tmp")) and not lock_path(run).exists()


def test_train_with_holdout_killed_then_resumed_is_bit_identical(reference: Path, tmp_path: Path) -> None:
    """The restricted samplers (data/holdout.py) resume from the same checkpointed state."""
    args = [*TRAIN, "--holdout", "--holdout-steps", "2", "--holdout-radius", "3", "--spike-warmup", "0"]
    _cli("train", reference / "ds", *args, "--out", tmp_path / "whole")
    run = tmp_path / "run"
    _killed_at(["train", reference / "ds", *args, "--out", run], "train.iteration:3")
    _cli("train", reference / "ds", *args, "--resume", "--out", run)
    want, got = _state(tmp_path / "whole"), _state(run)
    assert want.keys() == got.keys() and all(torch.equal(want[k], got[k]) for k in want)
    assert _curves(run) == _curves(tmp_path / "whole")
    assert (run / "holdout.json").read_bytes() == (tmp_path / "whole" / "holdout.json").read_bytes()
    assert json.loads((run / "holdout.json").read_text())["check_steps"] == [20, 39]


#: 6 orbit views and an 80-step stream: spike states saved at steps 32 and 64 (SPIKE_STATE_EVERY)
RENDER = ["--trajectory", "orbit", "--orbit-frames", "6", "--spikes", "--spike-steps", "80", "--quiet"]


def _render_files(root: Path) -> dict[str, bytes]:
    """Every file's bytes; render.json without its ``seconds``."""
    files = {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}
    manifest = json.loads(files["render.json"])
    assert manifest.pop("seconds") >= 0
    files["render.json"] = json.dumps(manifest).encode()
    return files


@pytest.fixture(scope="module")
def rendered(reference: Path) -> Path:
    """An uninterrupted render of the reference run."""
    _cli("render", reference / "run", *RENDER, "--out", reference / "render")
    return reference / "render"


@pytest.mark.parametrize("point", ["render.view:3", "render.spikes:2", "write:spikes_gray.dat:1"])
def test_render_killed_then_rerun_is_bit_identical(
    reference: Path, rendered: Path, tmp_path: Path, point: str
) -> None:
    out = tmp_path / "render"
    _killed_at(["render", reference / "run", *RENDER, "--out", out], point)
    assert (out / CACHE / "key.json").is_file() and not (out / "render.json").exists()
    _cli("render", reference / "run", *RENDER, "--out", out)
    assert _render_files(out) == _render_files(rendered)
    assert not (out / CACHE).exists() and not lock_path(out).exists()


def test_a_rerun_render_reuses_what_it_kept_and_only_under_the_same_settings(
    reference: Path, rendered: Path, tmp_path: Path
) -> None:
    """Marked cache entries show up in the output: the views and the spike steps before the kill are not
    rendered again; with another orbit the cache is started afresh."""
    out, args = tmp_path / "render", ["render", reference / "run", *RENDER]
    _killed_at([*args, "--out", out], "render.spikes:2")  # all views and 64 spike steps kept
    with np.load(out / CACHE / "views" / "00000.npz") as data:
        view = dict(data)
    np.savez(out / CACHE / "views" / "00000.npz", **{**view, "color": np.full_like(view["color"], 7)})
    bits = out / CACHE / "spikes.bits"
    bits.write_bytes(b"\xff" * 32 + bits.read_bytes()[32:])  # the first step (16 × 16 bits): all fired
    _cli(*args, "--out", out)
    assert np.all(iio.imread(out / "images" / "00000.png") == 7)
    spikes, want = read_dat(out / "spikes_gray.dat", 16, 16), read_dat(rendered / "spikes_gray.dat", 16, 16)
    assert spikes[0].all() and not want[0].all() and np.array_equal(spikes[1:], want[1:])
    _killed_at([*args, "--out", out], "render.view:3")
    np.savez(out / CACHE / "views" / "00000.npz", **{**view, "color": np.full_like(view["color"], 7)})
    _cli("render", reference / "run", *RENDER[:3], "7", *RENDER[4:], "--out", out)  # 7 orbit views
    assert not np.all(iio.imread(out / "images" / "00000.png") == 7)


def test_a_render_after_a_killed_one_leaves_no_file_of_either_stale(reference: Path, tmp_path: Path) -> None:
    """The old render.json goes as a new render starts (its files are cleared), and the video an
    interrupted render wrote, listed in no render.json, goes with the next render of another trajectory."""
    out, run = tmp_path / "render", reference / "run"
    _cli("render", run, "--trajectory", "test", "--quiet", "--out", out)
    assert (out / "test.mp4").is_file() and (out / "render.json").is_file()
    _killed_at(["render", run, *RENDER, "--out", out], "render.spikes:1")  # orbit.mp4 written, no manifest
    assert (out / "orbit.mp4").is_file() and not (out / "test.mp4").exists()
    assert not (out / "render.json").exists()
    _cli("render", run, "--trajectory", "test", "--quiet", "--out", out)
    assert sorted(p.name for p in out.iterdir()) == [
        ".spikenerf",
        "depth",
        "images",
        "render.json",
        "test.mp4",
    ]


def test_second_writer_is_refused_naming_the_holder(
    reference: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "ds"
    first = _spawn([*SIM, "--out", out], "simulate.render:3:STOP")  # freezes holding the lock
    _refused_while_frozen(first, out, [[*SIM, "--out", out], [*SIM, "--overwrite", "--out", out]], capsys)
    assert _files(out) == _files(reference / "ds")  # the first writer finished undisturbed


def test_second_import_is_refused_while_one_writes(
    reference: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out, rec = tmp_path / "ds", reference / "rec" / "stream.dat"
    first = _spawn(["import", rec, *IMPORT, "--out", out], "import.keyframe:2:STOP")
    others = [["import", rec, *IMPORT, "--overwrite", "--out", out], [*SIM, "--out", out]]  # import, simulate
    _refused_while_frozen(first, out, others, capsys)
    assert _files(out) == _files(reference / "imported")


def _refused_while_frozen(
    first: subprocess.Popen[str], out: Path, others: list[list[object]], capsys: pytest.CaptureFixture[str]
) -> None:
    """Once ``first`` has frozen itself (SIGSTOP) holding ``out``'s lock, each of ``others`` is refused in one
    line naming the folder and the holder; then ``first`` is continued and must finish with exit 0."""
    try:
        deadline = time.monotonic() + 60
        while not _stopped(first.pid) and time.monotonic() < deadline and first.poll() is None:
            time.sleep(0.05)  # SIGCONT before the writer has frozen itself would leave it frozen for good
        assert _stopped(first.pid) and holder(out) == first.pid, "the first writer never took the lock"
        for second in others:
            with pytest.raises(SystemExit) as exit_:
                _cli(*second)
            err = capsys.readouterr().err.strip()
            assert exit_.value.code == 2 and err.count("\n") == 0
            assert str(out) in err and f"process {first.pid}" in err
    finally:
        first.send_signal(signal.SIGCONT)
    assert first.wait(timeout=120) == 0


def test_stale_lock_of_a_dead_process_is_taken_over(reference: Path, tmp_path: Path) -> None:
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True)
    out = tmp_path / "ds"
    lock_path(out).write_text(dead.stdout.decode())
    assert holder(out) == int(dead.stdout)
    _cli(*SIM, "--out", out)
    assert _files(out) == _files(reference / "ds") and not lock_path(out).exists()


#: two cells of a tiny benchmark; a checkpoint every 2 iterations, so a kill at iteration 3 resumes from one
BENCH = {"scenes": ["analytic-orbs"], "variants": ["nerf-gt", "nerf-blur"], "colors": ["gray"], "size": 16,
         "frames": 100, "iters": 4, "device": "cpu", "test_views": 1, "render": False,
         "extra_train_args": [*BENCHMARK_TRAIN, "--ckpt-every", "2", "--quiet"]}  # fmt: skip


def _stopped_in_group(pgid: int) -> list[int]:
    """PIDs of the stopped (SIGSTOP) processes of process group ``pgid`` (Linux /proc)."""
    found = []
    for proc in Path("/proc").iterdir():
        fields = _stat(proc) if proc.name.isdigit() else []
        if fields[:1] == ["T"] and int(fields[2]) == pgid:
            found.append(int(proc.name))
    return found


def _numbers(out: Path) -> list[dict]:
    """results.json's cells without their wall-clock times (training and evaluation)."""
    cells = json.loads((out / "results.json").read_text())["cells"]
    return [{k: v for k, v in c.items() if not k.endswith("seconds")} for c in cells]


def _kill_in_second_cell(out: Path, log: Path) -> None:
    """Run the benchmark in its own process group; every train stops (SIGSTOP) at iteration 3: the first
    cell's is let go on, and at the second cell's the whole group (benchmark and step) is SIGKILLed."""
    script = "; ".join([
        "from pathlib import Path",
        "from spikenerf.pipelines.benchmark import BenchmarkConfig, run_benchmark",
        f"run_benchmark(BenchmarkConfig(**{BENCH!r}, out=Path({str(out)!r})))",
    ])  # fmt: skip
    env = {**os.environ, "OMP_NUM_THREADS": "1", KILL_ENV: "train.iteration:3:STOP"}
    with log.open("w") as sink:
        bench = subprocess.Popen([sys.executable, "-c", script], env=env, stdout=sink,
                                 stderr=subprocess.STDOUT, start_new_session=True)  # fmt: skip
    first = out / "runs" / "analytic-orbs" / "gray" / "nerf-gt"
    try:
        deadline = time.monotonic() + 240
        while bench.poll() is None and time.monotonic() < deadline:
            stopped = _stopped_in_group(bench.pid)
            if stopped and (first / "metrics.json").is_file():  # the second cell's train, at iteration 3
                os.killpg(bench.pid, signal.SIGKILL)
                break
            for pid in stopped:  # the first cell's train
                os.kill(pid, signal.SIGCONT)
            time.sleep(0.02)
    finally:
        if bench.poll() is None:
            os.killpg(bench.pid, signal.SIGKILL)
    assert bench.wait(timeout=30) == -signal.SIGKILL, log.read_text()


def test_benchmark_killed_in_its_second_cell_resumes_without_redoing_the_first(tmp_path: Path) -> None:
    # the uninterrupted reference of the second cell (a cell's numbers do not depend on the other cells)
    ref = BenchmarkConfig(**{**BENCH, "variants": ["nerf-blur"]}, out=tmp_path / "ref")
    run_benchmark(ref)
    out = tmp_path / "bench"
    shutil.copytree(ref.out / "datasets", out / "datasets")  # the same dataset, simulated once
    mark(out, "benchmark")
    _kill_in_second_cell(out, tmp_path / "log")
    first, second = (out / "runs" / "analytic-orbs" / "gray" / v for v in BENCH["variants"])
    assert not (second / "metrics.json").exists() and (second / "checkpoint.pt").is_file()
    done = {p.name: p.stat().st_mtime_ns for p in first.iterdir()}
    run_benchmark(BenchmarkConfig(**BENCH, out=out))
    assert _numbers(out)[1] == _numbers(ref.out)[0]
    assert {p.name: p.stat().st_mtime_ns for p in first.iterdir()} == done  # the first cell was not re-run
    steps = json.loads((out / "results.json").read_text())["commands"]["this_run"]
    assert [(s["command"][1], "--resume" in s["command"]) for s in steps] == [
        ("train", True),
        ("eval", False),
    ]


def test_sigterm_unwinds_like_ctrl_c(reference: Path, tmp_path: Path) -> None:
    """SIGTERM: one line, exit 143, the lock released and no temporary left; the run then resumes."""
    run = tmp_path / "run"
    first = _spawn(["train", reference / "ds", *TRAIN, "--out", run], "train.iteration:3:STOP")
    try:
        deadline = time.monotonic() + 60
        while not _stopped(first.pid) and time.monotonic() < deadline and first.poll() is None:
            time.sleep(0.05)
        assert _stopped(first.pid) and holder(run) == first.pid
        first.send_signal(signal.SIGTERM)
    finally:
        first.send_signal(signal.SIGCONT)
    _, err = first.communicate(timeout=60)
    last = err.strip().splitlines()[-1]
    assert first.returncode == 143 and last == f"spikenerf: terminated ({RESUME_HINTS['train']})", err
    assert "--resume" in last
    assert "Traceback" not in err and not lock_path(run).exists() and not list(run.glob(".*.tmp"))
    _cli("train", reference / "ds", *TRAIN, "--resume", "--out", run)
    assert _curves(run) == _curves(reference / "run")


def test_resume_onto_a_dataset_simulated_again_is_refused(
    reference: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    ds, run = tmp_path / "ds", tmp_path / "run"
    shutil.copytree(reference / "ds", ds)
    _cli("train", ds, *TRAIN, "--iters", "2", "--out", run)
    _cli(*SIM, "--overwrite", "--threshold", "2", "--out", ds)  # the same folder, other spikes
    before = (run / "checkpoint.pt").read_bytes()
    capsys.readouterr()
    for command in (["train", ds, *TRAIN, "--resume", "--out", run], ["eval", run, "--device", "cpu"]):
        with pytest.raises(SystemExit) as exit_:
            _cli(*command)
        err = capsys.readouterr().err.strip()
        assert (
            exit_.value.code == 2
            and err.count("\n") == 0
            and "its files differ from those the run trained on" in err
        ), err
    assert (run / "checkpoint.pt").read_bytes() == before and not (run / "metrics.json").exists()
