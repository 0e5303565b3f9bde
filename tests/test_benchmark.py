"""The benchmark runner: parallel cells with per-step logs, resume, and failure handling."""

from __future__ import annotations

import json
import threading
import time
from dataclasses import replace
from pathlib import Path

import pytest

from helpers import BENCHMARK_TRAIN
from spikenerf.core.errors import InputError
from spikenerf.pipelines.benchmark import BenchmarkConfig, cell_keys, run_benchmark
from spikenerf.pipelines.benchmark.local_executor import _parallel
from spikenerf.pipelines.benchmark.run import other_finished_cells


def test_parallel_keeps_order_runs_at_once_and_stops_on_failure() -> None:
    running, peak, lock = [0], [0], threading.Lock()

    def task(i: int, fail: bool = False):  # type: ignore[no-untyped-def]
        def run() -> int:
            with lock:
                running[0] += 1
                peak[0] = max(peak[0], running[0])
            time.sleep(0.05 * (3 - i % 3))
            with lock:
                running[0] -= 1
            if fail:
                raise InputError(f"task {i} failed")
            return i

        return run

    assert _parallel([task(i) for i in range(6)], 2, "t", "task") == list(range(6))
    assert peak[0] == 2
    started: list[int] = []
    tasks = [task(0, fail=True)] + [lambda i=i: time.sleep(0.02) or started.append(i) for i in range(1, 40)]
    with pytest.raises(InputError, match="task 0 failed"):
        _parallel(tasks, 1, "t", "task")
    assert len(started) < 39  # the tasks not yet started were cancelled


