"""Held-out check steps: the steps that ``eval``'s no-reference checks score, and the guard band around each
that training never sees (docs/real-data.md, docs/metrics.md).

The check steps are an imported dataset's test keyframes, else ``count`` evenly spaced steps
(:func:`check_steps`, the one definition that ``train`` and ``eval`` share). With the hold-out on, training
drops every image target whose step lies within ``radius`` steps of a check step and every spike window that
overlaps such a band. The default radius (:func:`guard_radius`) makes the spikes that training reads disjoint
from the spikes that the check of step c reads. TFI and TFSTP have no window (they read out to the
neighbouring spikes, TFSTP from step 0): with the hold-out on, their training targets are reconstructed with
the stream cut at the band edges (:meth:`Holdout.cuts`) and the check's image of step c from steps
c−e..c+e alone (:func:`check_reach`), so both read only their own steps.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from torch import Tensor

from spikenerf.camera.reconstruct import WINDOWLESS
from spikenerf.core.atomic import write_text_atomic
from spikenerf.core.errors import InputError

if TYPE_CHECKING:
    from spikenerf.data.dataset import SpikeDataset

#: the run's record of its held-out steps (written by ``train``, read by ``eval``)
HOLDOUT_FILE = "holdout.json"


def is_imported(dataset: SpikeDataset) -> bool:
    """Whether the dataset was written by ``spikenerf import`` (its config has an ``imported`` section)."""
    return isinstance((dataset.config or {}).get("imported"), dict)


def check_steps(dataset: SpikeDataset, count: int) -> tuple[np.ndarray, str]:
    """Stream indices (N,) int64 of the check steps and where they come from."""
    total = len(dataset.trajectory)
    keys = ((dataset.config or {}).get("imported") or {}).get("test_keyframes")
    if keys:
        try:
            steps = np.asarray(keys, dtype=np.int64).reshape(-1)
        except (TypeError, ValueError):
            raise InputError(
                f"config.yaml: imported.test_keyframes must be a list of step indices, found {keys!r}",
                path=dataset.root,
            ) from None
        if steps.min() < 0 or steps.max() >= total:
            raise InputError("config.yaml: imported.test_keyframes lie outside the stream", path=dataset.root)
        return steps, "the imported test keyframes"
    n = min(count, total)
    return np.unique(np.linspace(0, total - 1, n + 2)[1:-1].round().astype(np.int64)), "evenly spaced steps"


def check_reach(recon_window: int, mask_n: int, spike_window: int) -> int:
    """e: the check of step c reads spikes c−e..c+e, e = max(a, L//2) (a = max(TFP or learned half
    window, mask n): its reconstruction and mask; and the L-step spike window centred on c). A TFI or
    TFSTP image of c is made from those steps alone where the hold-out is on."""
    return max(recon_window // 2, mask_n, spike_window // 2)


def guard_radius(recon_window: int, mask_n: int, spike_window: int) -> int:
    """The default band half-width r: a training target at step k reads spikes k−a..k+a (a = max(TFP or
    learned half window, mask n); a TFI or TFSTP one the stretch between bands that holds k, and its mask);
    the check of step c reads c−e..c+e (:func:`check_reach`). r = a + e keeps the two sets of spikes
    apart."""
    return max(recon_window // 2, mask_n) + check_reach(recon_window, mask_n, spike_window)


@dataclass(frozen=True)
class Holdout:
    """The check steps of a run and their guard bands.

    Attributes:
        steps: (N,) int64 stream indices of the check steps. radius: r. total: T, steps in the stream.
        source: where the steps come from (see :func:`check_steps`). recon: the run's reconstruction (its
        targets' and the check's). reach: e, the steps either side of a check step that the check reads
        (:func:`check_reach`). whole: a resumed run that began before the cut (its record has no
        ``recon_cut``): its TFI or TFSTP targets stay those of the whole stream, as it began.
    """

    steps: np.ndarray
    radius: int
    total: int
    source: str
    recon: str = "tfp"
    reach: int = 0
    whole: bool = False

    @property
    def cut(self) -> bool:
        """Whether the reconstruction reads past any window (TFI, TFSTP) and the run is not :attr:`whole`:
        then training reconstructs the stream cut at :meth:`cuts` and the check each step c from steps
        c−e..c+e alone."""
        return self.recon in WINDOWLESS and not self.whole

    def band(self) -> np.ndarray:
        """(T,) bool: True at stream indices within ``radius`` of a check step."""
        idx = np.arange(self.total)
        return (np.abs(idx[:, None] - self.steps[None, :]) <= self.radius).any(axis=1)

    def image_indices(self, image_steps: Tensor, stream_steps: np.ndarray) -> Tensor:
        """(K',) int64 indices of the image targets to train on: those whose spike step (``image_steps``
        (K,), numbers of ``stream_steps`` (T,); −1 unknown) lies outside every band."""
        banned = stream_steps[self.band()]
        keep = ~np.isin(np.asarray(image_steps), banned)
        if (np.asarray(image_steps) < 0).any():
            raise InputError("the hold-out needs the spike step of every image target", param="holdout")
        return torch.as_tensor(np.flatnonzero(keep), dtype=torch.int64)

    def cuts(self) -> np.ndarray:
        """(M,) int64 the stream indices where a band begins or ends (the first step in or past it): cut
        there, no piece of the stream holds both a trained step and a banded one."""
        return np.flatnonzero(np.diff(self.band())) + 1

    def window_starts(self, length: int) -> Tensor:
        """(S,) int64 first steps of the L-step windows ``[s, s + L)`` that overlap no band."""
        hit = np.concatenate([[0], np.cumsum(self.band())])
        starts = np.arange(self.total - length + 1)
        return torch.as_tensor(starts[hit[starts + length] == hit[starts]], dtype=torch.int64)

    def record(self, stream_steps: np.ndarray) -> dict[str, Any]:
        """What ``RUN/holdout.json`` holds: check steps (indices and step numbers, from ``stream_steps`` (T,)
        int64, the stream's step numbers), radius, source, band; the reconstruction, whether it was cut
        (:attr:`cut`) and the check's reach e."""
        return {
            "check_steps": [int(s) for s in self.steps],
            "step_numbers": [int(stream_steps[s]) for s in self.steps],
            "radius": self.radius,
            "source": self.source,
            "excluded_steps": int(self.band().sum()),
            "total_steps": self.total,
            "recon": self.recon,
            "recon_cut": self.cut,
            "check_reach": self.reach,
        }


def checked(holdout: Holdout, trainable: int, what: str) -> None:
    """InputError naming ``holdout_radius`` and ``holdout_steps`` when the bands leave nothing of ``what`` to
    train on."""
    if trainable < 1:
        raise InputError(
            f"holdout_radius {holdout.radius} around {len(holdout.steps)} check steps leaves no {what} of "
            f"the {holdout.total} steps to train on; lower it, check fewer holdout_steps or turn the "
            "hold-out off",
            param=("holdout_radius", "holdout_steps"),
        )


def write_record(run_dir: str | Path, record: dict[str, Any] | None) -> None:
    """Write ``RUN/holdout.json`` atomically (``record`` None: remove a stale one)."""
    path = Path(run_dir) / HOLDOUT_FILE
    if record is None:
        path.unlink(missing_ok=True)
    else:
        write_text_atomic(path, json.dumps(record, indent=2) + "\n")


def read_record(run_dir: str | Path) -> dict[str, Any] | None:
    """``RUN/holdout.json``, or None when the run trained on every step; an InputError naming the file when
    it is malformed (a record whose reconstruction was cut, ``recon_cut`` true, holds ``check_reach``)."""
    path = Path(run_dir) / HOLDOUT_FILE
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError) as err:  # (UnicodeDecodeError, JSONDecodeError: ValueErrors)
        raise InputError(f"malformed hold-out record ({type(err).__name__}: {err})", path=path) from None
    if not isinstance(data, dict):
        raise InputError(f"malformed hold-out record (expected an object, found {type(data).__name__})", path)
    if "check_steps" not in data:
        raise InputError("malformed hold-out record (no check_steps)", path=path)
    for key in ("check_steps", "step_numbers"):
        values = data.get(key, [])
        if not (isinstance(values, list) and all(_count(v) for v in values)):
            raise InputError(
                f"malformed hold-out record ({key}: expected a list of integers ≥ 0, found {values!r:.60})",
                path,
            )
    if not isinstance(data.get("recon_cut", False), bool):
        raise InputError(f"malformed hold-out record (recon_cut: expected true or false, found "
                         f"{data['recon_cut']!r:.60})", path)  # fmt: skip
    for key in ("radius", "excluded_steps", "total_steps", "check_reach"):
        if key in data and not _count(data[key]):
            raise InputError(
                f"malformed hold-out record ({key}: expected an integer ≥ 0, found {data[key]!r:.60})", path
            )
    if data.get("recon_cut") is True and "check_reach" not in data:  # (eval would read the whole stream)
        raise InputError(
            "malformed hold-out record (recon_cut is true but check_reach is missing: the steps either side "
            "of a check step that its reconstruction reads)",
            path,
        )
    return data


def _count(value: object) -> bool:
    """Whether ``value`` is an integer ≥ 0 (a JSON true is none) that an int64 holds (the steps index numpy
    arrays: 10**400 was an OverflowError there)."""
    return isinstance(value, int) and not isinstance(value, bool) and 0 <= value < 2**63


def make_holdout(
    dataset: SpikeDataset,
    on: bool | None,
    count: int,
    radius: int,
    recon: str = "tfp",
    reach: int = 0,
    whole: bool = False,
) -> Holdout | None:
    """The run's :class:`Holdout`, or None when it trains on every step (``on`` None: on for imported
    datasets). ``count``: check steps of a dataset without imported test keyframes; ``recon``, ``reach``,
    ``whole``: see :class:`Holdout`."""
    if not (is_imported(dataset) if on is None else on):
        return None
    steps, source = check_steps(dataset, count)
    return Holdout(steps, radius, len(dataset.trajectory), source, recon, reach, whole)
