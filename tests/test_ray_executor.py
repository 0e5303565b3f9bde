"""``benchmark --executor ray``: same numbers as the local executor, a killed worker's cell is retried, and a
clear one-line hint without Ray. The Ray tests start their own 2-CPU cluster on 127.0.0.1 and shut it down."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace

import pytest

from helpers import BENCHMARK_TRAIN
from spikenerf.cli import main
from spikenerf.core.errors import InputError
from spikenerf.pipelines.benchmark import BenchmarkConfig, run_benchmark
from spikenerf.pipelines.benchmark.ray_executor import INSTALL_HINT, execute, rebase, scratch_root
from spikenerf.pipelines.benchmark.steps import Job

SRC = Path(__file__).resolve().parents[1] / "src"
WORKER = re.compile(r"Ray worker pid (\d+)")


def tiny(out: Path, variants: list[str], **kw: object) -> BenchmarkConfig:
    return BenchmarkConfig(
        ["analytic-orbs"], variants, ["gray"], out, size=16, frames=60, iters=4, device="cpu",
        test_views=1, render=False, extra_train_args=BENCHMARK_TRAIN, **kw,  # type: ignore[arg-type]
    )  # fmt: skip


def numbers(out: Path) -> list[dict]:
    """results.json's cells without their timings."""
    cells = json.loads((out / "results.json").read_text())["cells"]
    return [{k: v for k, v in c.items() if not k.endswith("seconds")} for c in cells]


@pytest.fixture(scope="module")
def cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """A local 2-CPU Ray cluster on 127.0.0.1; its workers import this checkout. Yields their scratch root."""
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'spikenerf[cluster]')")
    scratch = tmp_path_factory.mktemp("scratch")
    saved = {k: os.environ.get(k) for k in ("PYTHONPATH", "OMP_NUM_THREADS", "SPIKENERF_RAY_SCRATCH")}
    os.environ.update(PYTHONPATH=os.pathsep.join(filter(None, [str(SRC), saved["PYTHONPATH"]])),
                      OMP_NUM_THREADS="1", SPIKENERF_RAY_SCRATCH=str(scratch))  # fmt: skip
    ray.init(address="local", num_cpus=2, include_dashboard=False, _node_ip_address="127.0.0.1",
             log_to_driver=False)  # fmt: skip
    try:
        yield scratch
    finally:
        ray.shutdown()
        for key, value in saved.items():
            os.environ.pop(key, None) if value is None else os.environ.__setitem__(key, value)


