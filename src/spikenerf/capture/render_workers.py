"""Rendering a scene's frames in worker processes (``simulate --jobs N``): :func:`render_frames` yields the
frames of the steps in order, from a pool of spawned processes where the source allows it
(``parallel_render``), each with its share of the cores' math-library threads (:func:`worker_env`) and no
more processes than cores or frames (:func:`usable_jobs`)."""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import pickle
import signal
import tempfile
import threading
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from spikenerf.scenes.base import FrameSource

#: the source a render worker process draws from (set once per worker by :func:`_init_render_worker`)
_WORKER_SOURCE: FrameSource | None = None


def _init_render_worker(source_file: str) -> None:
    """Load the source the parent pickled to ``source_file``: passed by name, it keeps the pickle that
    starts each worker small, so starting one does not wait for it to import torch (see
    :func:`render_frames`)."""
    global _WORKER_SOURCE
    with open(source_file, "rb") as fh:
        _WORKER_SOURCE = pickle.load(fh)


def _render_step(step: int) -> np.ndarray:
    assert _WORKER_SOURCE is not None
    return np.asarray(next(iter(_WORKER_SOURCE.frames([step]))))


#: thread-count variables of the math libraries a render worker may use (numpy's BLAS, OpenMP, MKL)
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def _cores() -> int:
    """CPU cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not on Linux
        return os.cpu_count() or 1


def usable_jobs(jobs: int, work: int) -> int:
    """Worker processes worth starting for ``work`` items: ``jobs``, but no more than the items and the
    CPU cores this process may use (``--jobs 100000`` starts a process per core, not per step)."""
    return max(1, min(jobs, work, _cores()))


def worker_env(jobs: int) -> dict[str, str]:
    """Thread counts for ``jobs`` worker processes: each its share of the cores, so that their math
    libraries (numpy's BLAS threads a frame's large products) do not start a pool per core in every worker;
    a variable already set is kept."""
    share = str(max(1, _cores() // jobs))
    return {name: os.environ.get(name, share) for name in THREAD_VARS}


def render_frames(source: FrameSource, steps: list[int], jobs: int) -> Iterator[np.ndarray]:
    """The frames (H, W, 3) of ``steps`` in order: from ``jobs`` worker processes when the source allows it
    (``parallel_render``: a picklable source whose frames depend on the step alone), else in this one."""
    jobs = usable_jobs(jobs, len(steps))
    if jobs <= 1 or not getattr(source, "parallel_render", False):
        yield from source.frames(steps)
        return
    ctx = multiprocessing.get_context("spawn")  # no fork of a process that may hold torch threads
    saved = {name: os.environ.get(name) for name in THREAD_VARS}
    pool = None
    with tempfile.TemporaryDirectory(prefix="spikenerf-render-") as folder:
        source_file = os.path.join(folder, "source.pkl")
        with open(source_file, "wb") as fh:
            pickle.dump(source, fh)
        try:
            os.environ.update(worker_env(jobs))  # read by the workers as they start (all of them in map())
            # the workers start with Ctrl-C ignored, so that one during their start prints no traceback and
            # the parent alone stops the run; starting them takes milliseconds (the source goes by file),
            # so the parent's own Ctrl-C is not lost meanwhile
            with _sigint_ignored():
                pool = ProcessPoolExecutor(jobs, ctx, _init_render_worker, (source_file,))
                frames = pool.map(_render_step, steps, chunksize=max(1, min(8, len(steps) // (4 * jobs))))
            _restore(saved)  # the workers have started: the caller iterates with its own settings
            yield from frames
        finally:
            _restore(saved)
            if pool is not None:  # on an interrupt the workers finish their chunk of frames, no more
                pool.shutdown(wait=True, cancel_futures=True)


@contextlib.contextmanager
def _sigint_ignored() -> Iterator[None]:
    """SIGINT ignored in this process meanwhile (the main thread only), so that processes started in it
    inherit the ignoring (Python keeps an inherited SIG_IGN) and print no traceback on a Ctrl-C."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _restore(saved: dict[str, str | None]) -> None:
    for name, value in saved.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value
