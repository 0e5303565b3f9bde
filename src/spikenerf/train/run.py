"""Loading a finished (or checkpointed) run folder for ``render`` and ``eval``."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import MISSING, dataclass, fields
from pathlib import Path

import numpy as np
import torch

from spikenerf.core.device import resolve_device
from spikenerf.core.errors import InputError, as_path, is_finite, is_integer
from spikenerf.data.dataset import CONFIG as DATASET_CONFIG
from spikenerf.data.dataset import SpikeDataset, load_dataset, read_mapping, spike_files
from spikenerf.data.holdout import read_record
from spikenerf.render.base import RadianceModel
from spikenerf.train.checkpoint import CHECKPOINT, check_same_run, load_checkpoint, model_of
from spikenerf.train.config import TrainConfig
from spikenerf.train.config_file import CONFIG_FILE, load_run_config
from spikenerf.train.methods import make_method
from spikenerf.train.sensor_response import SENSOR_MAP, read_sensor_map

#: a metrics file and the run's iterations → the lines ``info`` prints of it (``eval.describe.metrics_lines``)
MetricsLines = Callable[[Path, int], list[str]]
#: what a run that reached its iterations reports (:class:`TrainSummary`)
SUMMARY = "summary.json"


@dataclass
class TrainSummary:
    """What a finished (or stopped) run reports; also written to ``RUN/summary.json``."""

    iteration: int
    seconds: float
    rays_per_second: float
    train_psnr: float
    test_psnr: float
    device: str
    #: test views the test PSNR was scored on (``eval_views`` of them), and the dataset's (0: not recorded)
    test_views: int = 0
    dataset_views: int = 0

    def test_text(self) -> str:
        """``18.10 dB``, ``18.10 dB (on 3 of 5 test views; eval scores all)``, or ``n/a``."""
        if self.test_psnr != self.test_psnr:
            return "n/a"
        part = 0 < self.test_views < self.dataset_views
        of = f" (on {self.test_views} of {self.dataset_views} test views; eval scores all)" if part else ""
        return f"{self.test_psnr:.2f} dB{of}"


def _db(value: float) -> str:
    """A PSNR for ``info``: ``24.01 dB``, or ``n/a`` where none was scored (NaN: no test views, or a value
    that summary.json could not hold), as ``train`` prints it."""
    return "n/a" if value != value else f"{value:.2f} dB"


def read_summary(out: Path) -> TrainSummary | None:
    """``out``'s ``summary.json`` (None where there is none); InputError naming it where it does not read
    back whole: not a JSON object, a field missing, a value of another type or an int beyond a float (edited
    in: ``info`` could not show it). ``info`` reports such a file; a resume writes it again."""
    path = Path(out) / SUMMARY
    if not (path.exists() or path.is_symlink()):
        return None
    again = "delete it, or let `spikenerf train --resume` write it again"
    if path.is_dir():
        raise InputError(f"is a folder, not a training summary ({again})", path=path)
    try:
        data = read_mapping(path)
    except InputError as err:
        raise InputError(f"{err.message} ({again})", path=path) from None
    known = {f.name for f in fields(TrainSummary)}  # (another version's fields beside them are not read)
    if missing := [f.name for f in fields(TrainSummary) if f.default is MISSING and f.name not in data]:
        raise InputError(f"not a training summary: missing field {missing[0]!r} ({again})", path=path)
    summary = TrainSummary(**{k: math.nan if v is None else v for k, v in data.items() if k in known})
    for f in fields(summary):
        if not _SUMMARY_TYPES.get(str(f.type), _any)(value := getattr(summary, f.name)):
            raise InputError(
                f"field {f.name!r}: expected {_SUMMARY_WORDS.get(str(f.type), f.type)}, found {value!r:.40} "
                f"({again})",
                path=path,
            )
    return summary


def stored_summary(out: Path, iteration: int) -> TrainSummary | None:
    """``out``'s ``summary.json`` when it reads back whole (:func:`read_summary`) and reports ``iteration``
    (else None: a resume writes it again)."""
    try:
        return _at(read_summary(out), iteration)
    except InputError:
        return None


def _any(value: object) -> bool:
    return True


#: the check of each annotated type of :class:`TrainSummary` read back (NaN and inf are floats it shows; a
#: type not listed here is not checked)
_SUMMARY_TYPES: dict[str, Callable[[object], bool]] = {
    "int": is_integer,
    "float": lambda v: isinstance(v, float) or is_finite(v),
    "str": lambda v: isinstance(v, str),
}
_SUMMARY_WORDS = {"int": "an integer", "float": "a number", "str": "text"}


def load_run(
    run_dir: str | Path,
    dataset_root: str | Path | None = None,
    device: str = "cpu",
    train_images: bool = True,
) -> tuple[RadianceModel, TrainConfig, SpikeDataset]:
    """The trained model (eval mode, on ``device``), its config and its dataset.

    Args:
        run_dir: a run folder written by ``spikenerf train``.
        dataset_root: the dataset folder if it moved since training (default: the path in ``config.yaml``).
        device: auto | cpu | cuda.
        train_images: decode the dataset's GT renders and blur frames (:func:`load_dataset`; False: no
            ``dataset.gt`` views, no ``dataset.blur``).
    Returns:
        (model, config, dataset). Problems (missing files, foreign checkpoint) raise InputError.
    """
    return open_run(run_dir, dataset_root, device, train_images)[:3]  # type: ignore[return-value]


def open_run(
    run_dir: str | Path,
    dataset_root: str | Path | None = None,
    device: str = "cpu",
    train_images: bool = True,
) -> tuple[RadianceModel, TrainConfig, SpikeDataset, dict]:
    """:func:`load_run` and the checkpoint it read (its ``poses`` hold the run's pose refinement), for
    callers that need both without reading the checkpoint twice."""
    run_dir = as_path(run_dir, "run_dir")
    config = load_run_config(run_dir / CONFIG_FILE)
    ckpt = load_checkpoint(run_dir / CHECKPOINT)
    check_same_run(ckpt, config.to_dict(), run_dir / CHECKPOINT)
    model = model_of(ckpt, run_dir / CHECKPOINT)
    model.to(resolve_device(device)).eval()
    if dataset_root is None and not config.dataset:
        raise InputError(
            "has no 'dataset' entry (or an empty one): give the run's data folder with dataset_root",
            path=run_dir / CONFIG_FILE,
            param="dataset_root",
        )
    if dataset_root is None and not Path(config.dataset).exists():  # moved or deleted since training
        raise InputError(
            f"the run's data folder {config.dataset} is not there any more: if it moved, give its new "
            "folder with dataset_root",
            path=run_dir / CONFIG_FILE,
            param="dataset_root",
        )
    dataset = load_dataset(dataset_root if dataset_root is not None else config.dataset, train_images)
    check_dataset_fits(ckpt, dataset, "dataset_root" if dataset_root is not None else "the run's dataset")
    return model, config, dataset, ckpt


def dataset_fingerprint(dataset: SpikeDataset) -> dict:
    """What a run remembers of its dataset (stored in the checkpoint): image size, steps, rate, scene box."""
    k = dataset.intrinsics
    box = [[round(float(v), 6) for v in row] for row in dataset.scene_box]
    return {
        "size": [k.width, k.height],
        "steps": len(dataset.trajectory),
        "fps": float(dataset.trajectory.fps),
        "box": box,
        "content": content_digest(dataset),
    }


def content_digest(dataset: SpikeDataset, edge: int = 1 << 16) -> str:
    """A digest of what a dataset holds, cheap for any size: its ``transforms.json``, its config (without
    the recorded command line), and each spike file's size with its first and last ``edge`` bytes. A
    dataset simulated or imported again with other settings (or another seed) differs; the same folder
    moved does not."""
    import hashlib
    import json

    digest = hashlib.sha256()
    path = dataset.root / "transforms.json"
    digest.update(path.read_bytes() if path.is_file() else b"")
    config = {k: v for k, v in dataset.config.items() if k != "command"}  # the command names --out
    digest.update(json.dumps(config, sort_keys=True, default=str).encode())
    for mode in dataset.modes:
        for name in spike_files(mode):
            if not (dataset.root / name).is_file():
                continue
            with open(dataset.root / name, "rb") as fh:
                size = fh.seek(0, 2)
                fh.seek(0)
                head = fh.read(edge)
                fh.seek(max(0, size - edge))
                digest.update(f"{name}:{size}".encode() + head + fh.read(edge))
    return digest.hexdigest()[:16]


def check_dataset_fits(ckpt: dict, dataset: SpikeDataset, param: str) -> None:
    """InputError (naming ``param``) when ``dataset`` is not the one the checkpoint was trained on (its
    fingerprint; checkpoints without one are compared by scene box)."""
    if diff := dataset_differences(ckpt, dataset):
        raise InputError(
            f"{param}: this dataset does not fit the run: {'; '.join(diff)}", path=dataset.root, param=param
        )


def dataset_differences(ckpt: dict, dataset: SpikeDataset) -> list[str]:
    """How ``dataset`` differs from the one the checkpoint was trained on (its fingerprint; checkpoints
    without one are compared by scene box), one phrase each; empty where it fits."""
    want = ckpt.get("dataset")
    have = dataset_fingerprint(dataset)
    if want is None:
        want, have = {"box": ckpt["hparams"]["scene_box"]}, {"box": have["box"]}
    diff = []
    for key, value in want.items():
        if key == "box":
            fits = torch.allclose(torch.tensor(value).double(), torch.tensor(have[key]).double(), atol=1e-4)
        else:
            fits = have.get(key) == value
        if key == "content" and not fits:
            diff.append(
                "its files differ from those the run trained on (another dataset, or this one simulated or "
                "imported again?)"
            )
        elif not fits:
            diff.append(f"{key} {have.get(key)} (run: {value})")
    return diff


def check_resume_fits(ckpt: dict, config: TrainConfig, dataset: SpikeDataset) -> None:
    """InputError unless a resume continues the checkpoint's run: on the dataset it was trained on (its
    fingerprint, files included) and to at least the iterations it has done."""
    check_dataset_fits(ckpt, dataset, "dataset")
    done = int(ckpt["iteration"])
    if config.iters < done:
        raise InputError(
            f"iters {config.iters} is below the {done} iterations this run has done; give at least {done}",
            param="iters",
        )


def run_iteration(run_dir: str | Path) -> int:
    """Completed iterations stored in a run folder's checkpoint."""
    return int(load_checkpoint(Path(run_dir) / CHECKPOINT, map_location=torch.device("cpu"))["iteration"])