@pytest.fixture(scope="module")
def local_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny benchmark (one spike-nerf cell) under the local executor."""
    out = tmp_path_factory.mktemp("local") / "b"
    run_benchmark(tiny(out, ["spike-nerf"]))
    return out


def reuse_datasets(done: Path, out: Path) -> None:
    """A new benchmark folder ``out`` holding the datasets of the finished benchmark ``done``."""
    shutil.copytree(done / "datasets", out / "datasets")
    shutil.copy(done / ".spikenerf", out / ".spikenerf")  # marks ``out`` as a benchmark folder we wrote


def test_ray_gives_the_local_numbers_shared_and_shipped(
    cluster: Path, local_run: Path, tmp_path: Path
) -> None:
    on_ray = run_benchmark(tiny(tmp_path / "ray", ["spike-nerf"], executor="ray"))
    assert numbers(tmp_path / "ray") == numbers(local_run) and on_ray[0].psnr > 5
    assert "wrote" in (tmp_path / "ray" / "logs" / "simulate-analytic-orbs.log").read_text()
    # no shared storage: the dataset travels out to the worker, the run comes back through the object store
    shipped = tmp_path / "shipped"
    reuse_datasets(local_run, shipped)
    run = "runs/analytic-orbs/gray/spike-nerf"
    stale = scratch_root(str(shipped.resolve())) / run  # a scratch copy keyed on the path alone: never used
    stale.mkdir(parents=True)
    (stale / "metrics.json").write_text('{"mean": {"psnr": 99, "ssim": 1, "lpips": null}}')
    run_benchmark(tiny(shipped, ["spike-nerf"], executor="ray", ship_results=True))
    assert numbers(shipped) == numbers(local_run)
    nonce = json.loads((shipped / "benchmark.json").read_text())["nonce"]
    scratch = scratch_root(str(shipped.resolve()), nonce)
    this_run = json.dumps(json.loads((shipped / "results.json").read_text())["commands"]["this_run"])
    assert str(shipped.resolve()) in this_run and str(scratch) not in this_run  # commands as in OUT
    assert scratch.is_relative_to(cluster) and (scratch / run / "metrics.json").is_file()
    config = (shipped / run / "config.yaml").read_text()
    assert str(shipped.resolve()) in config and str(scratch) not in config
    assert str(scratch).encode() not in (shipped / run / "checkpoint.pt").read_bytes()  # (no path inside)
    assert WORKER.search((shipped / "logs" / "analytic-orbs-gray-spike-nerf.log").read_text())


def test_rebase_replaces_whole_path_components_only() -> None:
    text = b'out: /data/bench\n"/data/bench" /data/bench/runs /data/bench2/x /data/benchmark /data/bench'
    assert (
        rebase(text, "/data/bench", "/s/1")
        == b'out: /s/1\n"/s/1" /s/1/runs /data/bench2/x /data/benchmark /s/1'
    )
    assert scratch_root("/b", "n1") != scratch_root("/b", "n2") != scratch_root("/b")


def test_shipped_job_starts_from_an_empty_scratch_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A re-submitted job (its metrics.json deleted in OUT) never ships the worker's stale scratch copy."""
    monkeypatch.setenv("SPIKENERF_RAY_SCRATCH", str(tmp_path / "scratch"))
    stale = scratch_root("/b", "n") / "runs/x"
    stale.mkdir(parents=True)
    (stale / "metrics.json").write_text("{}")
    job = Job("x", lambda root: [], "runs/x", "runs/x/metrics.json")
    result = execute(job, "/b", ship=True, threads=1, nonce="n")
    assert "runs/x/metrics.json" not in result["files"] and "logs/x.log" in result["files"]


def _children(pid: int) -> list[int]:
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            if int(stat.read_text().rsplit(")", 1)[1].split()[1]) == pid:
                found.append(int(stat.parent.name))
        except (OSError, IndexError, ValueError):
            continue
    return found


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="finds the worker's child through /proc")
def test_killed_worker_cell_is_retried_and_nothing_is_lost(
    cluster: Path, local_run: Path, tmp_path: Path
) -> None:
    out = tmp_path / "b"
    shutil.copytree(local_run, out)  # the dataset and a finished spike-nerf cell
    finished = out / "runs/analytic-orbs/gray/spike-nerf/metrics.json"
    before = finished.stat().st_mtime_ns
    log = out / "logs" / "analytic-orbs-gray-nerf-gt.log"
    killed: dict = {}

    def kill_the_worker() -> None:
        """Once the cell's train step runs, SIGKILL the Ray worker that started it."""
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and "pid" not in killed:
            found = WORKER.search(log.read_text()) if log.is_file() else None
            children = _children(int(found.group(1))) if found else []
            if found and children:
                done = (out / "runs/analytic-orbs/gray/nerf-gt/metrics.json").exists()
                killed.update(pid=int(found.group(1)), children=children, mid_cell=not done)
                os.kill(killed["pid"], signal.SIGKILL)
                time.sleep(3)
                killed["orphans"] = [c for c in children if Path(f"/proc/{c}").exists()]
            time.sleep(0.1)

    killer = threading.Thread(target=kill_the_worker)
    killer.start()
    cells = run_benchmark(tiny(out, ["spike-nerf", "nerf-gt"], executor="ray", retries=2))
    killer.join()
    assert killed.get("pid") and killed["mid_cell"], killed
    assert killed["orphans"] == []  # the killed worker's train step died with it
    attempts = WORKER.findall(log.read_text())
    assert len(attempts) == 2 and attempts[0] == str(killed["pid"]) != attempts[1]
    assert [c.variant for c in cells] == ["spike-nerf", "nerf-gt"] and all(c.psnr > 5 for c in cells)
    assert finished.stat().st_mtime_ns == before  # the finished cell was not run again
    assert [c["variant"] for c in numbers(out)] == ["spike-nerf", "nerf-gt"]
    assert numbers(out)[0] == numbers(local_run)[0]


