"""``benchmark --executor ray``: the benchmark's jobs as Ray tasks, on this machine or on a cluster.

A job is a scene's dataset or one cell. Its Ray task runs the same recorded ``spikenerf`` commands as the
local executor, as subprocesses, asking Ray for ``ray_cpus`` CPUs (and one GPU with ``--device cuda``, or with
``--device auto`` on a cluster that has GPUs). A cell's task takes its dataset's task as an argument, so Ray
starts it once the dataset exists. Outputs land in the benchmark folder, which must be on storage that every
node shares. With ``ship_results`` a worker works in its own scratch copy instead (:func:`scratch_root`), and
files travel through Ray's object store: datasets out to the cells that need them, every finished job's folder
and log back to the benchmark folder.

Finished jobs are skipped (before submitting, and again on the worker); a failed task, or one whose worker
died, is retried up to ``retries`` times, each attempt appending to the job's log under a header. Ctrl-C
cancels the tasks in flight; finished cells stay. Ray is imported here only, and only when used
(:class:`RayExecutor` is the ``ray`` entry of :data:`~spikenerf.pipelines.benchmark.executor.EXECUTORS`).
"""

from __future__ import annotations

import hashlib
import logging
import os
import re
import shutil
import socket
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

from spikenerf.core.atomic import write_bytes_atomic
from spikenerf.core.errors import InputError
from spikenerf.core.progress import bar as progress_bar
from spikenerf.pipelines.benchmark.steps import Job, run_step


class BenchmarkConfig(Protocol):
    """What the Ray executor reads of the benchmark's settings (``cells.BenchmarkConfig``)."""

    out: Path
    address: str | None
    device: str
    ray_cpus: float
    retries: int
    ship_results: bool


INSTALL_HINT = "executor ray needs Ray: pip install 'spikenerf[cluster]'"
#: shipped files whose paths are rewritten between a worker's scratch root and the benchmark folder
TEXT_SUFFIXES = {".json", ".yaml", ".yml", ".csv", ".txt", ".log", ".md"}
ATTEMPT = "=== attempt on {host}, Ray worker pid {pid}, {when} ==="


class RayExecutor:
    """Every job a Ray task (see the module docstring)."""

    def check(self, cfg: Any) -> None:
        """Before anything is written: without Ray, InputError with the one-line install hint; a cluster
        named by ``address`` (or ``$RAY_ADDRESS``) that cannot be reached, InputError naming ``address``; a
        local cluster started here that cannot place a task (:func:`_cluster_problem`: a GPU it lacks, more
        ``ray_cpus`` than it has), InputError naming ``device`` or ``ray_cpus``. The connection is a probe,
        closed again (:func:`run_jobs` connects when it has jobs to run); a local cluster is started for it
        (seconds) even for one CPU: it may have none (the head of ``ray start --num-cpus 0``, which an
        unset ``address`` joins; a container allowed under one CPU, which Ray counts as 0). A named cluster
        (it may grow) and a Ray session this process has already started are left to :func:`run_jobs`,
        which only warns."""
        ray = require_ray()
        if ray.is_initialized():
            return
        named = cfg.address if cfg.address is not None else os.environ.get("RAY_ADDRESS")
        if named and named != "local":
            _connect(ray, cfg.address)  # reachable? (an autoscaler may still add what a task needs)
            ray.shutdown()
            return
        _connect(ray, cfg.address)
        try:
            problem = _cluster_problem(ray.cluster_resources(), cfg)
        finally:
            ray.shutdown()
        if problem:
            raise InputError(problem[1], param=problem[0])

    def processes(self, cfg: Any) -> int:
        """The task's CPUs (``ray_cpus``, at least 1)."""
        return max(1, int(cfg.ray_cpus))

    def run(self, cfg: Any, jobs: list[Job], log: list[dict], nonce: str,
            finished: Callable[[Job], None]) -> None:  # fmt: skip
        """:func:`run_jobs`."""
        run_jobs(cfg, jobs, log, nonce, finished)


def require_ray() -> Any:
    """The ``ray`` module, or InputError with the install hint (raised before anything is written)."""
    try:
        import ray
    except ImportError:
        raise InputError(INSTALL_HINT, param="executor") from None
    return ray


def scratch_root(out: str | Path, nonce: str = "") -> Path:
    """A worker's own benchmark folder for ``ship_results`` (``$SPIKENERF_RAY_SCRATCH`` or the temp dir),
    keyed on the benchmark folder and its ``benchmark.json`` nonce: a deleted and restarted benchmark at the
    same path gets a new scratch folder, never the old one's datasets and cells."""
    base = os.environ.get("SPIKENERF_RAY_SCRATCH") or Path(tempfile.gettempdir()) / "spikenerf-ray"
    return Path(base) / hashlib.sha1(f"{out}\0{nonce}".encode()).hexdigest()[:12]