def describe_run(run_dir: str | Path, metrics: MetricsLines | None = None) -> str:
    """A few lines about a run folder: method and its key settings, field, progress (with a warning line
    where the run's dataset is not the one its checkpoint was trained on), the last curve point and, with
    ``metrics`` (``spikenerf.eval.describe.metrics_lines``; eval sits above this layer), the scores of each
    metrics file eval wrote."""
    from spikenerf.train.evaluate import CURVES, read_curves

    run_dir = Path(run_dir)
    config = load_run_config(run_dir / CONFIG_FILE)
    done, unfit = 0, None
    if (run_dir / CHECKPOINT).exists():  # another run's checkpoint copied in is refused, as eval does
        ckpt = load_checkpoint(run_dir / CHECKPOINT, map_location=torch.device("cpu"))
        check_same_run(ckpt, config.to_dict(), run_dir / CHECKPOINT)
        model_of(ckpt, run_dir / CHECKPOINT)  # a tensor eval refuses (another shape, dtype) is named here
        done, unfit = int(ckpt["iteration"]), _dataset_unfit(ckpt, config)
    method = make_method(config)
    lines = [
        f"run: {run_dir}",
        f"method: {method.describe()}",
        *([f"settings: {'; '.join(found)}"] if (found := method.settings()) else []),
        f"color: {config.color}   field: {config.field}   seed: {config.seed}   batch: "
        f"{config.rays_per_step()} rays   dataset: {config.dataset}",
        f"iterations: {done} of {config.iters}"
        + ("" if done >= config.iters else "  (resume with --resume)"),
    ]
    if unfit:
        lines.append(
            f"warning: the dataset is not the one this run trained on: {unfit}; eval, render and a resume "
            "refuse it"
        )
    if config.method == "spike-integral" and (poses := config.window_poses()) > 1 and _tfp_keyframes(config):
        lines.append(  # it trains on spike counts; only eval's keyframe scores read window_poses
            f"eval's TFP keyframes (the imported dataset's test views): each against the mean of {poses} "
            "renders across its window"
        )
    if (run_dir / SENSOR_MAP).is_file():  # integral.pixel_gain's learned map
        lines.append(_sensor_line(run_dir / SENSOR_MAP))
    if (held := read_record(run_dir)) is not None:
        lines.append(held_line(held, _imported(config)))
    stored = read_summary(run_dir)  # (a garbled one is an InputError naming it, as a garbled curves.csv)
    if curves := read_curves(run_dir / CURVES):  # (a garbled one is an InputError naming it)
        last = curves[-1]
        train_psnr, test = last["train_psnr"], _db(last["test_psnr"])  # curves.csv rounds to 4 decimals
        if (summary := _at(stored, int(last["iteration"]))) is not None:  # as train printed
            train_psnr, test = summary.train_psnr, summary.test_text()
        lines.append(
            f"last evaluation: iteration {int(last['iteration'])}, {last['seconds']:.0f} s of training, "
            f"train PSNR {_db(train_psnr)} (against its training targets), test PSNR {test}"
        )
    elif done and (summary := _at(stored, done)) is not None:  # curves.csv removed
        lines.append(
            f"last evaluation: iteration {done}, {summary.seconds:.0f} s of training, train PSNR "
            f"{_db(summary.train_psnr)} (against its training targets), test PSNR "
            f"{summary.test_text()} (from summary.json)"
        )
    for name in ("metrics.json", "metrics_train.json"):  # eval's held-out scores, and --split train's
        if metrics is not None and (path := run_dir / name).exists():
            lines += metrics(path, done)
    return "\n".join(lines)


