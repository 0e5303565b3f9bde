"""The pair folder written by ``spikenerf recon-data`` and read by ``spikenerf recon-train``.

Layout: ``OUT/manifest.json`` (the generation settings and the exact command), ``OUT/train/`` and
``OUT/val/`` holding shards ``shard-NNNNN.npz`` with ``spikes`` (N, K, P, ⌈P/8⌉) uint8 — the windows'
bits packed along the last axis — ``targets`` (N, P, P) float32 sharp rates, ``size`` P and ``info`` (JSON
per sample). Shards are written atomically one by one, so an interrupted run resumes at the next shard.
"""

from __future__ import annotations

import io
import json
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from spikenerf.core.atomic import write_bytes_atomic
from spikenerf.core.errors import InputError
from spikenerf.recon.pairs import Sample

MANIFEST = "manifest.json"
SPLITS = ("train", "val")


def shard_path(root: Path, split: str, index: int) -> Path:
    return root / split / f"shard-{index:05d}.npz"


def write_shard(path: Path, samples: list[Sample]) -> None:
    """Pack ``samples`` (all P × P, same K) into one shard, atomically."""
    spikes = np.packbits(np.stack([s.window for s in samples]).astype(bool), axis=-1)
    targets = np.stack([s.target for s in samples]).astype(np.float32)
    info = np.array([json.dumps(s.info) for s in samples])
    buf = io.BytesIO()
    np.savez_compressed(buf, spikes=spikes, targets=targets, size=np.int64(targets.shape[-1]), info=info)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_bytes_atomic(path, buf.getvalue())


def batched(samples: Iterable[Sample], per_shard: int) -> Iterator[list[Sample]]:
    """Group a sample stream into lists of ``per_shard`` (the last may be shorter)."""
    group: list[Sample] = []
    for s in samples:
        group.append(s)
        if len(group) == per_shard:
            yield group
            group = []
    if group:
        yield group


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


def load_split(root: str | Path, split: str) -> PairSet:
    """Read every shard of ``root/split``; an empty or malformed folder is an InputError."""
    folder = Path(root) / split
    files = sorted(folder.glob("shard-*.npz"))
    if not files:
        raise InputError(f"no pair shards in {split}/ (write them with `spikenerf recon-data`)", path=root)
    spikes, targets, info = [], [], []
    for f in files:
        try:
            with np.load(f, allow_pickle=False) as z:
                spikes.append(z["spikes"])
                targets.append(z["targets"])
                info += [json.loads(s) for s in z["info"]]
        except (OSError, KeyError, ValueError) as err:
            raise InputError(f"unreadable pair shard ({type(err).__name__})", path=f) from err
    if len({s.shape[1:] for s in spikes}) != 1:
        raise InputError("pair shards differ in window or size; regenerate the folder", path=folder)
    return PairSet(torch.from_numpy(np.concatenate(spikes)), torch.from_numpy(np.concatenate(targets)), info)


def read_manifest(root: str | Path) -> dict:
    path = Path(root) / MANIFEST
    if not path.is_file():
        raise InputError("not a pair folder written by `spikenerf recon-data` (no manifest.json)", path=root)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as err:  # JSONDecodeError is a ValueError
        raise InputError(f"corrupt manifest.json ({type(err).__name__})", path=path) from err
    if not isinstance(data, dict):
        raise InputError("corrupt manifest.json (not a JSON object)", path=path)
    return data