def test_failing_cell_is_retried_and_its_logs_kept(cluster: Path, local_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "b"
    reuse_datasets(local_run, out)
    cfg = tiny(out, ["nerf-gt"], executor="ray", retries=1)
    cfg.extra_train_args = [*BENCHMARK_TRAIN, "--no-such-flag"]  # train exits with code 2
    with pytest.raises(
        InputError, match=r"1 job\(s\) failed after 1 retries: analytic-orbs-gray-nerf-gt \(step "
    ):
        run_benchmark(cfg)
    log = (out / "logs" / "analytic-orbs-gray-nerf-gt.log").read_text()
    assert len(WORKER.findall(log)) == 2 and log.count("--no-such-flag") == 2  # both attempts' output kept
    assert not (out / "results.json").exists()


def test_without_ray_one_line_hint_exit_2(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray → ImportError
    out = tmp_path / "bench"
    with pytest.raises(SystemExit) as exit_:
        main(["benchmark", "--scenes", "analytic-orbs", "--executor", "ray", "--out", str(out)])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.splitlines() == [f"spikenerf: error: --{INSTALL_HINT}"]  # the parameter shown as its flag
    assert INSTALL_HINT.startswith("executor ray needs Ray")
    assert "pip install 'spikenerf[cluster]'" in err
    assert not out.exists()  # nothing written


class _FakeRay:
    """A Ray stand-in with no GPU and 2 CPUs: records whether the session it started was shut down."""

    def __init__(self) -> None:
        self.down = False

    def is_initialized(self) -> bool:
        return False

    def init(self, **kw: object) -> None:
        pass

    def cluster_resources(self) -> dict[str, float]:
        return {"CPU": 2.0}

    def shutdown(self) -> None:
        self.down = True


class _UnreachableRay(_FakeRay):
    """A Ray stand-in whose cluster cannot be reached, as ``ray.init(address="auto")`` with none running."""

    def init(self, **kw: object) -> None:
        raise ConnectionError("Could not find any running Ray instance.")


def test_an_unreachable_cluster_is_refused_before_anything_is_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """It left OUT/benchmark.json behind, so the next call with other settings was refused as a resume."""
    from spikenerf.pipelines.benchmark import ray_executor

    monkeypatch.setattr(ray_executor, "require_ray", _UnreachableRay)
    out = tmp_path / "bench"
    with pytest.raises(SystemExit) as exit_:
        main(["benchmark", "--scenes", "analytic-orbs", "--executor", "ray", "--address", "auto",
              "--out", str(out)])  # fmt: skip
    assert exit_.value.code == 2 and not out.exists()
    assert capsys.readouterr().err.splitlines() == [
        "spikenerf: error: --address: cannot reach a Ray cluster at 'auto' (Could not find any running Ray "
        "instance.)"
    ]


@pytest.mark.parametrize(("kw", "param"), [({"device": "cuda"}, "device"), ({"ray_cpus": 4.0}, "ray_cpus")])
def test_a_task_a_new_cluster_cannot_place_is_refused_not_waited_for(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, kw: dict, param: str
) -> None:
    """A cluster started for the benchmark never grows: cells asking for a GPU it lacks, or more CPUs than it
    has, would wait forever (they did, with --device cuda on a CPU machine)."""
    from spikenerf.pipelines.benchmark import ray_executor

    fake = _FakeRay()
    monkeypatch.setattr(ray_executor, "require_ray", lambda: fake)
    cfg = tiny(tmp_path / "b", ["nerf-gt"], executor="ray", address="local")
    cfg.device, cfg.ray_cpus = kw.get("device", "cpu"), float(kw.get("ray_cpus", 1.0))  # type: ignore[arg-type]
    job = Job("dataset", lambda root: [], "d", "d/.done")
    with pytest.raises(InputError, match=param) as err:
        ray_executor.run_jobs(cfg, [job], [])
    assert err.value.params == (param,) and fake.down
    assert ray_executor._cluster_problem({"CPU": 4.0, "GPU": 1.0}, cfg) is None  # a cluster that can


@pytest.mark.parametrize(
    ("args", "expected"),
    [(["--ray-cpus", "4"], "a task asks for --ray-cpus 4 CPUs, the Ray cluster has 2"),
     (["--device", "cuda"], "the Ray cluster has no GPU for --device cuda")],
)  # fmt: skip
@pytest.mark.parametrize("existing", [False, True])
def test_a_task_the_cluster_cannot_place_is_refused_before_anything_is_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], args: list[str],
    expected: str, existing: bool,
) -> None:  # fmt: skip
    """It left OUT/benchmark.json and its marker behind (the check ran once the settings were written)."""
    from spikenerf.pipelines.benchmark import ray_executor

    fake = _FakeRay()
    monkeypatch.setattr(ray_executor, "require_ray", lambda: fake)
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    out = tmp_path / "bench"
    if existing:
        out.mkdir()
    with pytest.raises(SystemExit) as exit_:
        main(["benchmark", "--scenes", "analytic-orbs", "--executor", "ray", "--out", str(out), *args])
    assert exit_.value.code == 2 and fake.down
    assert (list(out.iterdir()) == []) if existing else not out.exists()
    assert capsys.readouterr().err.splitlines() == [f"spikenerf: error: {expected}"]


