"""``spikenerf train DATASET --method ... --out RUN``: train a radiance field on a spike dataset."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from pathlib import Path

import click

from spikenerf.camera.reconstruct import WINDOWLESS
from spikenerf.cli.types import COUNT, SEED, OutPath, device_option
from spikenerf.core.errors import InputError
from spikenerf.core.yamlio import load_yaml
from spikenerf.data.choices import COLORS, METHODS
from spikenerf.data.reconstruction import RECONS
from spikenerf.fields.choices import FIELD_KINDS
from spikenerf.train.config import WINDOW_POSES, TrainConfig
from spikenerf.train.config_file import CONFIG_FILE, apply_overrides, load_config, load_run_config
from spikenerf.train.settings import (
    AMP_MODES,
    INTEGRAL_SHORTEST,
    INTEGRAL_SPAN_PX,
    INTEGRAL_WINDOW,
    LOG_KINDS,
    METHOD_SUMMARIES,
    SPIKE_LOSS_KINDS,
    TRACK_HALF,
)

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


_D = TrainConfig()
#: TrainConfig key → its flag: errors raised below the CLI name the key, the CLI shows the flag
#: (``spikenerf.cli.flag_of``)
#: the config keys this command's ``--set`` gave (an error about one names ``--set KEY``, not its flag)
SET_KEYS: set[str] = set()
PARAM_FLAGS = {
    f"{section}.{key}" if section else key: "--" + ("lambda" if name == "lam" else name.replace("_", "-"))
    for name, (section, key) in OPTION_FIELDS.items()
} | {"field_config": "--field-option (grid size)", "holdout": "--holdout (--no-holdout turns it off)"}


@click.command(
    help="Train a radiance field on a spike dataset folder (written by `spikenerf simulate`) into RUN.\n\n"
    "Methods: "
    + ", ".join(f"{name} ({summary})" for name, summary in METHOD_SUMMARIES.items())
    + ". Writes RUN/config.yaml, RUN/checkpoint.pt, RUN/curves.csv and "
    "RUN/summary.json; --resume continues an interrupted run (--iters, --eval-every, --ckpt-every, "
    "--eval-views, --device, --log, --log-every, --compile, --compile-optimizer and the field options "
    "lookup, composite and march may change; other options must match the run's). A "
    "flag or --set key that the method does not use is ignored with a one-line warning (none with "
    "--ignore-unused), also on --resume.\n\n"
    "--config FILE starts from a TrainConfig YAML (a run folder's config.yaml works; DATASET may then be "
    "left out); options given on the command line override it, and --set KEY=VALUE overrides any field "
    "last (e.g. --set spike.lam=0.5 --set targets.mask_n=3 --set field_config.n_voxels_final=2097152)."
)
@click.argument("dataset", required=False, type=click.Path(path_type=Path))
@click.option("--out", "out", required=True, type=OutPath(), help="Run folder to write.")
@click.option("--method", type=click.Choice(METHODS), default=_D.method, show_default=True)
@click.option(
    "--no-mask",
    is_flag=True,
    help="spike-nerf without spike masks: the ablation with the paper's targets, and the default with "
    "window-aware ones (--set targets.mask=true keeps them there).",
)
@click.option("--no-spike-loss", is_flag=True, help="Ablation: spike-nerf without the spike loss.")
@click.option(
    "--lambda", "lam", type=float, default=_D.spike.lam, show_default=True, help="Spike-loss weight λ."
)
@click.option(
    "--spike-loss",
    type=click.Choice(SPIKE_LOSS_KINDS),
    default=_D.spike.kind,
    show_default=True,
    help="interval: differentiable integral constraint; paper: the paper's spike comparison (no gradient).",
)
@click.option("--color", type=click.Choice(COLORS), default=_D.color, show_default=True)
@click.option("--field", type=click.Choice(FIELD_KINDS), default=_D.field, show_default=True)
@click.option("--iters", type=COUNT, default=_D.iters, show_default=True, help="Optimiser steps.")
@click.option(
    "--batch",
    type=int,
    default=_D.batch,
    help="Rays per step (reconstruction). Default: 1024; spike-integral 4096 (4096 windows × 1 render; "
    "docs/spike-integral.md); on CUDA 4× these where the step fits the GPU (a GPU step costs about the "
    "same up to 16384 rays: H200, 21.8 ms at 4096 and 21.9 ms at 16384 for spike-integral).",
)
@click.option("--lr", type=float, default=None, help="Base learning rate (default: the field's own).")
@click.option("--seed", type=SEED, default=_D.seed, show_default=True)
@device_option(_D.device)
@click.option("--recon", type=click.Choice(RECONS), default=_D.targets.recon, show_default=True)
@click.option("--window", type=int, default=_D.targets.window, show_default=True, help="TFP window (odd).")
@click.option(
    "--blur-samples",
    type=int,
    default=_D.targets.blur_samples,
    show_default=True,
    help="Poses per exposure (nerf-blur-aware; nerf-bad's virtual frames, ≥ 2).",
)
@click.option(
    "--window-poses",
    type=int,
    default=None,
    help="Poses per TFP target, spread over its window and averaged (nerf-recon, spike-nerf; "
    "1 = the paper's; > 1 = window-aware targets, --recon tfp) "
    f"[default: {WINDOW_POSES} with --recon tfp, else 1].",
)
@click.option(
    "--integral-window",
    type=str,
    default=None,
    callback=lambda ctx, param, value: _lengths(value),
    help="spike-integral: window length(s) in steps, comma-separated (each target draws one) "
    f"[default: {INTEGRAL_WINDOW}, shortened to span at most {INTEGRAL_SPAN_PX:g} px of the dataset's "
    f"image motion (`spikenerf info` prints it), at least {INTEGRAL_SHORTEST}].",
)
@click.option(
    "--integral-samples",
    type=int,
    default=_D.integral.samples,
    show_default=True,
    help="spike-integral: steps rendered per window (stratified; their mean estimates the window's).",
)
@click.option(
    "--integral-track",
    type=int,
    default=None,
    help="spike-integral: h > 0 compares each render, after "
    f"{_D.integral.track_after} iterations (--set integral.track_after), with the spikes along its point's "
    "image track over 2h + 1 steps; 0: its pixel's window (docs/spike-integral.md) [default: "
    f"{TRACK_HALF} where the image moves more than {INTEGRAL_SPAN_PX / INTEGRAL_WINDOW:g} px a step, "
    "else 0].",
)
@click.option(
    "--spike-window", type=int, default=_D.spike.window, show_default=True, help="Steps per window."
)
@click.option(
    "--spike-pixels", type=int, default=_D.spike.pixels, show_default=True, help="Pixels per window."
)
@click.option(
    "--spike-warmup",
    type=int,
    default=_D.spike.warmup_iters,
    help="Iterations before λ ramps up (then a ramp of iters/5) [default: iters/5].",
)
@click.option(
    "--refine-poses/--no-refine-poses",
    default=None,
    help="Learn rotation and translation corrections (so(3)×R³) of the keyframe poses while training "
    "(poses.* in --set) [default: on for imported datasets; see docs/real-data.md].",
)
@click.option(
    "--holdout/--no-holdout",
    default=None,
    help="Keep the check steps of eval's no-reference checks, and a guard band around each, out of "
    "every training target [default: on for imported datasets].",
)
@click.option(
    "--holdout-steps",
    type=int,
    default=_D.holdout_steps,
    show_default=True,
    help="Check steps (evenly spaced) when the dataset has no imported test keyframes.",
)
@click.option(
    "--holdout-radius",
    type=int,
    default=None,
    help="Guard band half-width in steps [default: TFP half window + max(it, spike window / 2), e.g. 40].",
)
@click.option("--eval-every", type=int, default=_D.eval_every, show_default=True, help="0 = only at the end.")
@click.option("--eval-views", type=int, default=_D.eval_views, show_default=True, help="Test views per eval.")
@click.option("--ckpt-every", type=int, default=_D.ckpt_every, show_default=True)
@click.option(
    "--log",
    type=click.Choice(LOG_KINDS),
    default=_D.log,
    show_default=True,
    help="tensorboard: also write TensorBoard event files to RUN/tensorboard (needs spikenerf[tensorboard]).",
)
@click.option(
    "--log-every",
    type=int,
    default=_D.log_every,
    show_default=True,
    help="Iterations between reads of the loss terms (progress bar, TensorBoard).",
)
@click.option(
    "--amp",
    type=click.Choice(AMP_MODES),
    default=_D.amp,
    show_default=True,
    help="Mixed-precision training step (bf16 also on a CPU; fp16 with a gradient scaler, for CUDA).",
)
@click.option(
    "--compile",
    is_flag=True,
    default=_D.compile,
    help="torch.compile the field's per-sample functions; with --field-option static_samples=N the whole "
    "step's forward and loss instead, as one graph (CUDA graphs on CUDA). Compiles for tens of seconds "
    "first (cached for later runs); falls back to eager with a warning on failure. For long GPU runs: on a "
    "CPU the compiled step gained little (docs/performance.md).",
)
@click.option(
    "--compile-optimizer",
    is_flag=True,
    default=_D.compile_optimizer,
    help="torch.compile the Adam update of every parameter as one graph (a few seconds' compiling per grid "
    "resolution; eager with a warning on failure; not with --amp fp16). For CUDA, where it is not measured "
    "yet; on a CPU it is slower (docs/performance.md).",
)
@click.option(
    "--field-option",
    "field_options",
    multiple=True,
    metavar="KEY=VALUE",
    help="Override a field config entry (GridFieldConfig / MLPFieldConfig), e.g. n_voxels_final=2097152; "
    "values are parsed as YAML. Repeatable. Every key, its default and meaning: docs/cli.md, Field options.",
)
@click.option(
    "--config",
    "config_file",
    type=click.Path(path_type=Path),
    help="Start from this TrainConfig YAML (e.g. RUN/config.yaml, or the RUN folder) instead of the "
    "defaults.",
)
@click.option(
    "--set",
    "overrides",
    multiple=True,
    metavar="KEY=VALUE",
    help="Override any TrainConfig field (sections with dots: spike.lam, targets.window, field_config.X); "
    "values are YAML. Repeatable; applied after every other option.",
)
@click.option("--resume", is_flag=True, help="Continue the run in --out from its checkpoint.")
@click.option(
    "--ignore-unused",
    is_flag=True,
    help="No warning for flags the method does not use (for scripts that give every method one set).",
)
@click.option("--quiet", "--no-progress", "quiet", is_flag=True, help="No progress bar.")
@click.pass_context
def command(
    ctx: click.Context,
    dataset: Path | None,
    out: Path,
    config_file: Path | None,
    overrides: tuple[str, ...],
    resume: bool,
    ignore_unused: bool,
    quiet: bool,
    **options: object,
) -> None:
    SET_KEYS.clear()  # (several commands may run in one process: tests, the Python API)
    stored = out / CONFIG_FILE
    if config_file is not None:  # the file, then the options given on the command line, then --set
        if config_file.is_dir() and (config_file / CONFIG_FILE).is_file():  # a run folder: its config
            config_file = config_file / CONFIG_FILE
        if not config_file.is_file():
            found = "is a folder without a config.yaml" if config_file.is_dir() else "file not found"
            raise InputError(f"--config: {found}", path=config_file)
        base = load_config(config_file)
    elif resume and stored.is_file():  # resuming: keep the stored config, apply only given options
        base = load_run_config(stored)
    else:  # the click defaults are TrainConfig's defaults
        base = TrainConfig()
    given = {
        name
        for name in [*OPTION_FIELDS, "no_mask", "no_spike_loss", "field_options"]
        if ctx.get_parameter_source(name) == click.core.ParameterSource.COMMANDLINE
    }
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
    if overrides:
        keys = [item.partition("=")[0].strip() for item in overrides]
        SET_KEYS.update(keys)  # errors name --set KEY
        with _naming("--set", keys):
            base = TrainConfig.from_dict(apply_overrides(base.to_dict(), overrides))
    if dataset is None and not base.dataset:
        raise InputError("give the DATASET folder (or a --config whose 'dataset' names one)")
    if dataset is not None and overrides and "dataset" in keys:  # both: which one is meant?
        raise InputError("give the dataset once: as DATASET or as --set dataset=PATH, not both")
    from_run = dataset is None and resume and config_file is None and "dataset" not in SET_KEYS
    from_file = dataset is None and config_file is not None and "dataset" not in SET_KEYS
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
    base.dataset = str(dataset.resolve())
    notes = [] if ignore_unused else _unused(base.method, given, overrides, base.targets.recon)
    warmup = base.spike.warmup_iters
    if (
        base.method_class().has_spike_loss
        and base.spike.enabled
        and warmup is not None
        and warmup >= base.iters
    ):
        notes.append(
            f"--spike-warmup {warmup} is not below --iters {base.iters}: the spike loss never switches on"
        )
    from spikenerf.core.device import resolve_device
    from spikenerf.train.trainer import train  # (torch: not for --help or a bad flag)

    if base.field == "mlp" and not resume and resolve_device(base.device).type == "cpu":
        notes.append(
            f"--field mlp on a CPU: the paper's MLP runs 64 + 192 samples a ray through 8-layer networks, "
            f"so a step of {base.rays_per_step()} rays can take minutes here; it is meant for a GPU (the "
            "default grid trains on a CPU)"
        )
    summary = train(base.validate(), out, resume=resume, progress=not quiet, notes=notes)
    from spikenerf.train.methods import make_method

    stored = out / CONFIG_FILE  # as it trained, the dataset's defaults filled in
    method = make_method(load_run_config(stored) if stored.is_file() else base)
    if settings := method.settings():
        click.echo(f"{method.describe()}: {'; '.join(settings)}")
    test = summary.test_text()
    click.echo(
        f"trained {summary.iteration} iterations in {summary.seconds:.1f} s "
        f"({summary.rays_per_second:.0f} rays/s); train PSNR {summary.train_psnr:.2f} dB (against its "
        f"training targets), test PSNR {test} → {out}"
    )


#: flags that set a config key other than their own name's (``OPTION_FIELDS`` has the rest)
_FLAG_KEYS = {"no_mask": "targets.mask", "no_spike_loss": "spike.enabled"}


def _unused(method: str, given: set[str], overrides: tuple[str, ...], recon: str = "tfp") -> list[str]:
    """A warning for each given flag or ``--set`` key that ``method`` does not read (e.g. ``--lambda`` with
    ``--method nerf-gt``), or that its ``recon`` does not (``--window`` with ``--recon tfi``): the run goes
    on, as the same command line often trains several methods."""
    flags = {n: _FLAG_KEYS.get(n) or ".".join(filter(None, OPTION_FIELDS.get(n, ()))) for n in sorted(given)}
    keys = {key: PARAM_FLAGS.get(key, "--" + name.replace("_", "-")) for name, key in flags.items() if key}
    keys |= {item.partition("=")[0].strip(): f"--set {item.partition('=')[0].strip()}" for item in overrides}
    from spikenerf.train.methods import check_only_keys, unused_keys

    unused = unused_keys(method, keys)
    notes = [f"{keys[key]} is not used by --method {method}; ignored" for key in unused]
    checks_only = check_only_keys(method, keys)
    if recon in WINDOWLESS and "targets.window" in keys and "targets.window" not in unused + checks_only:
        notes.append(
            f"{keys['targets.window']} does not change --recon {recon}'s targets ({recon.upper()} has no "
            "window); it only sets the hold-out guard band"
        )
    notes += [
        f"{keys[key]} does not change how --method {method} trains; it only sets "
        + (
            "the reconstruction eval's no-reference checks compare renders with"
            if key == "targets.recon"
            else "eval's no-reference checks and the hold-out guard band"
        )
        for key in checks_only
    ]
    return notes


def _lengths(text: str | None) -> list[int] | None:
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