def test_keep_going_runs_every_job_it_can_and_lists_the_failures_at_the_end(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Datasets ``a`` (fine) and ``b`` (fails); cells a1 (fails), a2 (fine), b1 (skipped: its dataset failed).
    Without ``keep_going`` the first failure stops the datasets' phase: no cell runs."""
    import sys
    from types import SimpleNamespace

    from spikenerf.pipelines.benchmark.local_executor import LocalExecutor
    from spikenerf.pipelines.benchmark.steps import Job

    def job(name: str, ok: bool, needs: str | None = None) -> Job:
        code = f"open({str(tmp_path / name)!r}, 'w').close()" if ok else "raise SystemExit(3)"
        return Job(name, lambda root: [[sys.executable, "-c", code, name]], name, f"{name}.done", needs)

    jobs = [
        job("a", True),
        job("b", False),
        job("a1", False, "a"),
        job("a2", True, "a"),
        job("b1", True, "b"),
    ]
    with pytest.raises(KeyError):  # a bug is no failed job: raised as it is, with its traceback
        broken = Job("x", lambda root: {}["key"], "x", "x.done")
        LocalExecutor().run(SimpleNamespace(out=tmp_path, jobs=1, keep_going=True), [broken], [], "n", print)
    for keep_going in (False, True):
        for name in ("a", "a2", "b1"):
            (tmp_path / name).unlink(missing_ok=True)
        done: list[str] = []
        cfg = SimpleNamespace(out=tmp_path, jobs=1, keep_going=keep_going)
        with pytest.raises(InputError) as err:
            LocalExecutor().run(cfg, jobs, [], "nonce", lambda j, done=done: done.append(j.name))
        if not keep_going:
            assert "exit code 3" in str(err.value) and not (tmp_path / "a2").exists()
            continue
        assert sorted(done) == ["a", "a2"] and (tmp_path / "a2").exists() and not (tmp_path / "b1").exists()
        assert str(err.value).startswith("2 of 5 jobs failed: b, a1 (their errors are above), 1 skipped")
        assert "The tables are written once every cell has: fix" in str(err.value)
        warnings = [
            line for line in capsys.readouterr().err.splitlines() if "going on with the others" in line
        ]
        assert "step failed with exit code 3" in warnings[0]
        assert len(warnings) == 2  # b and a1 (b1 never ran)
        (tmp_path / "results.json").write_text("{}")  # an earlier call's tables: said to be that
        with pytest.raises(InputError, match=r"every cell has \(those in the folder now are an earlier"):
            LocalExecutor().run(cfg, jobs, [], "nonce", print)


def test_a_step_writing_to_the_terminal_starts_on_a_line_of_its_own(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """With one job at a time a step writes to the terminal: the benchmark's bar is cleared first (its
    error line did not start on the bar's line), and drawn again after the step."""
    import sys
    from types import SimpleNamespace

    from spikenerf.pipelines.benchmark.local_executor import LocalExecutor
    from spikenerf.pipelines.benchmark.steps import Job

    code = "import sys; sys.stderr.write('step line\\n')"
    steps = Job("a", lambda root: [[sys.executable, "-c", code]], "a", "a.done", None)
    LocalExecutor().run(SimpleNamespace(out=tmp_path, jobs=1, keep_going=False), [steps], [], "n", print)
    err = capfd.readouterr().err
    assert "benchmark datasets" in err  # the bar was drawn
    before, after = err.split("step line\n")
    assert before.endswith("\r") and "benchmark datasets" in after


def test_a_stopped_step_leaves_the_resume_hint_to_its_benchmark(monkeypatch: pytest.MonkeyPatch) -> None:
    """An interrupted benchmark's steps say "terminated" alone, not "train --resume": the benchmark's own line
    says to run it again, and a lone `train` keeps its hint."""
    import sys

    from spikenerf.cli import RESUME_HINTS, resume_hint
    from spikenerf.pipelines.benchmark.steps import STEP_ENV, run_step

    monkeypatch.delenv(STEP_ENV, raising=False)
    assert resume_hint("train") == f" ({RESUME_HINTS['train']})"
    log: list[dict] = []
    check = f"import os, sys; sys.exit(0 if os.environ.get({STEP_ENV!r}) == '1' else 3)"
    run_step([sys.executable, "-c", check], log)  # a step's environment marks it
    run_step([sys.executable, "-c", check], log, threads=1)
    assert [entry["rc"] for entry in log] == [0, 0]
    monkeypatch.setenv(STEP_ENV, "1")
    assert resume_hint("train") == resume_hint("benchmark") == ""


def test_an_interrupted_benchmark_stops_its_running_steps() -> None:
    import sys

    from spikenerf.pipelines.benchmark.steps import run_step

    log: list[dict] = []
    started = threading.Event()

    def long_step() -> None:
        started.set()
        run_step([sys.executable, "-c", "import time; time.sleep(60)"], log)

    def interrupt() -> None:
        started.wait(10)
        time.sleep(1.0)  # the step's process is running
        raise KeyboardInterrupt  # as Ctrl-C or SIGTERM (Terminated) reaches the benchmark

    t0 = time.perf_counter()
    with pytest.raises(KeyboardInterrupt):
        _parallel([long_step, interrupt], 2, "cells", "cell")
    assert time.perf_counter() - t0 < 30  # the running step was stopped, not waited for
    assert log and log[0]["rc"] != 0


def test_two_jobs_write_logs_and_resume(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    cfg = BenchmarkConfig(["analytic-orbs"], ["nerf-gt", "nerf-blur"], ["gray"], tmp_path / "b", size=16,
                          frames=100, iters=4, device="cpu", test_views=1, render=False,
                          extra_train_args=BENCHMARK_TRAIN, jobs=2)  # fmt: skip
    cells = run_benchmark(cfg)
    assert [c.variant for c in cells] == ["nerf-gt", "nerf-blur"] and all(c.psnr > 5 for c in cells)
    logs = sorted(p.name for p in (cfg.out / "logs").iterdir())
    assert logs == [f"analytic-orbs-gray-{v}.log" for v in ("nerf-blur", "nerf-gt")] + [
        "simulate-analytic-orbs.log"
    ]
    assert "trained 4 iterations" in (cfg.out / "logs" / "analytic-orbs-gray-nerf-gt.log").read_text()
    log = json.loads((cfg.out / "results.json").read_text())["commands"]["this_run"]
    assert sorted(entry["command"][1] for entry in log) == ["eval", "eval", "simulate", "train", "train"]
    assert run_benchmark(cfg) == cells  # everything reused
    assert json.loads((cfg.out / "results.json").read_text())["commands"]["this_run"] == []
    # resuming with other dataset or training settings is refused, naming the settings (the CLI shows
    # their flags), before anything runs
    before = (cfg.out / "results.json").stat().st_mtime_ns
    for change, words in [
        ({"iters": 5}, "iters 4 → 5"),
        ({"size": 24, "seed": 1}, "size 16 → 24; seed 0 → 1"),
        ({"colors": ["gray", "rgb"]}, "color 'gray' → 'all'"),
        ({"field_kind": "mlp"}, "field_kind"),
        ({"noise": "realistic"}, "noise 'ideal' → 'realistic'"),
        # the demo's derived train arguments: only the options that differ
        (
            {"extra_train_args": [("5" if a == "2" else a) for a in cfg.extra_train_args]},
            "extra train arguments --eval-every 2 → 5\\)",
        ),
    ]:
        with pytest.raises(
            InputError, match=f"other settings: pass the same values .* or a new out \\({words}"
        ):
            run_benchmark(replace(cfg, **change))
    # … and so is a folder whose cells another version's field defaults trained (or an unrecorded one)
    stored = json.loads((cfg.out / "benchmark.json").read_text())
    older = {**stored["settings"]["field_defaults"], "step_ratio": 0.5}
    for defaults, words in [(older, "step_ratio 0.5 → 0.75"), (None, "unrecorded")]:
        settings = {**stored["settings"], "field_defaults": defaults}
        (cfg.out / "benchmark.json").write_text(json.dumps({**stored, "settings": settings}))
        with pytest.raises(InputError, match=f"other field defaults \\({words}.*or use a new out"):
            run_benchmark(cfg)
    (cfg.out / "benchmark.json").write_text(json.dumps(stored))
    assert (cfg.out / "results.json").stat().st_mtime_ns == before
    # a folder from before benchmark.json resumes as it is, and gets the file
    nonce = json.loads((cfg.out / "benchmark.json").read_text())["nonce"]
    (cfg.out / "benchmark.json").unlink()
    assert run_benchmark(replace(cfg, jobs=1)) == cells
    assert json.loads((cfg.out / "benchmark.json").read_text())["settings"]["iters"] == 4
    assert json.loads((cfg.out / "benchmark.json").read_text())["nonce"] != nonce
    # a call with fewer methods writes tables of its own cells, and says which finished cells it leaves out
    capsys.readouterr()
    assert run_benchmark(replace(cfg, variants=["nerf-gt"])) == cells[:1]
    assert (
        "spikenerf: warning: the tables hold this call's 1 cells; 1 other finished cells"
        in capsys.readouterr().err
    )
    assert other_finished_cells(cfg, cell_keys(replace(cfg, variants=["nerf-gt"]))) == [
        cfg.out / "runs" / "analytic-orbs" / "gray" / "nerf-blur"
    ]


def test_benchmark_noise(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``benchmark --noise realistic`` simulates its datasets with the realistic camera and says so above
    its tables; a folder recorded before the setting existed reads as ``ideal``, and a dataset simulated
    with the other noise is refused."""
    from helpers import run_cli
    from spikenerf.pipelines.benchmark.cells import dataset_command
    from spikenerf.pipelines.benchmark.results import read_call
    from spikenerf.pipelines.benchmark.run import dataset_mismatch
    from spikenerf.pipelines.benchmark.settings import NAME, check_settings, settings

    cfg = BenchmarkConfig(["analytic-orbs"], ["nerf-gt"], ["gray"], tmp_path / "b", size=16, frames=60,
                          iters=2, device="cpu", test_views=1, render=False, noise="realistic",
                          extra_train_args=BENCHMARK_TRAIN)  # fmt: skip
    command = dataset_command(cfg, "analytic-orbs")
    assert command[command.index("--noise") + 1] == "realistic"
    args = ["--quiet", "--threads", "1", "benchmark", "--scenes", "analytic-orbs", "--methods", "nerf-gt",
            "--color", "gray", "--size", "16", "--frames", "60", "--iters", "2", "--test-views", "1",
            "--no-render", "--device", "cpu", "--out", cfg.out, "--set", "batch=64"]  # fmt: skip
    code, _, err = run_cli(capsys, *args, "--noise", "loud")
    assert code == 2 and "--noise" in err and not cfg.out.exists()
    assert run_cli(capsys, *args, "--noise", "realistic")[0] == 0
    dataset = cfg.out / "datasets" / "analytic-orbs"
    assert "noise: realistic" in (dataset / "config.yaml").read_text()
    assert "realistic noise" in (cfg.out / "table1.md").read_text()
    assert read_call(cfg.out / "results.json").config["noise"] == "realistic"
    code, _, err = run_cli(capsys, *args)  # resumed without it: refused, naming the flag
    assert code == 2 and "noise 'realistic' → 'ideal'" in err and "--noise" in err
    # the dataset alone (benchmark.json gone) is refused too
    (cfg.out / NAME).unlink()
    problem = dataset_mismatch(replace(cfg, noise="ideal"), "analytic-orbs")
    assert problem is not None and "noise realistic" in problem.message
    assert dataset_mismatch(cfg, "analytic-orbs") is None
    # records written before the setting existed: an ideal camera
    ideal = replace(cfg, out=tmp_path / "old", noise="ideal")
    ideal.out.mkdir()
    old = {k: v for k, v in settings(ideal).items() if k != "noise"}
    (ideal.out / NAME).write_text(json.dumps({"settings": old, "nonce": "n"}))
    assert check_settings(ideal) == "n"
    with pytest.raises(InputError, match="noise 'ideal' → 'realistic'"):
        check_settings(replace(ideal, noise="realistic"))
    results = json.loads((cfg.out / "results.json").read_text())
    del results["config"]["noise"]
    (ideal.out / "results.json").write_text(json.dumps(results))
    assert read_call(ideal.out / "results.json").config["noise"] == "ideal"


def test_settings_resolve_the_trainers_default_iters(tmp_path: Path) -> None:
    """Without ``--iters`` the folder records the trainer's default, so a folder started under an older
    default (recorded as null) is refused instead of mixing 3000- and 8000-iteration cells."""
    from spikenerf.pipelines.benchmark.settings import NAME, check_settings, settings
    from spikenerf.train.config import TrainConfig

    cfg = BenchmarkConfig(["analytic-orbs"], ["nerf-gt"], ["gray"], tmp_path, size=16, frames=100,
                          test_views=1, render=False)  # fmt: skip
    assert cfg.iters is None and settings(cfg)["iters"] == TrainConfig().iters
    stored = {**settings(cfg), "iters": None}
    (tmp_path / NAME).write_text(json.dumps({"settings": stored, "nonce": "n"}))
    with pytest.raises(InputError, match=r"recorded no iteration count.*pass that count as iters"):
        check_settings(cfg)
    assert check_settings(replace(cfg, iters=3000)) == "n"  # the caller names the old default


def test_a_folder_from_before_an_added_field_entry_resumes_when_it_trains_as_before(tmp_path: Path) -> None:
    """A record without the entries added since (ADDED_DEFAULTS: the TV prior, off) is read with their
    earlier behaviour; one that recorded another value is refused."""
    from spikenerf.pipelines.benchmark.settings import (
        ADDED_DEFAULTS,
        NAME,
        REMOVED_DEFAULTS,
        check_settings,
        settings,
    )

    cfg = BenchmarkConfig(["analytic-orbs"], ["nerf-gt"], ["gray"], tmp_path, size=16, frames=100,
                          test_views=1, render=False, iters=4)  # fmt: skip
    now = settings(cfg)
    assert all(now["field_defaults"][k] == v for k, v in ADDED_DEFAULTS.items())
    older = {k: v for k, v in now["field_defaults"].items() if k not in ADDED_DEFAULTS}
    (tmp_path / NAME).write_text(json.dumps({"settings": {**now, "field_defaults": older}, "nonce": "n"}))
    assert check_settings(cfg) == "n"
    removed = {**older, **REMOVED_DEFAULTS}  # an entry since removed, at the value that trains as now
    (tmp_path / NAME).write_text(json.dumps({"settings": {**now, "field_defaults": removed}, "nonce": "n"}))
    assert check_settings(cfg) == "n"
    unread = {**now["field_defaults"], "batch_rays": 8192}  # never read, so any value trained as now
    (tmp_path / NAME).write_text(json.dumps({"settings": {**now, "field_defaults": unread}, "nonce": "n"}))
    assert check_settings(cfg) == "n"
    gathered = {**now["field_defaults"], "gather_lookup": True}
    (tmp_path / NAME).write_text(json.dumps({"settings": {**now, "field_defaults": gathered}, "nonce": "n"}))
    with pytest.raises(InputError, match=r"other field defaults \(gather_lookup True → None"):
        check_settings(cfg)
    other = {**now["field_defaults"], "tv_app": 0.5}
    (tmp_path / NAME).write_text(json.dumps({"settings": {**now, "field_defaults": other}, "nonce": "n"}))
    with pytest.raises(InputError, match=r"other field defaults \(tv_app 0.5 → 0.0"):
        check_settings(cfg)


def test_disk_estimate_counts_seeds_and_every_simulated_stream(monkeypatch: pytest.MonkeyPatch) -> None:
    from spikenerf.capture.simulate import estimate_resources
    from spikenerf.pipelines.benchmark import resources

    seen: list[float] = []
    monkeypatch.setattr(resources, "check_resources", lambda memory, disk, *_: seen.append(disk))
    cfg = BenchmarkConfig(["analytic-orbs"], ["nerf-gt"], ["gray", "rgb"], Path("b"), size=16, frames=100,
                          test_views=1, render=False)  # fmt: skip
    for seeds in (None, [0, 1, 2]):
        resources.check_benchmark_resources(replace(cfg, seeds=seeds))
    one, three = seen
    sim = estimate_resources(16, 16, 100, ("gray", "rgb", "bayer"), 1, 4, 10, 1)[1]  # what --color all writes
    cell = (one - sim) / 2  # two colours, one seed
    assert cell > 0 and three == pytest.approx(sim + 6 * cell)


def test_set_reaches_every_cell_and_a_bad_key_fails_first(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import yaml

    from spikenerf.cli import main

    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    out = tmp_path / "b"
    args = ["benchmark", "--scenes", "analytic-orbs", "--methods", "nerf-gt", "--color", "gray", "--size",
            "16", "--frames", "40", "--iters", "2", "--device", "cpu", "--test-views", "1", "--no-render",
            "--out"]  # fmt: skip
    for bad, words in [("nope=1", "--set: unknown train config keys ['nope']"), ("batch", "--set: override")]:
        with pytest.raises(SystemExit) as exit_:
            main([*args, str(out), "--set", bad])
        err = capsys.readouterr().err.strip()
        assert exit_.value.code == 2 and words in err and "\n" not in err
        assert not out.exists()
    with pytest.raises(SystemExit):  # a key that no chosen method reads is named (then --retries stops it)
        main([*args, str(out), "--set", "spike.lam=2", "--set", "batch=64", "--retries", "2"])
    warning, error = capsys.readouterr().err.strip().splitlines()
    assert (
        warning == "spikenerf: warning: --set spike.lam is not used by any chosen method (nerf-gt); ignored"
    )
    assert error.startswith("spikenerf: error: --retries") and not out.exists()
    main([*args, str(out), "--set", "batch=64", "--set", "field_config.hidden=16"])
    config = yaml.safe_load((out / "runs" / "analytic-orbs" / "gray" / "nerf-gt" / "config.yaml").read_text())
    assert config["batch"] == 64 and config["field_config"]["hidden"] == 16
    stored = json.loads((out / "benchmark.json").read_text())["settings"]["extra_train_args"]
    assert stored == ["--set", "batch=64", "--set", "field_config.hidden=16"]
    simulate = json.loads((out / "results.json").read_text())["commands"]["datasets"]["analytic-orbs"]
    assert simulate[simulate.index("--jobs") + 1] == "1"  # OMP_NUM_THREADS render processes


def test_render_processes_share_the_cores(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from spikenerf.pipelines.benchmark.cells import render_processes

    cfg = BenchmarkConfig(["analytic-orbs", "analytic-blocks"], ["nerf-gt"], ["gray"], tmp_path, jobs=16)
    monkeypatch.setattr("os.cpu_count", lambda: 16)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    assert render_processes(cfg) == 8  # two datasets at once share the 16 cores
    assert render_processes(replace(cfg, jobs=1)) == 16
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert render_processes(cfg) == 3
    monkeypatch.setenv("OMP_NUM_THREADS", "4,2")  # a nested OpenMP list is not a count: fall back
    assert render_processes(cfg) == 8
    assert render_processes(replace(cfg, executor="ray", ray_cpus=2.5)) == 2  # the task's CPUs


def test_a_folder_whose_spike_integral_cells_other_defaults_trained_is_refused(tmp_path: Path) -> None:
    """spike-integral's window, renders and batch defaults are recorded; a folder from before the record
    (the 11 × 2, 2048-ray defaults) or with others is refused when it has spike-integral cells, and a
    folder without them resumes."""
    from spikenerf.pipelines.benchmark.settings import (
        NAME,
        PREVIOUS_INTEGRAL,
        adopt_integral_defaults,
        check_settings,
        settings,
    )

    cfg = BenchmarkConfig(["analytic-orbs"], ["spike-integral"], ["gray"], tmp_path, size=16, frames=100,
                          test_views=1, render=False, iters=4)  # fmt: skip
    now = settings(cfg)
    assert now["integral_defaults"] == {
        "window": 5, "samples": 1, "batch": 4096, "window_span_px": 1.5, "track": 5
    }  # fmt: skip
    (tmp_path / NAME).write_text(json.dumps({"settings": now, "nonce": "n"}))
    assert check_settings(cfg) == "n"
    unrecorded = {k: v for k, v in now.items() if k != "integral_defaults"}
    (tmp_path / NAME).write_text(json.dumps({"settings": unrecorded, "nonce": "n"}))
    assert check_settings(cfg) == "n"  # no spike-integral cell trained yet (a demo folder of four methods)
    adopt_integral_defaults(cfg)  # its cells will train with today's defaults: recorded
    cell = tmp_path / "runs" / "analytic-orbs" / "gray" / "spike-integral"
    cell.mkdir(parents=True)
    (cell / "checkpoint.pt").write_bytes(b"")
    assert check_settings(cfg) == "n"
    (tmp_path / NAME).write_text(json.dumps({"settings": unrecorded, "nonce": "n"}))
    adopt_integral_defaults(cfg)  # a trained cell: nothing adopted
    with pytest.raises(InputError, match=r"spike-integral cells .*window 11 → 5, samples 2 → 1, batch 2048"):
        check_settings(cfg)
    assert PREVIOUS_INTEGRAL == {"window": 11, "samples": 2, "batch": 2048}
    fixed = {**now, "integral_defaults": {"window": 5, "samples": 1, "batch": 4096}}  # before the motion rule
    (tmp_path / NAME).write_text(json.dumps({"settings": fixed, "nonce": "n"}))
    with pytest.raises(InputError, match=r"window_span_px None → 1.5"):
        check_settings(cfg)
    untracked = {
        **now,
        "integral_defaults": {k: v for k, v in now["integral_defaults"].items() if k != "track"},
    }
    (tmp_path / NAME).write_text(json.dumps({"settings": untracked, "nonce": "n"}))  # before track windows
    with pytest.raises(InputError, match=r"track None → 5"):
        check_settings(cfg)
    assert check_settings(replace(cfg, variants=["nerf-gt"])) == "n"  # no spike-integral cell: resumes


def test_a_cell_is_done_when_its_render_is(tmp_path: Path) -> None:
    """With renders on, a cell whose eval finished but whose render was killed runs again (the render
    resumes from its cache); without them the metrics end it."""
    from spikenerf.pipelines.benchmark.cells import cell_keys
    from spikenerf.pipelines.benchmark.run import _jobs

    cfg = BenchmarkConfig(["analytic-orbs"], ["nerf-gt"], ["gray"], tmp_path, size=16, frames=100,
                          test_views=1, iters=4)  # fmt: skip
    cell = _jobs(cfg, cell_keys(cfg))[-1]
    assert cell.done.endswith("nerf-gt/render/render.json") and cfg.render
    assert _jobs(replace(cfg, render=False), cell_keys(cfg))[-1].done.endswith("nerf-gt/metrics.json")
    assert cell.commands(tmp_path)[-1][3:5] == ["render", str(tmp_path / cell.folder)]
    assert len(cell.commands(tmp_path)) == 3  # train, eval, render
    (tmp_path / cell.folder).mkdir(parents=True)
    (tmp_path / cell.folder / "metrics.json").write_text("{}")  # killed in its render: only that again
    assert [c[3] for c in cell.commands(tmp_path)] == ["render"]
    from spikenerf.pipelines.benchmark.cells import cell_commands

    (tmp_path / cell.folder / "checkpoint.pt").write_bytes(b"")
    recorded = cell_commands(cfg, "analytic-orbs", "gray", "nerf-gt", todo=False)  # what results.json keeps
    assert [c[3] for c in recorded] == ["train", "eval", "render"] and "--resume" not in recorded[0]


def test_table_ii_of_an_earlier_run_goes_when_this_run_has_no_ablation(tmp_path: Path) -> None:
    from spikenerf.pipelines.benchmark.results import write_all
    from spikenerf.pipelines.benchmark.tables import Cell

    cfg = BenchmarkConfig(["analytic-orbs"], ["nerf-gt"], ["gray"], tmp_path, size=16, frames=100,
                          test_views=1, iters=4)  # fmt: skip
    (tmp_path / "table2.md").write_text("# Table II of an earlier run\n")
    write_all(cfg, [Cell("analytic-orbs", "nerf-gt", "gray", 20.0, 0.5, None, 1.0, 0)], [])
    assert (tmp_path / "table1.md").is_file() and not (tmp_path / "table2.md").exists()


def test_a_folder_of_datasets_simulated_first_is_adopted(tmp_path: Path) -> None:
    """docs/cluster.md: datasets simulated first into OUT/datasets/SCENE; anything else unmarked is not."""
    from spikenerf.core.marker import mark
    from spikenerf.pipelines.benchmark.run import pre_simulated

    out = tmp_path / "out"
    mark(out / "datasets" / "analytic-orbs", "dataset")
    assert pre_simulated(out)
    (out / "notes.txt").write_text("mine")
    assert not pre_simulated(out)
    (out / "notes.txt").unlink()
    (out / "datasets" / "thesis").mkdir()
    assert not pre_simulated(out)
    assert not pre_simulated(tmp_path / "nowhere")


def test_scene_lists_name_what_is_wrong() -> None:
    """``--scenes ""`` read "unknown scene(s) []"."""
    from spikenerf.pipelines.benchmark.cells import resolve_scenes

    with pytest.raises(InputError, match=r"^scenes: none given; expected 'all' or names from: analytic-orbs"):
        resolve_scenes(" , ")
    with pytest.raises(InputError, match=r"^scenes: unknown scene\(s\) nope, other; expected"):
        resolve_scenes("analytic-orbs,nope,other")
    assert resolve_scenes("analytic-orbs, analytic-blocks") == ["analytic-orbs", "analytic-blocks"]
