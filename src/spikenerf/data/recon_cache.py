"""Whole-stream learned reconstructions for training targets: built once on the training device and cached
in the run folder.

``train --recon learned`` runs the shipped reconstructor over every step of the stream. The trainer opens
:func:`learned_targets_in` around building its targets; inside it, ``reconstruct_stream(..., "learned")``
(:mod:`spikenerf.data.targets`) runs the network on the training device, several frames per call on CUDA
(``recon.infer.CUDA_BATCH``), and keeps the result as ``RUN/targets/learned-KEY.npy`` (float16, written
atomically). KEY hashes the dataset fingerprint, the stream's bytes, the colour mode, the window, φ and the
weights file, so a changed dataset or option rebuilds it (the old file is removed) and a resumed run reads it
back. Float16 is exact for the targets, which are float16 themselves (masks are 0/1). Outside the context
(``reconstruct``, ``eval``) nothing is cached and the network runs on the CPU as before.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import json
from collections.abc import Iterable, Iterator
from contextvars import ContextVar
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from spikenerf.core.atomic import atomic_path, clean_stale_temps
from spikenerf.core.errors import InputError
from spikenerf.recon.infer import reconstruct_learned

#: the cache's sub-folder of the run folder
CACHE_DIR = "targets"


@dataclass(frozen=True)
class LearnedSettings:
    """Where whole-stream learned reconstructions are cached (None: not cached) and built."""

    folder: Path | None
    device: torch.device
    fingerprint: dict[str, Any] = field(default_factory=dict)


_SETTINGS: ContextVar[LearnedSettings | None] = ContextVar("learned_settings", default=None)


@contextlib.contextmanager
def learned_targets_in(
    folder: str | Path | None, device: torch.device | str, fingerprint: dict[str, Any] | None = None
) -> Iterator[LearnedSettings]:
    """Inside: whole-stream learned reconstructions run on ``device`` and are cached under
    ``folder/targets`` (``folder`` None: not cached); ``fingerprint`` (the dataset's) is part of the key."""
    settings = LearnedSettings(
        None if folder is None else Path(folder), torch.device(device), dict(fingerprint or {})
    )
    token = _SETTINGS.set(settings)
    try:
        yield settings
    finally:
        _SETTINGS.reset(token)


def _digest(chunks: Iterable[bytes]) -> str:
    h = hashlib.blake2b(digest_size=16)
    for chunk in chunks:
        h.update(chunk)
    return h.hexdigest()


def stream_digest(spikes: np.ndarray) -> str:
    """A digest of an array's shape, dtype and bytes, e.g. a (T, ...) stream; read about 1 MB of leading
    rows at a time, so a memory-mapped stream is never loaded whole (a scalar counts as one row)."""
    a = np.atleast_1d(np.asarray(spikes))
    head = [repr((a.shape, str(a.dtype))).encode()]
    rows = max(1, (1 << 20) // max(a[:1].nbytes, 1))
    chunks = (np.ascontiguousarray(a[i : i + rows]).tobytes() for i in range(0, len(a), rows))
    return _digest(itertools.chain(head, chunks))


def cache_key(
    spikes: np.ndarray, mode: str, window: int | None, threshold: float, weights: Path,
    fingerprint: dict[str, Any],
) -> str:  # fmt: skip
    """The cache key: 16 hex digits of the dataset fingerprint, the stream ``spikes`` (T, H, W) or
    (T, 3, H, W), mode, window, φ and weights."""
    parts = {
        "fingerprint": fingerprint,
        "stream": stream_digest(spikes),
        "recon": "learned",
        "mode": mode,
        "window": window,
        "threshold": float(threshold),
        "weights": _digest([_weights_bytes(Path(weights))]),
    }
    return hashlib.blake2b(json.dumps(parts, sort_keys=True).encode(), digest_size=8).hexdigest()


def _weights_bytes(path: Path) -> bytes:
    """The weights file's bytes; InputError naming it when it cannot be read (as loading it would)."""
    try:
        return path.read_bytes()
    except OSError as err:
        found = "weights file not found" if not path.exists() else f"weights file unreadable ({err.strerror})"
        raise InputError(found, path=path) from err


def build_learned(
    spikes: np.ndarray, mode: str, threshold: float, window: int | None, device: torch.device
) -> np.ndarray:
    """The learned reconstruction float32 (T, ...) of every step of ``spikes``, batched on ``device``."""
    return reconstruct_learned(spikes, mode, threshold, window=window, device=device)


def _read(path: Path, shape: tuple[int, ...]) -> np.ndarray | None:
    """The cached float16 array, or None when it is missing, unreadable, of another shape or not finite."""
    try:
        cached = np.load(path, allow_pickle=False)
    except (OSError, ValueError):
        return None
    if cached.shape != shape or cached.dtype != np.float16:
        return None
    return cached if np.isfinite(cached).all() else None  # damaged (NaN or inf): built again


def learned_stream(
    spikes: np.ndarray, threshold: float = 1.0, frames: slice | None = None, window: int | None = None
) -> np.ndarray:
    """The learned reconstruction float32 (N, ...) of a (T, H, W) gray or (T, 3, H, W) rgb stream.

    Inside :func:`learned_targets_in` and for the whole stream (``frames`` None): on its device, from or into
    its cache (values rounded to float16). Otherwise: ``reconstruct_learned`` on the CPU, unrounded.
    """
    mode = "rgb" if np.ndim(spikes) == 4 else "gray"
    settings = _SETTINGS.get()
    if settings is None or frames is not None:
        return reconstruct_learned(spikes, mode, threshold, frames=frames, window=window)
    if settings.folder is None:
        built = build_learned(spikes, mode, threshold, window, settings.device)
        return built.astype(np.float16).astype(np.float32)
    from spikenerf.recon.net import shipped_weights

    key = cache_key(spikes, mode, window, threshold, shipped_weights(), settings.fingerprint)
    folder = settings.folder / CACHE_DIR
    path = folder / f"learned-{key}.npy"
    cached = _read(path, tuple(np.shape(spikes))) if path.is_file() else None
    if cached is None:
        clean_stale_temps(folder)  # a killed build's partial file (the trainer holds the run's lock)
        cached = build_learned(spikes, mode, threshold, window, settings.device).astype(np.float16)
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.save(fh, cached)
        for old in folder.glob("learned-*.npy"):  # another key: a changed dataset or option
            if old != path:
                old.unlink(missing_ok=True)
    return cached.astype(np.float32)
