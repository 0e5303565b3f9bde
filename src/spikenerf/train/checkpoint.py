"""Atomic, resumable checkpoints holding only tensors and primitive containers (``weights_only=True`` loads).

``RUN/checkpoint.pt`` = {"format", "iteration", "elapsed", "model" (state dict), "hparams" (to rebuild the
model), "optimizer" (state dict), "rng" (torch CPU/CUDA states and the samplers'), "config" (TrainConfig as a
dict)}. It is written to a temporary sibling and moved into place with ``os.replace``. ``torch.save`` writes
a zip whose every record carries a CRC-32; ``torch.load`` does not check them, :func:`load_checkpoint` does
(:func:`check_crc`), so bytes changed on disk since the write are refused rather than used.
"""

from __future__ import annotations

import errno
import json
import pickle
import warnings
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

from spikenerf.core.atomic import atomic_path
from spikenerf.core.errors import InputError, is_finite

CHECKPOINT = "checkpoint.pt"
FORMAT = "spikenerf-checkpoint-1"


def rng_state(samplers: dict[str, Any]) -> dict[str, Any]:
    """Every random stream the trainer draws from: torch's global CPU (and CUDA) state and each sampler's."""
    state: dict[str, Any] = {"torch": torch.get_rng_state()}
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    state.update({name: s.state_dict() for name, s in samplers.items()})
    return state


def restore_rng(state: dict[str, Any], samplers: dict[str, Any]) -> None:
    """Inverse of :func:`rng_state`. CUDA states are restored for the GPUs visible now (a run resumed
    with fewer, e.g. under another ``CUDA_VISIBLE_DEVICES``, restores those it has)."""
    torch.set_rng_state(state["torch"])
    if "cuda" in state and torch.cuda.is_available():
        for index, cuda in enumerate(state["cuda"][: torch.cuda.device_count()]):
            torch.cuda.set_rng_state(cuda, index)
    for name, sampler in samplers.items():
        sampler.load_state_dict(state[name])