def _at(summary: TrainSummary | None, iteration: int) -> TrainSummary | None:
    """``summary`` where it reports ``iteration`` (a summary of an earlier finish is not this state's)."""
    return summary if summary is not None and summary.iteration == iteration else None


def _sensor_line(path: Path) -> str:
    """``sensor map: RUN/sensor_map.npy, 64×64 …``: the learned per-pixel response factors' spread."""
    try:
        factors = read_sensor_map(path)
    except (OSError, ValueError) as err:
        return f"sensor map: {path} is unreadable ({err})"
    shape = "×".join(map(str, factors.shape))
    logs = np.log(np.clip(factors, 1e-12, None))
    return (
        f"sensor map: {path} ({shape} learned per-pixel response factors, std {logs.std():.1%} in log, "
        f"{factors.min():.3f} to {factors.max():.3f}; eval's renders do not use it)"
    )


def _dataset_unfit(ckpt: dict, config: TrainConfig) -> str | None:
    """Why the dataset the run's ``config.yaml`` names is not the one ``ckpt`` was trained on (another
    dataset, or this one simulated again: :func:`check_dataset_fits`, as eval and a resume check it); None
    where it fits, or is gone or unreadable (``info`` still describes the run; eval names the problem)."""
    if not config.dataset:
        return None
    try:
        return "; ".join(dataset_differences(ckpt, load_dataset(config.dataset, train_images=False))) or None
    except (InputError, OSError):  # gone or unreadable: eval names it
        return None


