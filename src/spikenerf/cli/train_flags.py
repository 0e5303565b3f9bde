"""``spikenerf train``'s flags turned into a :class:`~spikenerf.train.config.TrainConfig`: the config it
starts from (``--config``, a resumed run's, the defaults), the options given on the command line, ``--set``,
and the dataset folder."""

from __future__ import annotations

import contextlib
from collections.abc import Collection, Iterator, Mapping, Sequence
from pathlib import Path

import click

from spikenerf.core.errors import InputError
from spikenerf.core.yamlio import load_yaml
from spikenerf.train.config import TrainConfig
from spikenerf.train.config_file import CONFIG_FILE, apply_overrides, load_config, load_run_config

#: CLI option → (section of TrainConfig or None for the top level, field name)
OPTION_FIELDS: dict[str, tuple[str | None, str]] = {
    "method": (None, "method"),
    "color": (None, "color"),
    "field": (None, "field"),
    "iters": (None, "iters"),
    "batch": (None, "batch"),
    "lr": (None, "lr"),
    "seed": (None, "seed"),
    "device": (None, "device"),
    "eval_every": (None, "eval_every"),
    "eval_views": (None, "eval_views"),
    "ckpt_every": (None, "ckpt_every"),
    "log": (None, "log"),
    "log_every": (None, "log_every"),
    "amp": (None, "amp"),
    "compile": (None, "compile"),
    "compile_optimizer": (None, "compile_optimizer"),
    "recon": ("targets", "recon"),
    "window": ("targets", "window"),
    "blur_samples": ("targets", "blur_samples"),
    "window_poses": ("targets", "window_poses"),
    "integral_window": ("integral", "lengths"),
    "integral_samples": ("integral", "samples"),
    "integral_track": ("integral", "track"),
    "lam": ("spike", "lam"),
    "spike_loss": ("spike", "kind"),
    "spike_window": ("spike", "window"),
    "spike_pixels": ("spike", "pixels"),
    "spike_warmup": ("spike", "warmup_iters"),
    "refine_poses": ("poses", "refine"),
    "holdout": (None, "holdout"),
    "holdout_steps": (None, "holdout_steps"),
    "holdout_radius": (None, "holdout_radius"),
}


def given_flags(ctx: click.Context) -> set[str]:
    """The options of ``OPTION_FIELDS`` (and ``--no-mask``, ``--no-spike-loss``, ``--field-option``) given
    on the command line, not left at their defaults."""
    return {
        name
        for name in [*OPTION_FIELDS, "no_mask", "no_spike_loss", "field_options"]
        if ctx.get_parameter_source(name) == click.core.ParameterSource.COMMANDLINE
    }


def start_config(config_file: Path | None, resume: bool, stored: Path) -> tuple[TrainConfig, Path | None]:
    """The config the options apply to, and the file ``--config`` read it from (a run folder given: its
    config.yaml): ``--config``'s file ``config_file``, else the stored config ``stored`` of a run that
    ``resume`` continues, else the defaults (the click defaults are TrainConfig's)."""
    if config_file is not None:  # the file, then the options given on the command line, then --set
        if config_file.is_dir() and (config_file / CONFIG_FILE).is_file():  # a run folder: its config
            config_file = config_file / CONFIG_FILE
        if not config_file.is_file():
            found = "is a folder without a config.yaml" if config_file.is_dir() else "file not found"
            raise InputError(f"--config: {found}", path=config_file)
        return load_config(config_file), config_file
    if resume and stored.is_file():  # resuming: keep the stored config, apply only given options
        return load_run_config(stored), None
    return TrainConfig(), None


def apply_flags(base: TrainConfig, given: set[str], options: Mapping[str, object]) -> None:
    """Set in ``base`` each option of ``given`` to its value in ``options``; a ``--field-option`` key or
    value the field does not take is an InputError naming the flag."""
    for name, (section, key) in OPTION_FIELDS.items():
        if name in given:
            setattr(getattr(base, section) if section else base, key, options[name])
    if "no_mask" in given:
        base.targets.mask = not options["no_mask"]
    if "no_spike_loss" in given:
        base.spike.enabled = not options["no_spike_loss"]
    if "field_options" in given:
        base.field_config = {**base.field_config, **_field_options(options["field_options"])}  # type: ignore[arg-type]
        with _naming("--field-option"):
            from spikenerf.fields.registry import field_config

            field_config(base.field, base.field_config)  # a key or value the field does not take