class _NoCpuRay(_FakeRay):
    """A Ray stand-in whose cluster has no CPU: ``ray start --head --num-cpus 0`` (which an unset address
    joins), or a container allowed under one CPU (Ray counts it as 0)."""

    def cluster_resources(self) -> dict[str, float]:
        return {"CPU": 0.0, "memory": 1e9}


@pytest.mark.parametrize("args", [[], ["--ray-cpus", "0.5"]])
def test_a_cluster_without_cpus_is_refused_before_anything_is_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], args: list[str]
) -> None:
    """The check probed the cluster only for more than one CPU (or a GPU): a task of one CPU on a cluster
    of none was refused by run_jobs, once OUT/benchmark.json and the marker were written."""
    from spikenerf.pipelines.benchmark import ray_executor

    fake = _NoCpuRay()
    monkeypatch.setattr(ray_executor, "require_ray", lambda: fake)
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    out = tmp_path / "bench"
    with pytest.raises(SystemExit) as exit_:
        main(["benchmark", "--scenes", "analytic-orbs", "--executor", "ray", "--out", str(out), *args])
    assert exit_.value.code == 2 and fake.down and not out.exists()
    cpus = args[-1] if args else "1"
    assert capsys.readouterr().err.splitlines() == [
        f"spikenerf: error: a task asks for --ray-cpus {cpus} CPUs, the Ray cluster has 0"
    ]


def test_a_named_cluster_that_cannot_place_a_task_yet_is_only_probed(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """An autoscaler may add the node a task needs: the check refuses only a local cluster started here
    (docs/cluster.md), and reaches a named one without refusing; run_jobs warns there."""
    from spikenerf.pipelines.benchmark import ray_executor

    fake = _FakeRay()
    monkeypatch.setattr(ray_executor, "require_ray", lambda: fake)
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    named = SimpleNamespace(address="auto", ray_cpus=4, device="cpu")
    ray_executor.RayExecutor().check(named)  # no InputError: the cluster may grow
    assert fake.down  # the probe's session is closed again
    with pytest.raises(InputError, match="ray_cpus 4 CPUs, the Ray cluster has 2"):
        ray_executor.RayExecutor().check(SimpleNamespace(address="local", ray_cpus=4, device="cpu"))
    assert ray_executor._starts_local(None) and ray_executor._starts_local("local")
    assert not ray_executor._starts_local("auto") and not ray_executor._starts_local("10.0.0.1:6379")
    monkeypatch.setenv("RAY_ADDRESS", "10.0.0.1:6379")
    assert not ray_executor._starts_local(None)


@pytest.mark.parametrize(
    ("args", "expected"),
    [(["--address", "auto", "--ray-cpus", "2"], "--address, --ray-cpus: only with --executor ray"),
     (["--retries", "0"], "--retries: only with --executor ray"),
     (["--ray-ship-results"], "--ray-ship-results: only with --executor ray"),
     (["--executor", "ray", "--jobs", "2"], "--jobs: only with --executor local")],
)  # fmt: skip
def test_an_option_of_the_other_executor_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], expected: str
) -> None:
    out = tmp_path / "bench"
    with pytest.raises(SystemExit) as exit_:
        main(["benchmark", "--scenes", "analytic-orbs", "--out", str(out), *args])
    assert exit_.value.code == 2 and not out.exists()
    assert capsys.readouterr().err.splitlines() == [
        f"spikenerf: error: {expected}"
        + (" (Ray runs as many cells at once as it can place)" if "jobs" in expected else "")
    ]
