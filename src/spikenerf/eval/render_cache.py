"""What an interrupted ``spikenerf render`` has done, kept so that running it again continues.

The cache lives in ``OUT/.render-cache/`` while a render runs and is deleted when ``render.json`` is written:

- ``key.json``: what the views depend on (:func:`render_key`: a digest of the model's tensors, its config,
  the versions of spikenerf and torch, the poses, the camera, near/far, precision and the device type; for
  the spike stream its poses, seed and threshold), the values resolved when the cache began (the automatic
  chunk), which a resumed render reuses, and the files the render will write (its ``plan``, for the next
  render to clear). A cache with another key is deleted, so a changed run or trajectory never mixes with
  the old views.
- ``views/NNNNN.npz``: each rendered view (8-bit colour, float32 depth and opacity), written atomically
  after it is rendered. An unreadable or mis-sized file is rendered again.
- ``spikes.bits`` and ``spikes.npz``: the spike stream so far, one packed step after another, and, every
  :data:`SPIKE_STATE_EVERY` steps, the step count and the accumulators after it (written atomically after
  the bits it counts). A resumed stream starts from that state and fires the same spikes as an
  uninterrupted one.
"""

from __future__ import annotations

import hashlib
import io
import json
import shutil
import tokenize
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import torch

from spikenerf.core.atomic import clean_stale_temps, write_bytes_atomic, write_text_atomic
from spikenerf.core.faults import failpoint
from spikenerf.data.recon_cache import stream_digest

CACHE = ".render-cache"
#: steps between two saved spike states: the state (float32 accumulators) costs 32 steps' packed spikes
SPIKE_STATE_EVERY = 32
#: what reading a damaged cache file raises (a cut zip, a missing member, a bad header; a changed deflate
#: stream: zlib.error; a cut .npy header: TokenError; JSON nested beyond the stack; a step count of inf)
UNREADABLE = (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile, zlib.error,
              tokenize.TokenError, RecursionError, OverflowError)  # fmt: skip


def digest_array(array: np.ndarray | torch.Tensor) -> str:
    """A digest of an array's dtype, shape and bytes (``data.recon_cache.stream_digest``; a tensor of any
    dtype, bfloat16 included, through a byte view of its memory)."""
    if not isinstance(array, torch.Tensor):
        return stream_digest(array)
    t = array.detach().cpu().contiguous()
    raw = t.reshape(-1).view(torch.uint8).numpy() if t.numel() else np.zeros(0, np.uint8)
    return f"{t.dtype}{tuple(t.shape)}:{stream_digest(raw)}"


def model_digest(model: torch.nn.Module) -> str:
    """sha256 over the model's state (names and tensors, in name order)."""
    h = hashlib.sha256()
    for name, value in sorted(model.state_dict().items()):
        h.update(name.encode())
        h.update(digest_array(value).encode())
    return h.hexdigest()


def render_key(model: torch.nn.Module, **settings: Any) -> dict[str, Any]:
    """The cache key: the model's digest and ``settings`` (JSON values; arrays become their digests)."""
    arrays = np.ndarray | torch.Tensor
    plain = {k: digest_array(v) if isinstance(v, arrays) else v for k, v in settings.items()}
    return {"model": model_digest(model), **plain}