def apply_set(base: TrainConfig, overrides: tuple[str, ...], keys: Sequence[str]) -> TrainConfig:
    """``base`` with ``--set KEY=VALUE`` ``overrides`` (whose ``keys`` are given in that order) applied; an
    error that names no parameter names ``--set`` and the key."""
    with _naming("--set", keys):
        return TrainConfig.from_dict(apply_overrides(base.to_dict(), overrides))


def dataset_folder(
    dataset: Path | None,
    base: TrainConfig,
    out: Path,
    *,
    resume: bool,
    config_file: Path | None,
    set_keys: Collection[str],
) -> Path:
    """The dataset folder: ``dataset`` (the DATASET argument) or the config's (``--config``'s file, the run
    that ``resume`` continues, ``--set dataset``: ``set_keys`` are the keys ``--set`` gave), which must be a
    folder; where it is not, one line that says what is there instead and where the path came from."""
    if dataset is None and not base.dataset:
        raise InputError("give the DATASET folder (or a --config whose 'dataset' names one)")
    if dataset is not None and "dataset" in set_keys:  # both: which one is meant?
        raise InputError("give the dataset once: as DATASET or as --set dataset=PATH, not both")
    from_run = dataset is None and resume and config_file is None and "dataset" not in set_keys
    from_file = dataset is None and config_file is not None and "dataset" not in set_keys
    dataset = Path(base.dataset) if dataset is None else dataset
    if not dataset.is_dir():
        found = "is a file, not a dataset folder" if dataset.exists() else "dataset folder not found"
        from spikenerf.data.dataset import recording_in  # (not at import: `train --help` stays light)

        found = recording_in(dataset) or found
        if from_run and not dataset.exists():  # the run's own record: the dataset moved since
            found += f" (the run trained on it; if it moved: spikenerf train NEW_PATH --resume --out {out})"
        elif from_file and not dataset.exists():  # (a relative path: from the working directory)
            found += f" (the 'dataset' of {config_file}, from the folder the command runs in)"
        raise InputError(found, path=dataset)
    return dataset


def window_lengths(text: str | None) -> list[int] | None:
    """``--integral-window 11`` or ``5,11,21`` → [11] or [5, 11, 21] (one line naming the flag otherwise);
    None (not given) stays None, the dataset's default."""
    if text is None:
        return None
    try:
        values = [int(part) for part in text.split(",")]
    except ValueError:
        raise click.BadParameter(f"expected window lengths such as 11 or 5,11,21, found {text!r}") from None
    if not values or min(values) < 1:
        raise click.BadParameter(f"window lengths must be ≥ 1, found {text!r}")
    return values


@contextlib.contextmanager
def _naming(flag: str, keys: Sequence[str] = ()) -> Iterator[None]:
    """An InputError that names no parameter (an unknown key, a section given a value) gets ``flag``: before
    the key of ``keys`` that the message starts with (``--set spike.lam must be …``), else with the keys
    before the message (``--set spike: unknown spike keys …``)."""
    try:
        yield
    except InputError as err:
        if err.params:
            raise
        if any(err.message.startswith(f"{key} ") for key in keys):
            message = f"{flag} {err.message}"
        else:
            message = " ".join([flag, ", ".join(keys)]).strip() + f": {err.message}"
        raise InputError(message, path=err.path) from err


def _field_options(items: tuple[str, ...]) -> dict[str, object]:
    """``("KEY=VALUE", ...)`` → ``{KEY: yaml(VALUE)}``; a malformed item is an InputError."""
    import yaml

    out: dict[str, object] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise InputError(f"--field-option expects KEY=VALUE, found {item!r}")
        try:
            out[key.strip()] = load_yaml(value)
        except yaml.YAMLError as err:
            raise InputError(f"--field-option {key}: unreadable value {value!r} ({err})") from err
    return out