def save_checkpoint(path: str | Path, payload: dict[str, Any]) -> None:
    """Write ``payload`` (tensors, numbers, strings, lists, tuples, dicts) atomically."""
    serialization = torch.serialization
    crc = getattr(serialization, "get_crc32_options", lambda: True)()
    set_crc = getattr(serialization, "set_crc32_options", lambda _on: None)  # torch < 2.4: always on
    with atomic_path(path) as tmp:
        try:
            set_crc(True)  # load_checkpoint checks them (torch's default: on)
            torch.save({"format": FORMAT, **payload}, tmp)
        except RuntimeError as err:  # torch's writer turns a failed write (a full disk) into RuntimeError
            first = str(err).strip().split("\n")[0]
            raise OSError(
                errno.EIO, f"could not write the checkpoint ({first}; disk full?)", str(path)
            ) from err
        finally:
            set_crc(crc)


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Read a checkpoint with ``weights_only=True``; a missing or foreign file is an InputError."""
    path = Path(path)
    if not path.is_file():
        raise InputError("missing checkpoint (not a run folder written by `spikenerf train`?)", path=path)
    check_crc(path)  # first: a changed byte is named as such, not as a foreign or malicious pickle
    try:
        with warnings.catch_warnings():  # torch warns (several lines) about foreign pickle protocols
            warnings.simplefilter("ignore")
            data = torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as err:
        raise InputError(
            "refused: it holds Python objects that a weights-only load does not run (not a spikenerf "
            "checkpoint, or a malicious one)",
            path=path,
        ) from err
    except Exception as err:  # torch raises many types for truncated or foreign files
        first = str(err).strip().split(". ")[0]
        raise InputError(f"unreadable checkpoint ({type(err).__name__}: {first})", path=path) from err
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise InputError(f"not a spikenerf checkpoint (expected format {FORMAT!r})", path=path)
    check_schema(data, path)
    return data


def check_crc(path: Path) -> None:
    """InputError naming ``path`` when a record of the checkpoint's zip fails its CRC-32: its bytes changed
    on disk after ``torch.save`` wrote it (a bit flip, a bad copy, an edit). Files without CRCs pass: not a
    zip (torch's legacy format, or no checkpoint at all: ``torch.load`` tells), or saved with torch's CRCs
    switched off (every record's CRC 0)."""
    try:
        archive = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError, EOFError, ValueError):
        return  # not a zip, or its directory is cut: torch.load's own error names the file
    with archive:
        if all(r.CRC == 0 for r in archive.infolist() if r.file_size):
            return
        try:
            bad = archive.testzip()
        except Exception as err:  # a changed directory entry: a bad size, method or flag (zlib, EOF, …)
            raise InputError(
                f"damaged checkpoint: its records cannot be read ({type(err).__name__}: {err})", path=path
            ) from err
    if bad is not None:
        raise InputError(
            f"damaged checkpoint: its record {bad!r} fails its CRC-32 check (its bytes changed on disk "
            "after it was written)",
            path=path,
        )


#: the entries every checkpoint holds and their types, checked before any is used
SCHEMA: dict[str, type | tuple[type, ...]] = {
    "iteration": int, "elapsed": (int, float), "model": dict, "hparams": dict, "optimizer": dict,
    "rng": dict, "config": dict,
}  # fmt: skip


def check_schema(data: dict[str, Any], path: str | Path) -> None:
    """InputError naming ``path`` when a checkpoint with the right format tag misses an entry or holds one
    of the wrong type (a damaged or hand-made file): model tensors by name, Adam's state and param groups,
    the CPU random state."""

    def bad(what: str) -> InputError:
        return InputError(f"damaged checkpoint: {what}", path=path)

    for key, kind in SCHEMA.items():
        if key not in data:
            raise bad(f"missing entry {key!r}")
        if not isinstance(data[key], kind) or isinstance(data[key], bool):
            raise bad(f"entry {key!r} is a {type(data[key]).__name__}")
    if data["iteration"] < 0:
        raise bad(f"iteration {data['iteration']} is negative")
    if not (is_finite(data["elapsed"]) and data["elapsed"] >= 0):
        raise bad(f"elapsed time {data['elapsed']} is not a finite number of seconds >= 0")
    if not all(isinstance(k, str) and torch.is_tensor(v) for k, v in data["model"].items()):
        raise bad("entry 'model' must map names to tensors")
    for name, tensor in data["model"].items():
        if problem := _tensor_problem(tensor):
            raise bad(f"model tensor {name!r} {problem}")
    optimizer = data["optimizer"]
    if not isinstance(optimizer.get("state"), dict) or not isinstance(optimizer.get("param_groups"), list):
        raise bad("entry 'optimizer' lacks its 'state' and 'param_groups'")
    if problem := _optimizer_problem(optimizer):
        raise bad(f"entry 'optimizer': {problem}")
    if not (torch.is_tensor(data["rng"].get("torch")) and data["rng"]["torch"].dtype == torch.uint8):
        raise bad("entry 'rng' lacks the torch random state")
    if "rays" in data and (
        not isinstance(data["rays"], int) or isinstance(data["rays"], bool) or data["rays"] < 0
    ):
        raise bad(f"entry 'rays' is {data['rays']!r}, not a count of rays")
    if (poses := data.get("poses")) is not None:  # the pose refinement's state (--refine-poses)
        ok = isinstance(poses, dict) and isinstance(poses.get("refiner"), dict)
        ok = ok and all(isinstance(k, str) and torch.is_tensor(v) for k, v in poses["refiner"].items())
        problem = (
            _tensor_problem(*poses["refiner"].values()) or _refiner_problem(poses["refiner"]) if ok else None
        )
        if not ok or problem:
            raise bad(f"entry 'poses' is not a pose refinement's state ({problem if ok else 'its layout'})")
    if data.get("dataset") is not None and not _is_fingerprint(data["dataset"]):  # (older ones: none)
        raise bad("entry 'dataset' is not a dataset fingerprint (plain values, a 2×3 finite box)")


def _tensor_problem(*tensors: torch.Tensor) -> str | None:
    """What is wrong with stored tensors (a phrase), or None: complex values (no spikenerf tensor holds
    them), or NaN/inf in a floating one (a run that diverged keeps its last finite checkpoint instead)."""
    for tensor in tensors:
        if tensor.is_complex():
            return f"holds complex values ({tensor.dtype})"
        if tensor.is_floating_point() and tensor.numel() and not bool(torch.isfinite(tensor).all()):
            return "holds NaN or inf values"
    return None


def _refiner_problem(state: dict[str, torch.Tensor]) -> str | None:
    """What is wrong with a pose refiner's stored tensors (a phrase), or None: the corrections ``xi`` (K, 6)
    floating and the keyframe marks ``_extra_state`` (K,) bool (absent from older checkpoints)."""
    if unknown := sorted(set(state) - {"xi", "_extra_state"}):
        return f"unknown entries {unknown}"
    xi, marks = state.get("xi"), state.get("_extra_state")
    if xi is None or not (xi.is_floating_point() and xi.dim() == 2 and xi.shape[1] == 6):
        return "its corrections 'xi' are not (K, 6) floats" if xi is not None else "no corrections 'xi'"
    if marks is not None and not (marks.dtype == torch.bool and tuple(marks.shape) == (len(xi),)):
        return f"its keyframe marks are a {tuple(marks.shape)} {marks.dtype} tensor, not ({len(xi)},) bool"
    return None


def _optimizer_problem(optimizer: dict[str, Any]) -> str | None:
    """What is wrong with a stored Adam state dict's layout or values (a phrase), or None. The shapes are
    checked against the model's parameters where they are known (:func:`check_optimizer_fits`)."""
    for index, state in optimizer["state"].items():
        if not isinstance(state, dict):
            return f"the state of parameter {index!r} is a {type(state).__name__}"
        for key, value in state.items():
            if key == "step":
                if not (is_finite(value) or (torch.is_tensor(value) and value.numel() == 1)):
                    return f"the step of parameter {index!r} is {type(value).__name__}, not a number"
            elif not torch.is_tensor(value):
                return f"{key} of parameter {index!r} is a {type(value).__name__}, not a tensor"
            if torch.is_tensor(value) and (problem := _tensor_problem(value)):
                return f"{key} of parameter {index!r} {problem}"
    for group in optimizer["param_groups"]:
        if not isinstance(group, dict) or not isinstance(group.get("params"), list):
            return "a parameter group without its list of parameters"
        if not all(isinstance(i, int) and not isinstance(i, bool) for i in group["params"]):
            return "a parameter group lists parameters other than by index"
        if not (
            is_finite(group.get("lr")) or (torch.is_tensor(group.get("lr")) and group["lr"].numel() == 1)
        ):
            return f"a parameter group's rate is {group.get('lr')!r}, not a number"
    return None


def check_optimizer_fits(optimizer: torch.optim.Optimizer, stored: dict[str, Any], path: str | Path) -> None:
    """InputError naming ``path`` unless the stored Adam state fits ``optimizer`` (built for the model the
    checkpoint holds): as many groups with as many parameters, and each moment tensor of its parameter's
    shape and dtype. (``load_state_dict`` checks the counts with a traceback and not the shapes:
    a fused step on a moment of another shape reads past its memory and crashes the process.)"""

    def bad(what: str) -> InputError:
        return InputError(f"damaged checkpoint: entry 'optimizer': {what}", path=path)

    groups = stored["param_groups"]
    if len(groups) != len(optimizer.param_groups):
        raise bad(f"{len(groups)} parameter groups where the model has {len(optimizer.param_groups)}")
    for group, saved in zip(optimizer.param_groups, groups, strict=True):
        if len(saved["params"]) != len(group["params"]):
            raise bad(
                f"a group of {len(saved['params'])} parameters where the model's has {len(group['params'])}"
            )
        for param, index in zip(group["params"], saved["params"], strict=True):
            for key, value in stored["state"].get(index, {}).items():
                if key == "step":
                    continue
                if tuple(value.shape) != tuple(param.shape) or value.dtype != param.dtype:
                    raise bad(
                        f"{key} of parameter {index} is {tuple(value.shape)} {value.dtype}, its parameter "
                        f"{tuple(param.shape)} {param.dtype}"
                    )


def _is_fingerprint(found: object) -> bool:
    """``found`` is what ``train.run.dataset_fingerprint`` stores: a dict of plain (JSON) values whose
    ``box``, if any, is 2×3 finite numbers (a tensor or a ragged box would fail the comparison with it)."""
    try:
        json.dumps(found)  # (TypeError for a tensor or another object)
        box = np.asarray(found.get("box", np.zeros((2, 3))), dtype=np.float64)  # type: ignore[union-attr]
    except (TypeError, ValueError, OverflowError, AttributeError, RecursionError):
        return False
    return isinstance(found, dict) and box.shape == (2, 3) and bool(np.isfinite(box).all())


def model_of(ckpt: dict[str, Any], path: str | Path) -> Any:
    """The model a checkpoint stores (rebuilt from its hparams, its tensors loaded); InputError naming
    ``path`` when they do not fit (a wrong shape, an unknown entry)."""
    from spikenerf.render.model import model_from_hparams

    try:
        model = model_from_hparams(ckpt["hparams"])
        own = model.state_dict()
        for name, tensor in ckpt["model"].items():
            if name in own and tensor.dtype != own[name].dtype:  # load_state_dict would cast it silently
                raise InputError(f"model tensor {name!r} is {tensor.dtype}, expected {own[name].dtype}")
        model.load_state_dict(ckpt["model"])
        return model
    except InputError as err:  # (a bad field_config entry of its hparams: named as the key, not the file)
        if err.path is not None:
            raise
        raise InputError(f"damaged checkpoint: {err.message}", path=path) from err
    except Exception as err:  # load_state_dict: RuntimeError; a bad hparams entry: KeyError/TypeError
        lines = [line.strip() for line in str(err).strip().split("\n") if line.strip()]
        if len(lines) > 1 and lines[0].startswith("Error(s) in loading state_dict"):
            lines = lines[1:]  # torch's header; the next line names the missing, unexpected or misshapen key
        first = lines[0] if lines else type(err).__name__
        first = first if len(first) <= 300 else first[:297] + "..."
        raise InputError(f"damaged checkpoint: its model does not load ({first})", path=path) from err


def check_same_run(ckpt: dict[str, Any], config: dict[str, Any], path: str | Path) -> None:
    """InputError when the checkpoint at ``path`` was trained with another method, field, colour or seed
    than the run folder's ``config`` says (another run's checkpoint copied in)."""
    stored = dict(ckpt["config"])
    kind = ckpt.get("hparams", {}).get("kind") if isinstance(ckpt.get("hparams"), dict) else None
    if kind is not None and stored.get("field", kind) == config.get("field"):
        stored["field"] = kind  # the model it holds (a checkpoint rewritten under another config says so)
    diff = [k for k in ("method", "field", "color", "seed") if k in stored and stored[k] != config.get(k)]
    if diff:
        shown = ", ".join(f"{k} {stored[k]!r} (config.yaml: {config.get(k)!r})" for k in diff)
        raise InputError(f"belongs to another run: {shown}", path=path)


def match_state_layout(optimizer: torch.optim.Optimizer) -> None:
    """Give every per-parameter state tensor (Adam's moments) its parameter's memory layout, in place.

    ``load_state_dict`` keeps the strides stored in the checkpoint. A checkpoint written before the grid
    factors were stored channels-last holds the moments in the plain layout, and fused Adam assumes that a
    parameter, its gradient and its state share one layout: without this, such a resume trains wrongly.
    """
    for group in optimizer.param_groups:
        for p in group["params"]:
            state = optimizer.state.get(p, {})
            for key, value in state.items():
                if torch.is_tensor(value) and value.shape == p.shape and value.stride() != p.stride():
                    state[key] = torch.empty_like(p, dtype=value.dtype).copy_(value)