def rebase(data: bytes, old: str, new: str) -> bytes:
    """``data`` with the folder path ``old`` replaced by ``new`` where it is a whole path component
    (``/data/bench`` in ``/data/bench/x`` or ``"/data/bench"``, never in ``/data/bench2``)."""
    pattern = re.escape(old.encode()) + rb"(?=[/\"'\s:,]|$)"
    return re.sub(pattern, lambda _: new.encode(), data)


def _rebase_log(log: list[dict], old: str, new: str) -> list[dict]:
    """Log entries with ``old`` → ``new`` in their command arguments."""
    return [{**e, "command": [rebase(a.encode(), old, new).decode() for a in e["command"]]} for e in log]


def pack(root: Path, paths: list[str], out: str) -> dict[str, bytes]:
    """The files under ``root/paths`` by relative path; in text files, ``root`` is rewritten to ``out``."""
    files: dict[str, bytes] = {}
    for rel in paths:
        top = root / rel
        for path in sorted(top.rglob("*")) if top.is_dir() else [top] if top.is_file() else []:
            if path.is_file():
                data = path.read_bytes()
                if path.suffix in TEXT_SUFFIXES and str(root) != out:
                    data = rebase(data, str(root), out)
                files[path.relative_to(root).as_posix()] = data
    return files


def unpack(root: Path, files: dict[str, bytes], done: str, out: str) -> None:
    """Write shipped files under ``root`` (``out`` → ``root`` in text files); the ``done`` marker last."""
    for rel in sorted(files, key=lambda r: r == done):
        data = files[rel]
        if Path(rel).suffix in TEXT_SUFFIXES and str(root) != out:
            data = rebase(data, out, str(root))
        write_bytes_atomic(root / rel, data)


def execute(
    job: Job, out: str, ship: bool, threads: int | None, needed: dict | None = None, nonce: str = ""
) -> dict:
    """On a worker: make the needed dataset present, run the job unless it has finished; the run's log
    entries (paths as in ``out``) and, with ``ship``, the job's files. With ``ship`` the job's scratch folder
    is emptied first: the driver submits only unfinished jobs, so what it holds is stale."""
    root = scratch_root(out, nonce) if ship else Path(out)
    if ship:
        shutil.rmtree(root / job.folder, ignore_errors=True)
    if needed and needed["files"] and not (root / needed["done"]).is_file():
        unpack(root, needed["files"], needed["done"], out)
    log: list[dict] = []
    output = root / "logs" / f"{job.name}.log"
    if not (root / job.done).is_file():
        output.parent.mkdir(parents=True, exist_ok=True)
        header = ATTEMPT.format(host=socket.gethostname(), pid=os.getpid(), when=time.strftime("%F %T"))
        with output.open("a") as sink:
            sink.write(header + "\n")
        for command in job.commands(root):
            run_step([sys.executable, *command[1:]], log, output, threads)  # the worker's own Python
    if not ship:
        return {"log": log, "files": {}, "done": job.done}
    files = pack(root, [job.folder, f"logs/{job.name}.log"], out)
    return {"log": _rebase_log(log, str(root), out), "files": files, "done": job.done}


def _connect(ray: Any, address: str | None) -> bool:
    """Join the running Ray session, or connect to/start one; True when this call started the session."""
    if ray.is_initialized():
        return False
    local = address in (None, "local")
    try:
        ray.init(address=address, logging_level=logging.WARNING, log_to_driver=False,
                 **({"include_dashboard": False} if local else {}))  # fmt: skip
    except (ConnectionError, ValueError, RuntimeError) as err:
        raise InputError(
            f"address: cannot reach a Ray cluster at {address!r} ({err})", param="address"
        ) from None
    return True


def _starts_local(address: str | None) -> bool:
    """Whether connecting with ``address`` starts a new local cluster (``local``, or none given and no
    ``$RAY_ADDRESS``) rather than joining a named one, which an autoscaler may grow."""
    return address == "local" or (address is None and not os.environ.get("RAY_ADDRESS"))


def _cluster_problem(resources: dict[str, float], cfg: BenchmarkConfig) -> tuple[str, str] | None:
    """(parameter, message) when the cluster's ``resources`` cannot place a task of ``cfg`` now (Ray would
    wait until a node that can joins), else None."""
    if cfg.device.startswith("cuda") and resources.get("GPU", 0) < 1:
        return "device", f"the Ray cluster has no GPU for device {cfg.device}"
    if resources.get("CPU", 0) < cfg.ray_cpus:
        cpus = resources.get("CPU", 0)
        return "ray_cpus", f"a task asks for ray_cpus {cfg.ray_cpus:g} CPUs, the Ray cluster has {cpus:g}"
    return None


def _threads(cpus: float) -> int:
    """Threads per step: ``OMP_NUM_THREADS`` (``--threads``) when set here, else the task's CPUs."""
    return int(os.environ.get("OMP_NUM_THREADS") or max(1, int(cpus)))


