"""``spikenerf benchmark``: the paper's Table I and Table II, resumable, as md, csv, json and html."""

from __future__ import annotations

from pathlib import Path

import click
from click.core import ParameterSource

from spikenerf.camera.modes import NOISE_RANGES, NOISES
from spikenerf.cli.options import noise_param_option, parse_noise_params
from spikenerf.cli.types import SEED, OutPath, device_option
from spikenerf.core.errors import InputError, comma_list
from spikenerf.data.choices import COLORS
from spikenerf.fields.choices import FIELD_KINDS
from spikenerf.pipelines.benchmark.executor import EXECUTORS
from spikenerf.pipelines.benchmark.variants import VARIANTS

#: lower-layer parameters named unlike their flag (see ``spikenerf.cli.flag_of``)
PARAM_FLAGS = {"field_kind": "--field", **{name: f"--noise-param {name}" for name in NOISE_RANGES}}
#: TrainConfig keys that each cell gets from the benchmark's own flags (a --set of one would train another
#: cell than its tables label), with those flags
BENCHMARK_KEYS = {
    "method": "--methods", "color": "--color", "field": "--field", "seed": "--seeds", "iters": "--iters",
    "dataset": "--scenes", "device": "--device",
}  # fmt: skip


@click.command(help="Reproduce Table I (comparison) and Table II (ablation) on the built-in scenes.")
@click.option(
    "--scenes", default="all", show_default=True,
    help="'all' (the six Blender scenes; the analytic ones where Blender is not installed, with a warning) "
    "or comma-separated scene names.",
)  # fmt: skip
@click.option(
    "--methods", default="all", show_default=True,
    help=f"'all', 'table1', 'table2' or comma-separated variants ({', '.join(VARIANTS)}).",
)  # fmt: skip
@click.option("--color", default="gray,rgb", show_default=True, help="gray, rgb or gray,rgb.")
@click.option("--out", type=OutPath(), required=True, help="Benchmark folder (resumable).")
@click.option("--size", type=int, default=100, show_default=True, help="Image width = height in pixels.")
@click.option("--frames", type=int, default=1000, show_default=True, help="Spike steps on the orbit.")
@click.option("--iters", type=click.IntRange(min=1), help="Training iterations per run [default: trainer's].")
@click.option("--field", type=click.Choice(FIELD_KINDS), default="grid", show_default=True)
@device_option(help="Where cells train.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Dataset (simulation) seed.")
@click.option(
    "--seeds",
    help="Training seeds, comma-separated (e.g. 0,1,2): every cell is trained once per seed; tables show "
    "mean ± std and OUT/differences.md the paired differences with 95% intervals [default: --seed].",
)
@click.option(
    "--blur-views", default="all", show_default=True,
    help="The datasets' blur views (simulate --blur-views): 'all' = the paper's baseline (one exposure "
    "centred on every step), 'frames' = consecutive 400 fps frames, or N evenly spaced exposures.",
)  # fmt: skip
@click.option("--test-views", type=click.IntRange(min=1), default=8, show_default=True)
@click.option(
    "--noise", type=click.Choice(NOISES), default="ideal", show_default=True,
    help="The simulated spike camera's noise (simulate --noise): 'realistic' adds shot noise, dark current "
    "and per-pixel gain and threshold mismatch (docs/camera.md).",
)  # fmt: skip
@noise_param_option
@click.option(
    "--set", "overrides", multiple=True, metavar="KEY=VALUE",
    help="Override a TrainConfig field in every cell's training, as `train --set` (e.g. --set batch=4096 "
    "--set field_config.n_voxels_final=27000000 for a GPU). Repeatable; kept in OUT/benchmark.json.",
)  # fmt: skip
@click.option(
    "--no-render",
    is_flag=True,
    help="Skip rendering test views (the report's view figure then shows the methods as missing).",
)
@click.option(
    "--jobs",
    type=click.IntRange(min=1),
    default=1,
    show_default=True,
    help="Steps run at once (outputs go to OUT/logs/; each gets cpu_count // jobs threads unless "
    "OMP_NUM_THREADS is set).",
)
@click.option("--keep-going", is_flag=True,
              help="Run every cell even when one fails; the failures are listed at the end (exit 2; the "
              "tables are written once every cell has finished) and the next call retries them "
              "(--executor ray always goes on).")  # fmt: skip
@click.option("--executor", type=click.Choice(list(EXECUTORS)), default="local", show_default=True,
              help="local: --jobs processes on this machine; ray: every dataset and cell a Ray task (needs "
              "'spikenerf[cluster]'; OUT on shared storage, see docs/cluster.md).")  # fmt: skip
@click.option("--address", help="Ray cluster: 'auto', HOST:PORT or 'local' (a new one here) [default: "
              "$RAY_ADDRESS, else the cluster last started here, else a new local one].")  # fmt: skip
@click.option("--retries", type=click.IntRange(min=0), default=2, show_default=True,
              help="Ray: retries of a failed cell (logs of every attempt kept in OUT/logs/).")  # fmt: skip
