"""Resuming a run: which options a resumed run may change (:data:`RESUMABLE`, and the field options that
choose kernels, :data:`RESUMABLE_FIELD`), the settings it resumes with (its stored config, with what the call
leaves to defaults filled from it), and the one-line refusal naming every other option that differs.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from spikenerf.camera.reconstruct import WINDOWLESS
from spikenerf.core.errors import InputError
from spikenerf.data.holdout import read_record
from spikenerf.fields.grid_config import KERNEL_OPTIONS
from spikenerf.train.config import TrainConfig
from spikenerf.train.config_file import load_run_config
from spikenerf.train.methods import unused_keys

#: options that may change when a run is resumed (everything else must match the stored config)
RESUMABLE = (
    "iters", "eval_every", "ckpt_every", "device", "eval_views", "log", "log_every", "compile",
    "compile_optimizer",
)  # fmt: skip
#: field options that choose how the same model is computed, not the model: a resume may change them (e.g.
#: a run trained with Triton kernels on a GPU resumed on a CPU)
RESUMABLE_FIELD = KERNEL_OPTIONS


def with_kernels(hparams: dict, field_cfg: Any) -> dict:
    """A checkpoint's model ``hparams`` with the kernel choices (:data:`RESUMABLE_FIELD`) of ``field_cfg``,
    the resumed run's field config (the model itself is the stored one)."""
    chosen = {k: getattr(field_cfg, k) for k in RESUMABLE_FIELD if hasattr(field_cfg, k)}
    if not chosen or not isinstance(hparams.get("config"), dict):
        return hparams
    return {**hparams, "config": {**hparams["config"], **chosen}}


def stored_and_given(path: Path, given: TrainConfig) -> tuple[TrainConfig, TrainConfig]:
    """The run's stored config and ``given``; a run from before the hold-out (its config.yaml has no
    ``holdout`` key) trained on every step, so it resumes without one unless ``given`` asks for it. Window
    poses, masks, rays per step, windows and tracks that ``given`` leaves to their defaults are the run's
    own; a run from before track windows has none. Keys the method does not read (``unused_keys``) are the
    run's own too: a flag ``train`` called ignored does not block the resume."""
    stored = load_run_config(path)
    if stored.dataset:  # a run from before absolute dataset paths: as seen from here, as ``given``'s is
        stored.dataset = str(Path(stored.dataset).resolve())
    if stored.integral.track is None:  # a run from before track windows: none
        stored.integral.track = 0
    if not any(line.startswith("holdout:") for line in path.read_text(encoding="utf-8").splitlines()):
        stored.holdout = False
        if given.holdout is None:
            given = dataclasses.replace(given, holdout=False)
    if given.targets.window_poses is None:  # not asked: the count the run trained with
        targets = dataclasses.replace(given.targets, window_poses=stored.targets.window_poses)
        given = dataclasses.replace(given, targets=targets)
    if given.targets.mask is None:  # not asked: the masks the run trained with (runs before: on)
        given = dataclasses.replace(
            given, targets=dataclasses.replace(given.targets, mask=stored.targets.mask)
        )
    if given.batch is None:  # not asked: the rays per step the run trained with
        given = dataclasses.replace(given, batch=stored.batch)
    if given.integral.lengths is None:  # not asked: the windows the run trained with
        integral = dataclasses.replace(given.integral, lengths=stored.integral.lengths)
        given = dataclasses.replace(given, integral=integral)
    if given.integral.track is None:  # not asked: the run's tracks
        integral = dataclasses.replace(given.integral, track=stored.integral.track)
        given = dataclasses.replace(given, integral=integral)
    if given.method == stored.method:  # what the method does not read (train warned) cannot differ
        data, old = given.to_dict(), stored.to_dict()
        for section in ("targets", "spike", "integral", "exposure"):
            for key in unused_keys(given.method, [f"{section}.{k}" for k in data[section]]):
                data[section][key.partition(".")[2]] = old[section][key.partition(".")[2]]
        given = TrainConfig.from_dict(data)
    return stored, given


def check_resume(
    stored: TrainConfig, given: TrainConfig, path: Path, also: tuple[str, ...] = ()
) -> TrainConfig:
    """The stored config with the resumable options (:data:`RESUMABLE` and ``also``, and the field options
    of :data:`RESUMABLE_FIELD` that ``given`` sets) of ``given``; other differences are an InputError."""
    resumable = (*RESUMABLE, *also)
    a, b = stored.to_dict(), given.to_dict()
    for d in (a, b):  # compared without the implementation choices
        d["field_config"] = {k: v for k, v in d["field_config"].items() if k not in RESUMABLE_FIELD}
    diff = sorted(k for k in a if k not in resumable and a[k] != b[k])
    if diff:
        leaves = [(k, x, y) for k in diff for k, x, y in _leaf_changes(k, a[k], b[k])]
        detail = ", ".join(f"{k}: run has {x!r}, asked {y!r}" for k, x, y in leaves)
        raise InputError(
            f"resume with different options ({detail}); use a new out folder to change them",
            path,
            param=(*(k for k, _, _ in leaves), "resume", "out"),
        )
    chosen = {k: v for k, v in given.field_config.items() if k in RESUMABLE_FIELD}
    field = {**stored.field_config, **chosen}  # the stored choices stay unless given again
    return dataclasses.replace(stored, **{k: getattr(given, k) for k in resumable}, field_config=field)


def began_uncut(run_dir: Path, recon: str) -> bool:
    """Whether a resumed run's ``recon`` (TFI or TFSTP) targets were made from the whole stream: its hold-out
    record does not say they were cut at the bands' edges (written before the cut: no ``recon_cut``; or by
    such a run resumed: false). It goes on with them (cut halfway, the run would have trained on both, and
    its record would claim the cut for all of it)."""
    held = read_record(run_dir) if recon in WINDOWLESS else None
    return held is not None and held.get("recon_cut") is not True


def _leaf_changes(key: str, was: Any, now: Any) -> list[tuple[str, Any, Any]]:
    """The differing entries of a config section, dotted (``targets.recon``), down to its leaves: one
    changed option is named alone, not with its whole section."""
    if isinstance(was, dict) and isinstance(now, dict) and key != "field_config":
        return [
            change
            for k in sorted({*was, *now}, key=str)
            if was.get(k) != now.get(k)
            for change in _leaf_changes(f"{key}.{k}", was.get(k), now.get(k))
        ]
    return [(key, was, now)]