def run_jobs(
    cfg: BenchmarkConfig,
    jobs: list[Job],
    log: list[dict],
    nonce: str = "",
    finished: Callable[[Job], None] = lambda job: None,
) -> None:
    """Run ``jobs`` on Ray (datasets first, cells after their dataset), appending the steps run to ``log``
    and calling ``finished(job)`` for each job done (before, or now: its files unpacked); InputError lists the
    jobs that still failed after ``cfg.retries`` retries."""
    ray = require_ray()
    if all((cfg.out / job.done).is_file() for job in jobs):
        for job in jobs:
            finished(job)
        return  # all finished before: no cluster needed
    started = _connect(ray, cfg.address) and _starts_local(cfg.address)
    if problem := _cluster_problem(ray.cluster_resources(), cfg):
        if started:  # a local cluster started here never grows: its tasks would wait forever
            ray.shutdown()
            raise InputError(problem[1], param=problem[0])
        print(f"spikenerf: warning: {problem[1]} now; its cells wait until a node that has them joins",
              file=sys.stderr, flush=True)  # fmt: skip
    out = str(cfg.out.resolve())
    gpus = cfg.device.startswith("cuda") or (
        cfg.device == "auto" and ray.cluster_resources().get("GPU", 0) > 0
    )
    task = ray.remote(num_cpus=cfg.ray_cpus, max_retries=cfg.retries, retry_exceptions=True)(execute)
    refs: dict[Any, Job] = {}
    by_name: dict[str, Any] = {}
    datasets = {job.name: job for job in jobs if job.needs is None}
    cells = [job for job in jobs if job.needs is not None]
    try:
        for job in jobs:
            if (cfg.out / job.done).is_file():
                finished(job)
                continue  # finished before
            if job.needs and job.needs not in by_name and cfg.ship_results:  # a dataset finished before
                dep = datasets[job.needs]
                by_name[job.needs] = ray.put({"files": pack(Path(out), [dep.folder], out), "done": dep.done})
            opts = {"num_gpus": 1} if gpus and job.needs else {}
            ref = task.options(name=job.name, **opts).remote(
                job, out, cfg.ship_results, _threads(cfg.ray_cpus), by_name.get(job.needs or ""), nonce
            )
            refs[ref], by_name[job.name] = job, ref
        failed = _wait(ray, cfg, refs, cells, log, finished)
    except KeyboardInterrupt:
        _cancel(ray, list(refs))
        raise
    finally:
        if started:
            ray.shutdown()
    if failed:
        names = ", ".join(f"{name} ({why})" for name, why in failed)
        raise InputError(
            f"{len(failed)} job(s) failed after {cfg.retries} retries: {names}; logs in {cfg.out / 'logs'} "
            "(run the same command again to resume)"
        )


def _wait(
    ray: Any,
    cfg: BenchmarkConfig,
    refs: dict[Any, Job],
    cells: list[Job],
    log: list[dict],
    finished: Callable[[Job], None],
) -> list:
    """Collect results as they come (``finished(job)`` for each), with a progress bar of cells done / running
    / failed."""
    failed: list[tuple[str, str]] = []
    pending = set(refs)
    with progress_bar(total=len(cells), desc="benchmark cells (ray)", unit="cell") as bar:
        bar.update(sum(1 for job in cells if job not in refs.values()))
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=1.0)
            for ref in ready:
                pending.discard(ref)
                job = refs[ref]
                try:
                    result = ray.get(ref)
                except ray.exceptions.RayError as err:
                    failed.append((job.name, str(getattr(err, "cause", None) or type(err).__name__)))
                    bar.update(job.needs is not None)
                    continue
                if result["files"]:
                    out = cfg.out.resolve()
                    unpack(out, result["files"], result["done"], str(out))
                log.extend(result["log"])
                finished(job)
                bar.update(job.needs is not None)
            datasets = sum(1 for ref in pending if refs[ref].needs is None)
            running = _running(ray, cfg.ray_cpus, len(pending) - datasets, datasets)
            bar.set_postfix(running=running, failed=len(failed), refresh=False)
            bar.refresh()
    return failed


def _running(ray: Any, cpus: float, cells: int, datasets: int) -> int:
    """Cells running now, estimated: tasks holding the cluster's CPUs, less the datasets in flight, at most
    the cells in flight."""
    try:
        used = ray.cluster_resources().get("CPU", 0) - ray.available_resources().get("CPU", 0)
    except Exception:  # the state may be unavailable for a moment; the count is only for display
        return cells
    return max(0, min(cells, round(used / max(cpus, 1e-9)) - datasets))


def _cancel(ray: Any, refs: list) -> None:
    """Ctrl-C: interrupt the tasks in flight (which kills their ``spikenerf`` step), then force the rest."""
    for ref in refs:
        ray.cancel(ref)
    _, stuck = ray.wait(refs, num_returns=len(refs), timeout=10.0)
    for ref in stuck:
        ray.cancel(ref, force=True)