@click.option(
    "--ray-cpus",
    type=click.FloatRange(min=0, min_open=True),
    default=1.0,
    show_default=True,
    help="Ray: CPUs per task (and its threads); a cell also takes a GPU with --device cuda.",
)
@click.option(
    "--ray-ship-results",
    is_flag=True,
    help="Ray: no shared storage; workers use a local scratch copy, files travel by object store.",
)
def command(
    scenes: str, methods: str, color: str, out: Path, size: int, frames: int, iters: int | None,
    field: str, device: str, seed: int, seeds: str | None, blur_views: str, test_views: int, noise: str,
    noise_params: tuple[str, ...], overrides: tuple[str, ...], no_render: bool, jobs: int, keep_going: bool,
    executor: str, address: str | None, retries: int, ray_cpus: float, ray_ship_results: bool,
) -> None:  # fmt: skip
    from spikenerf.capture.blur import check_blur_views
    from spikenerf.pipelines.benchmark.cells import (
        BenchmarkConfig,
        check_size,
        parse_seeds,
        resolve_scenes,
        resolve_variants,
    )
    from spikenerf.pipelines.suite import benchmark_with_report

    colors = comma_list(
        color, COLORS, lambda _: f"--color: expected gray, rgb or gray,rgb, got {color!r}", "color"
    )
    check_size(size)
    replaced = parse_noise_params(noise_params)
    if replaced and noise != "realistic":
        raise InputError(
            f"--noise-param: replaces the realistic noise's parameters, and --noise is {noise!r}"
        )
    if replaced:
        from spikenerf.camera.noise import noise_with

        noise_with(replaced, "noise_params")  # names and ranges, before any simulation
    if frames < 2:
        raise InputError(f"--frames must be ≥ 2, found {frames}")
    views = str(check_blur_views(blur_views, frames))
    variants = resolve_variants(methods)
    if overrides:  # a bad key fails here, once, not in every cell
        from spikenerf.fields.registry import field_config
        from spikenerf.pipelines.benchmark.variants import VARIANTS
        from spikenerf.train.config import TrainConfig
        from spikenerf.train.config_file import apply_overrides

        for item in overrides:  # a cell's identity: set by the benchmark, labelled in its tables
            key = item.partition("=")[0].strip()
            if key in BENCHMARK_KEYS:
                flag = BENCHMARK_KEYS[key]
                raise InputError(f"--set {key}: the benchmark sets it for each cell; use {flag}")
            if owner := next((v for v in VARIANTS if key in dict(VARIANTS[v].overrides)), None):
                raise InputError(  # it tells variants apart: a row would be labelled as another's
                    f"--set {key}: the benchmark's variants set it (e.g. {owner}); choose the variants with "
                    "--methods"
                )
        try:
            trained = TrainConfig.from_dict(apply_overrides(TrainConfig().to_dict(), list(overrides)))
            field_config(field, trained.validate().field_config)  # a field option's typo, for this field
        except InputError as err:
            raise InputError(f"--set: {err}") from err
        from spikenerf.train.methods import unused_keys

        chosen = sorted({VARIANTS[v].method for v in variants})
        keys = [item.partition("=")[0].strip() for item in overrides]
        for key in (k for k in keys if all(unused_keys(m, [k]) for m in chosen)):
            click.echo(
                f"spikenerf: warning: --set {key} is not used by any chosen method ({', '.join(chosen)}); "
                "ignored",
                err=True,
            )
    given = click.get_current_context().get_parameter_source
    ray_only = [
        name
        for name in ("address", "retries", "ray_cpus", "ray_ship_results")
        if given(name) != ParameterSource.DEFAULT
    ]
    if executor != "ray" and ray_only:
        flags = ", ".join(f"--{name.replace('_', '-')}" for name in ray_only)
        raise InputError(f"{flags}: only with --executor ray")
    if executor == "ray" and given("jobs") != ParameterSource.DEFAULT:
        raise InputError(
            "--jobs: only with --executor local (Ray runs as many cells at once as it can place)"
        )
    if executor == "ray" and device.startswith("cuda:"):
        raise InputError(
            f"--device {device}: Ray gives each cell its GPU; use --device cuda with --executor ray"
        )
    if executor != "ray":  # a Ray cluster's workers may have the device the head lacks
        from spikenerf.core.device import resolve_device

        resolve_device(device)
    if scenes == "all":
        from spikenerf.scenes.registry import blender_available

        if not blender_available():
            click.echo(
                "spikenerf: warning: --scenes all: Blender is not installed (pip install "
                "'spikenerf[blender]'), so the analytic scenes stand in for the paper's six Blender scenes",
                err=True,
            )
    cfg = BenchmarkConfig(
        scenes=resolve_scenes(scenes), variants=variants, colors=colors, out=out,
        size=size, frames=frames, iters=iters, field_kind=field, device=device, seed=seed,
        test_views=test_views, render=not no_render, jobs=jobs, executor=executor, address=address,
        retries=retries, ship_results=ray_ship_results, ray_cpus=ray_cpus, keep_going=keep_going,
        seeds=None if seeds is None else parse_seeds(seeds), blur_views=views, noise=noise,
        noise_params=replaced, extra_train_args=[arg for item in overrides for arg in ("--set", item)],
    )  # fmt: skip
    benchmark_with_report(cfg)
    names = ("table1.md", "table2.md", "differences.md", "results.csv", "results.json", "report.html")
    click.echo(f"wrote {out}/" + ", ".join(n for n in names if (Path(out) / n).is_file()))
