"""The pair folder written by ``spikenerf recon-data`` and read by ``spikenerf recon-train``.

Layout: ``OUT/manifest.json`` (the generation settings and the exact command), ``OUT/train/`` and
``OUT/val/`` holding shards ``shard-NNNNN.npz`` with ``spikes`` (N, K, P, ⌈P/8⌉) uint8 — the windows'
bits packed along the last axis — ``targets`` (N, P, P) float32 sharp rates, ``size`` P and ``info`` (JSON
per sample). Shards are written atomically one by one, so an interrupted run resumes at the next shard.
"""

from __future__ import annotations

import io
import json
import tokenize
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from spikenerf.core.atomic import write_bytes_atomic
from spikenerf.core.errors import InputError
from spikenerf.recon.net import MODES
from spikenerf.recon.pairs import Sample

MANIFEST = "manifest.json"
#: the two pair folders of a pair folder: training pairs and held-out validation pairs
SPLITS = ("train", "val")
#: what reading a damaged ``.npz`` raises (a cut zip, a missing member, a bad header, a foreign ``info``; a
#: changed deflate stream: zlib.error; a cut .npy header: TokenError; an ``info`` nested too deeply)
UNREADABLE = (
    OSError,
    KeyError,
    ValueError,
    TypeError,
    EOFError,
    zipfile.BadZipFile,
    zlib.error,
    tokenize.TokenError,
    RecursionError,
)


def shard_path(root: Path, split: str, index: int) -> Path:
    return root / split / f"shard-{index:05d}.npz"


def write_shard(path: Path, samples: list[Sample]) -> None:
    """Pack ``samples`` (all P × P, same K) into one shard, atomically. ValueError when a target is not finite
    (the caller refuses such a draw first: a shard that :func:`read_shard` refuses is never written)."""
    spikes = np.packbits(np.stack([s.window for s in samples]).astype(bool), axis=-1)
    targets = np.stack([s.target for s in samples]).astype(np.float32)
    if not np.isfinite(targets).all():
        raise ValueError(f"{path}: pair targets are not finite (NaN or inf); not writing the shard")
    info = np.array([json.dumps(s.info) for s in samples])
    buf = io.BytesIO()
    np.savez_compressed(buf, spikes=spikes, targets=targets, size=np.int64(targets.shape[-1]), info=info)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_bytes_atomic(path, buf.getvalue())


@dataclass
class PairSet:
    """All samples of one split in memory, bits still packed.

    Attributes:
        spikes: uint8 (N, K, P, ⌈P/8⌉) packed windows. targets: float32 (N, P, P). info: N dicts.
    """

    spikes: torch.Tensor
    targets: torch.Tensor
    info: list[dict]

    def __len__(self) -> int:
        return int(self.targets.shape[0])

    @property
    def window(self) -> int:
        return int(self.spikes.shape[1])

    def windows(self, index: torch.Tensor) -> torch.Tensor:
        """Unpacked windows (B, K, P, P) float32 of samples ``index`` (B,)."""
        packed = self.spikes[index]
        bits = torch.arange(7, -1, -1, dtype=torch.uint8)
        unpacked = (packed.unsqueeze(-1) >> bits) & 1
        size = self.targets.shape[-1]
        return unpacked.flatten(-2)[..., :size].float()


def load_split(root: str | Path, split: str, manifest: dict | None = None) -> PairSet:
    """Read every shard of ``root/split`` (each checked by :func:`read_shard` against the folder's manifest,
    read unless given); an empty or malformed folder is an InputError."""
    config = (read_manifest(root) if manifest is None else manifest)["config"]
    folder = Path(root) / split
    files = sorted(folder.glob("shard-*.npz"))
    if not files:
        raise InputError(f"no pair shards in {split}/ (write them with `spikenerf recon-data`)", path=root)
    spikes, targets, info = [], [], []
    for f in files:
        s, t, i = read_shard(f, config["window"], config["size"])
        spikes.append(s)
        targets.append(t)
        info += i
    return PairSet(torch.from_numpy(np.concatenate(spikes)), torch.from_numpy(np.concatenate(targets)), info)


def read_shard(path: Path, window: int, size: int) -> tuple[np.ndarray, np.ndarray, list[dict]]:
    """The packed spikes, targets and info of the shard ``path`` of ``window`` K steps and ``size`` P pixels.

    Raises:
        InputError: the shard is unreadable (truncated, not an .npz, a member missing), its arrays are not
            uint8 (N, K, P, ⌈P/8⌉) and float32 (N, P, P) with N ≥ 1 info entries, or a target is not finite.
    """
    try:
        with np.load(path, allow_pickle=False) as z:
            spikes, targets = z["spikes"], z["targets"]
            info = [json.loads(s) for s in z["info"]]
    except UNREADABLE as err:
        raise InputError(f"unreadable pair shard ({type(err).__name__})", path=path) from err
    k, p, n = window, size, len(info)
    found = (spikes.dtype, spikes.shape, targets.dtype, targets.shape)
    if n == 0 or found != (np.uint8, (n, k, p, -(-p // 8)), np.float32, (n, p, p)):
        raise InputError(
            f"malformed pair shard: spikes {spikes.dtype}{spikes.shape}, targets {targets.dtype}"
            f"{targets.shape} and {n} info entries; expected uint8(N, {k}, {p}, {-(-p // 8)}), "
            f"float32(N, {p}, {p}) and N ≥ 1 (window {k}, size {p} of {MANIFEST})",
            path=path,
        )
    if not np.isfinite(targets).all():
        raise InputError("pair shard has non-finite targets (NaN or inf)", path=path)
    return spikes, targets, info


def shard_ok(path: Path, window: int, size: int) -> bool:
    """True when ``path`` is a whole shard that :func:`read_shard` accepts (a resume writes others again)."""
    try:
        read_shard(path, window, size)
    except InputError:
        return False
    return True


def read_manifest(root: str | Path) -> dict:
    """The folder's manifest, with the fields recon-train relies on checked (``config`` with ``size``,
    ``window`` and ``modes``); InputError naming the file when it is missing, corrupt or malformed."""
    path = Path(root) / MANIFEST
    if not Path(root).is_dir():
        found = "is a file, not a pair folder" if Path(root).exists() else "pair folder not found"
        raise InputError(f"{found} (write one with `spikenerf recon-data`)", path=root)
    if not path.is_file():
        raise InputError("not a pair folder written by `spikenerf recon-data` (no manifest.json)", path=root)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, RecursionError) as err:  # (JSONDecodeError, UnicodeDecodeError: ValueErrors)
        raise InputError(f"corrupt manifest.json ({type(err).__name__})", path=path) from err
    if not isinstance(data, dict):
        raise InputError("corrupt manifest.json (not a JSON object)", path=path)
    config = data.get("config", _MISSING)
    sub = config if isinstance(config, dict) else {}
    size, window, modes = (sub.get(key, _MISSING) for key in ("size", "window", "modes"))
    for name, value, ok, expected in (
        ("config", config, isinstance(config, dict), "an object"),
        ("config.size", size, _count(size), "an integer ≥ 1"),
        ("config.window", window, _count(window), "an integer ≥ 1"),
        ("config.modes", modes, isinstance(modes, list) and modes and all(m in MODES for m in modes),
         "a list of " + ", ".join(MODES)),
    ):  # fmt: skip
        if not ok:
            found = "nothing" if value is _MISSING else json.dumps(value)
            raise InputError(f"malformed manifest.json: {name} must be {expected}, found {found}", path=path)
    return data


_MISSING = object()


def _count(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 1
