"""``spikenerf train DATASET --method ... --out RUN``: train a radiance field on a spike dataset.

The command's body: its options are declared in :mod:`spikenerf.cli.train_options` and turned into a
TrainConfig by :mod:`spikenerf.cli.train_flags`; here the notes about them, the training and its summary."""

from __future__ import annotations

from pathlib import Path

import click

from spikenerf.camera.reconstruct import WINDOWLESS
from spikenerf.cli.train_flags import (
    OPTION_FIELDS,
    apply_flags,
    apply_set,
    dataset_folder,
    given_flags,
    start_config,
)
from spikenerf.cli.train_options import HELP, train_options
from spikenerf.train.config_file import CONFIG_FILE, load_run_config

#: the config keys this command's ``--set`` gave (an error about one names ``--set KEY``, not its flag)
SET_KEYS: set[str] = set()
#: TrainConfig key → its flag: errors raised below the CLI name the key, the CLI shows the flag
#: (``spikenerf.cli.flag_of``)
PARAM_FLAGS = {
    f"{section}.{key}" if section else key: "--" + ("lambda" if name == "lam" else name.replace("_", "-"))
    for name, (section, key) in OPTION_FIELDS.items()
} | {"field_config": "--field-option (grid size)", "holdout": "--holdout (--no-holdout turns it off)"}


@click.command(help=HELP)
@train_options
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
    # the file, then the options given on the command line, then --set
    base, config_file = start_config(config_file, resume, out / CONFIG_FILE)
    given = given_flags(ctx)
    apply_flags(base, given, options)
    if overrides:
        keys = [item.partition("=")[0].strip() for item in overrides]
        SET_KEYS.update(keys)  # errors name --set KEY
        base = apply_set(base, overrides, keys)
    dataset = dataset_folder(dataset, base, out, resume=resume, config_file=config_file, set_keys=SET_KEYS)
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
    sets = {
        "targets.recon": "the reconstruction eval's no-reference checks compare renders with",
        "targets.window_poses": "how many renders eval averages over each TFP keyframe's window (an imported "
        "dataset's test views and the no-reference checks)",
    }
    notes += [
        f"{keys[key]} does not change how --method {method} trains; it only sets "
        + sets.get(key, "eval's no-reference checks and the hold-out guard band")
        for key in checks_only
    ]
    return notes