class RenderCache:
    """The cache folder of one render (see the module doc); :meth:`open` keeps or clears it by key."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.pinned: dict[str, Any] = {}

    @classmethod
    def open(
        cls, out: Path, key: dict[str, Any], pinned: dict[str, Any] | None = None, plan: Any = None
    ) -> RenderCache:
        """The cache in ``out``, kept where its ``key.json`` holds ``key`` and started afresh otherwise.
        ``pinned``: values resolved when the cache was started (the automatic chunk, which depends on the
        free GPU memory) that a resumed render reuses; :attr:`pinned` holds the cache's own where it is kept
        (each still of its given type), these otherwise. ``plan``: what this render will write (JSON), kept
        in ``key.json`` for the next render to clear should this one be interrupted."""
        root = out / CACHE
        wanted = json.loads(json.dumps(key, sort_keys=True, default=str))
        given = json.loads(json.dumps(pinned or {}, default=str))
        try:
            stored = json.loads((root / "key.json").read_text())
            kept = stored["key"] == wanted and set(stored["pinned"]) == set(given)
            kept = kept and all(type(stored["pinned"][k]) is type(v) for k, v in given.items())
        except UNREADABLE:
            kept = False
        if not kept:
            _remove(root)
            (root / "views").mkdir(parents=True, exist_ok=True)
            stored = {"key": wanted, "pinned": given}
        stored["plan"] = plan
        write_text_atomic(root / "key.json", json.dumps(stored, sort_keys=True))
        for folder in (root, root / "views"):  # a killed writer's temporaries (the caller holds the lock)
            clean_stale_temps(folder)
        cache = cls(root)
        cache.pinned = stored["pinned"]
        return cache

    def _view_path(self, index: int) -> Path:
        return self.root / "views" / f"{index:05d}.npz"

    def view(
        self, index: int, size: tuple[int, int], channels: int | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(colour uint8, depth, opacity) of view ``index`` if cached whole at ``size`` (H, W); else None.
        ``channels`` (1 or 3, where given): the colour's, (H, W) or (H, W, 3); depth and opacity are (H, W)
        float32 then."""
        try:
            with np.load(self._view_path(index)) as data:
                found = data["color"], data["depth"], data["opacity"]
        except UNREADABLE:
            return None
        if any(a.shape[:2] != size for a in found) or found[0].dtype != np.uint8:
            return None
        if channels is not None and (
            found[0].shape != (size if channels == 1 else (*size, 3))
            or any(a.shape != size or a.dtype != np.float32 for a in found[1:])
        ):
            return None
        return found

    def put_view(self, index: int, color: np.ndarray, depth: np.ndarray, opacity: np.ndarray) -> None:
        """Keep view ``index`` (atomically), then pass the ``render.view`` fail point."""
        buf = io.BytesIO()
        np.savez(buf, color=color, depth=depth.astype(np.float32), opacity=opacity.astype(np.float32))
        write_bytes_atomic(self._view_path(index), buf.getvalue())
        failpoint("render.view")

    def spike_state(self, step_shape: tuple[int, ...]) -> tuple[list[np.ndarray], np.ndarray] | None:
        """(the steps fired so far, each bool ``step_shape``; the accumulators after the last, camera layout)
        from the last saved state, or None (nothing saved, or the files disagree)."""
        try:
            with np.load(self.root / "spikes.npz") as data:
                count, acc = int(data["steps"].item()), data["accumulator"]
            bits = (self.root / "spikes.bits").read_bytes()
        except UNREADABLE:
            return None
        per_step = _packed_size(step_shape)
        if acc.shape != step_shape or count < 1 or len(bits) < count * per_step:
            return None
        n = int(np.prod(step_shape))
        flat = np.frombuffer(bits[: count * per_step], np.uint8).reshape(count, per_step)
        steps = [np.unpackbits(row, count=n).astype(bool).reshape(step_shape) for row in flat]
        return steps, acc

    def start_spikes(self, kept: int, step_shape: tuple[int, ...]) -> None:
        """Cut ``spikes.bits`` to the ``kept`` steps a resumed stream starts from (0: a new stream)."""
        with open(self.root / "spikes.bits", "ab") as fh:
            fh.truncate(kept * _packed_size(step_shape))

    def put_spike_step(self, count: int, spikes: np.ndarray, accumulator: torch.Tensor) -> None:
        """Append step ``count``'s spikes (the ``count``-th, from 1); every :data:`SPIKE_STATE_EVERY` steps
        also save the state after it (``accumulator``: camera layout, any device) and pass the
        ``render.spikes`` fail point."""
        with open(self.root / "spikes.bits", "ab") as fh:
            fh.write(np.packbits(spikes.reshape(-1)).tobytes())
        if count % SPIKE_STATE_EVERY == 0:
            buf = io.BytesIO()
            acc = accumulator.detach().float().cpu().numpy()
            np.savez(buf, steps=np.int64(count), accumulator=acc)
            write_bytes_atomic(self.root / "spikes.npz", buf.getvalue())
            failpoint("render.spikes")

    def close(self) -> None:
        """Delete the cache (the render is complete: a cache that cannot be deleted is left, not an error)."""
        shutil.rmtree(self.root, ignore_errors=True)


def cache_bytes(out: Path) -> int:
    """Bytes the cache in ``out`` holds (0 without one): space a resumed render will not need again."""
    root = out / CACHE
    return sum(p.stat().st_size for p in root.rglob("*") if p.is_file()) if root.is_dir() else 0


def _remove(root: Path) -> None:
    """Delete the cache folder ``root`` (or a file in its place)."""
    if root.is_dir() and not root.is_symlink():
        shutil.rmtree(root)
    else:
        root.unlink(missing_ok=True)


def _packed_size(step_shape: tuple[int, ...]) -> int:
    return (int(np.prod(step_shape)) + 7) // 8