def _imported(config: TrainConfig) -> dict:
    """The run's dataset's ``imported`` record (its ``config.yaml``, written by ``import``); empty for a
    simulated dataset, or where the dataset is gone or unreadable (``info`` still describes the run)."""
    try:
        imported = read_mapping(Path(config.dataset) / DATASET_CONFIG, "YAML").get("imported")
    except InputError:
        return {}
    return imported if isinstance(imported, dict) else {}


def _tfp_keyframes(config: TrainConfig) -> bool:
    """Whether the run's dataset has TFP keyframes as test views (an ``import`` that recorded
    ``imported.test_keyframes``), which eval scores against a mean of renders across each window."""
    imported = _imported(config)
    return bool(imported.get("test_keyframes")) and imported.get("keyframe_images", "tfp") == "tfp"


def held_line(held: dict, imported: dict) -> str:
    """``info``'s line of a run's hold-out record: its steps (the dataset's; also the recording's where an
    ``import --range`` started past step 0, as ``info`` of the dataset numbers them), band and cost."""
    steps = held.get("step_numbers", held["check_steps"])
    first = (imported.get("range") or [0])[0]
    shown = "steps " + ", ".join(map(str, steps))
    if isinstance(first, int) and not isinstance(first, bool) and first > 0:
        shown = f"recording steps {', '.join(str(first + s) for s in steps)} (dataset {shown})"
    excluded = held.get("excluded_steps")
    return f"held out: {shown} ± {held.get('radius')} ({excluded} steps not trained on)"
