"""A run's ``config.yaml``: ``--set KEY=VALUE`` overrides, writing it, and reading it back (a ``--config``
file or a run folder's), every refusal naming the file; the typed fields are :mod:`spikenerf.train.config`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from spikenerf.core.atomic import write_text_atomic
from spikenerf.core.errors import InputError
from spikenerf.core.marker import folder_kind, owned
from spikenerf.core.yamlio import load_yaml
from spikenerf.train.config import TrainConfig


def apply_overrides(data: dict[str, Any], items: tuple[str, ...] | list[str]) -> dict[str, Any]:
    """Apply ``KEY.SUB=VALUE`` overrides (values parsed as YAML) to a :meth:`TrainConfig.to_dict` mapping.

    ``KEY`` is any TrainConfig field, ``targets.X``/``spike.X`` their fields, ``field_config.X`` an entry of
    the field's config. Unknown keys are reported when the mapping is turned back into a config.
    """
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key or any(not part for part in key.split(".")):
            raise InputError(f"override expects KEY=VALUE (e.g. spike.lam=0.5), found {item!r}")
        try:
            value = load_yaml(text)
        except yaml.YAMLError as err:
            raise InputError(f"override {key}: unreadable value {text!r:.60} ({err})") from err
        *sections, leaf = key.split(".")
        node = data
        for i, section in enumerate(sections):
            if not isinstance(node.get(section), dict):
                where = ".".join(sections[: i + 1])
                raise InputError(
                    f"override {key}: {where!r} is not a section "
                    "(targets, spike, integral, poses, exposure, field_config)"
                )
            node = node[section]
        node[leaf] = value
    return data


def save_config(config: TrainConfig, path: str | Path) -> None:
    """Write ``config.yaml`` atomically."""
    write_text_atomic(path, yaml.safe_dump(config.to_dict(), sort_keys=False))


#: the largest config file read (a config is a few kB; a larger file is surely not one)
MAX_CONFIG_BYTES = 1 << 20


def _read_config(path: str | Path) -> tuple[Path, Any]:
    """The parsed YAML of a config file (InputError when missing or malformed)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("missing run config (not a run folder written by `spikenerf train`?)", path=path)
    if path.stat().st_size > MAX_CONFIG_BYTES:
        raise InputError(f"is {path.stat().st_size} bytes, too large for a YAML config", path=path)
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = "\0"
    if "\0" in text:
        raise InputError("is a binary file, not a YAML config", path=path)
    try:
        data = load_yaml(text)
    except yaml.YAMLError as err:
        raise InputError(f"malformed YAML ({err})", path=path) from err
    if data is None:
        raise InputError("is empty: expected a YAML mapping of TrainConfig fields", path=path)
    return path, data


def _refuse_other_folder(path: str | Path) -> None:
    """InputError when ``path`` is the ``config.yaml`` of a folder spikenerf wrote as other than a run (a
    dataset's is its camera's, whose keys a train config does not know): a folder marked so, or an older
    dataset (its files); a user's folder that merely holds a ``manifest.json`` is not one."""
    folder = Path(path).parent
    kind = folder_kind(folder)
    kind = kind if owned(folder) or kind == "dataset" else None
    if Path(path).name == CONFIG_FILE and kind not in (None, "run"):
        hint = " (train a run on it first: spikenerf train DATASET --out RUN)" if kind == "dataset" else ""
        raise InputError(f"is a {kind} folder, not a run folder{hint}", path=folder)


def load_config(path: str | Path) -> TrainConfig:
    """Read ``config.yaml`` written by :func:`save_config` (or a ``--config`` file); the camera config of a
    dataset (or another output's) is refused as such. A folder is read as its ``config.yaml``."""
    if Path(path).is_dir():
        path = Path(path) / CONFIG_FILE
    _refuse_other_folder(path)
    path, data = _read_config(path)
    return _checked_fields(_validated(TrainConfig.from_dict(data, path), path), path)


def _checked_fields(config: TrainConfig, path: Path) -> TrainConfig:
    """``config`` after its ``field_config`` is checked against its field, a refusal naming the file ``path``
    (else only the model build finds a bad key, named as a flag the user did not give)."""
    from spikenerf.fields.registry import field_config  # (imports torch: not at this module's import)

    try:
        typed = field_config(config.field, config.field_config)
        getattr(typed, "check", lambda: None)()
    except InputError as err:
        raise InputError(err.message, path=path, param=err.params) from err
    return config


def _validated(config: TrainConfig, path: Path) -> TrainConfig:
    """``config.validate()``, its refusals naming the file ``path`` the values came from (and its fields,
    not the command's flags)."""
    try:
        return config.validate()
    except InputError as err:
        if err.path is not None:
            raise
        raise InputError(err.message, path=path) from err


#: a run folder's config file (:func:`save_config` writes it, :func:`load_run_config` reads it)
CONFIG_FILE = "config.yaml"


def load_run_config(path: str | Path) -> TrainConfig:
    """A run folder's ``config.yaml`` as that run trained: :func:`load_config`, but a run written before
    ``targets.window_poses`` existed (its targets section lacks the key) trained with one pose per target,
    not today's default. (A run written since records the resolved count: :meth:`TrainConfig.resolved`.)
    A dataset folder's config (its camera's) is refused as such."""
    _refuse_other_folder(path)
    path, data = _read_config(path)
    config = _checked_fields(_validated(TrainConfig.from_dict(data, path), path), path)
    if isinstance(data.get("targets"), dict) and "window_poses" not in data["targets"]:
        config.targets.window_poses = 1
    return config
