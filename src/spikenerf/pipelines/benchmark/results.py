"""The benchmark's written results: table1.md, table2.md, differences.md, results.csv, results.json (and
the report), from the finished cells; see docs/results.md for what each table means. Read back: the cells
of several folders' results.json as one set of tables (:func:`merged_markdown`, the script
``benchmarks/tools/merge_results.py``) and the differences beyond the paper's claims
(:func:`extra_differences_markdown`, ``benchmarks/tools/learned_differences.py``)."""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from spikenerf.camera.modes import NOISE_RANGES, NOISES
from spikenerf.core.atomic import write_text_atomic
from spikenerf.core.errors import InputError, is_finite
from spikenerf.data.choices import COLORS
from spikenerf.data.summary import view_counts
from spikenerf.pipelines.benchmark import cells as plan
from spikenerf.pipelines.benchmark.executor import EXECUTORS
from spikenerf.pipelines.benchmark.stats import Difference, differences
from spikenerf.pipelines.benchmark.tables import (
    Cell,
    cells_csv,
    differences_table,
    per_scene_table,
    table1_markdown,
    table2_markdown,
    to_markdown,
)
from spikenerf.pipelines.benchmark.variants import (
    ABLATION_VARIANTS,
    COMPARISONS,
    LEARNED_COMPARISONS,
    TABLE1_VARIANTS,
    VARIANTS,
    WINDOW_COMPARISONS,
)

#: a finished benchmark's record of its config, environment, cells and commands
RESULTS = "results.json"
#: config entries that must agree between merged benchmark folders (:func:`read_results`)
MERGE_KEYS = (
    "scenes", "size", "frames", "iters", "field_kind", "seed", "test_views", "blur_views", "noise",
    "extra_train_args",
)  # fmt: skip
#: a method's ``views`` (what its targets are posed on) -> how "trained on" counts them
VIEW_TEXT = {"steps": "{} poses", "gt": "{} GT views", "blur": "{} blur views"}


def poses_per_view(run: Path, variant: str) -> int:
    """Poses a cell's run renders per target view (its ``config.yaml``; else the variant's defaults), e.g.
    ``blur_samples`` for ``nerf-blur-aware`` and ``nerf-bad``."""
    from spikenerf.train.config_file import load_run_config
    from spikenerf.train.methods import make_method

    try:
        config = load_run_config(run / "config.yaml")
    except InputError:
        config = VARIANTS[variant].config()
    return make_method(config).poses_per_view()


def trained_on(cfg: plan.BenchmarkConfig) -> dict[str, str]:
    """variant -> what its runs trained on, counted from the datasets (values differing by scene joined by /).

    Its method's ``views`` says what: every step's pose (spike methods), the stored GT renders (``nerf-gt``)
    or the blur views; ``× N poses`` when each view is rendered at N poses (``nerf-blur-aware``,
    ``nerf-bad``: its ``blur_samples`` poses of the exposure; window-aware targets: "T targets × N poses"
    of each TFP window; from the run config).
    """
    from spikenerf.train.methods import METHOD_CLASSES

    counts = [view_counts(root) for s in cfg.scenes if (root := cfg.out / "datasets" / s).is_dir()]
    out = {}
    for v in cfg.variants:
        views = METHOD_CLASSES[VARIANTS[v].method].views
        texts = {VIEW_TEXT[views].format(c[views]) for c in counts}
        samples = {poses_per_view(plan.run_dir(cfg, *k), v) for k in plan.cell_keys(cfg) if k.variant == v}
        if samples - {1}:
            if views == "steps":  # window-aware targets: each step's target at N poses of its window
                texts = {f"{c['steps']} targets" for c in counts}
            texts = {f"{t} × {'/'.join(map(str, sorted(samples)))} poses" for t in texts}
        out[v] = " / ".join(sorted(texts)) or "–"
    return out


def write_all(cfg: plan.BenchmarkConfig, cells: Sequence[Cell], log: list[dict]) -> None:
    """table1.md, table2.md, differences.md, results.csv and results.json (the report: suite.py)."""
    views, seeds = trained_on(cfg), plan.training_seeds(cfg)
    t1_variants = [v for v in cfg.variants if v in TABLE1_VARIANTS] or cfg.variants
    t1 = "\n\n".join(table1_markdown(cells, t1_variants, cfg.scenes, c, views) for c in cfg.colors)
    note = (
        f"{seed_note(seeds)} Test views: {cfg.test_views} per scene; 'trained on' counted from the datasets. "
        f"{noise_note(cfg.noise, cfg.noise_params)}"
    )
    write_text_atomic(cfg.out / "table1.md", f"# Table I: comparison (test views)\n\n{note}\n\n{t1}\n")
    if any(v in ABLATION_VARIANTS for v in cfg.variants):
        t2 = "\n\n".join(table2_markdown(cells, c, views) for c in cfg.colors)
        write_text_atomic(
            cfg.out / "table2.md", f"# Table II: ablation (mean over scenes)\n\n{note}\n\n{t2}\n"
        )
    else:  # no ablation in this run: a table II of an earlier run here would contradict the others
        (cfg.out / "table2.md").unlink(missing_ok=True)
    diffs = differences(cells, cfg.colors)
    write_text_atomic(cfg.out / "differences.md", differences_markdown(diffs))
    write_text_atomic(cfg.out / "results.csv", cells_csv(cells))
    config = {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(cfg).items()}
    results = {
        "config": config,
        "environment": plan.environment(),
        "cells": [asdict(c) for c in cells],
        "trained_on": views,
        "differences": [asdict(d) for d in diffs],
        "commands": {
            "datasets": {s: plan.dataset_command(cfg, s)[2:] for s in cfg.scenes},
            "cells": {
                "/".join(map(str, k[:3])) + ("" if k.seed == cfg.seed else f"/seed{k.seed}"): [
                    cmd[2:] for cmd in plan.cell_commands(cfg, *k, todo=False)
                ]
                for k in plan.cell_keys(cfg)
            },
            "this_run": log,
        },
    }
    write_text_atomic(cfg.out / RESULTS, json.dumps(results, indent=2) + "\n")


def noise_note(noise: str, params: dict | None = None) -> str:
    """What spike camera the datasets were simulated with (``simulate --noise``, ``--noise-param``)."""
    if noise == "ideal":
        return "Spike streams: noise-free simulated camera (ideal)."
    replaced = ", ".join(f"{key}={value:g}" for key, value in (params or {}).items())
    return (
        f"Spike streams: simulated camera with {noise} noise (shot noise, dark current, per-pixel gain and "
        "threshold mismatch; docs/camera.md)" + (f", the preset's {replaced}." if replaced else ".")
    )


def seed_note(seeds: Sequence[int]) -> str:
    if len(seeds) == 1:
        return f"One training seed ({seeds[0]}): no error bars."
    return (
        f"Mean ± sample standard deviation over {len(seeds)} training seeds ({', '.join(map(str, seeds))})."
    )


def differences_note() -> str:
    """How the differences table is computed (shown above it in Markdown and HTML)."""
    return (
        "Each difference (ours − baseline) is paired over scene × seed: the same dataset and training seed. "
        "95% confidence interval = mean ± t(0.975, n−1)·std/√n (Student t). Pairs of one scene "
        "share its effect, so the per-seed 95% CI repeats it over the per-seed means (each over the "
        "scenes every seed has, seeds − 1 degrees of freedom). A claim is 'shown' only when both intervals "
        "exclude 0 on the claimed side (higher PSNR/SSIM, lower LPIPS); otherwise 'not shown' (a zero "
        "difference is not excluded; 'reversed' when the pair interval excludes 0 on the other side). One "
        "pair gives no interval; with one training seed the interval spans scenes only, not seed noise, so "
        "nothing is 'shown'."
    )


def differences_markdown(diffs: Sequence[Difference]) -> str:
    """``differences.md``: the paired differences the paper claims, with 95% Student-t intervals."""
    table = to_markdown(differences_table(diffs)) if diffs else "No comparable pairs were run."
    return f"# Paired differences (ours − baseline)\n\n{differences_note()}\n\n{table}\n"


@dataclass(frozen=True)
class RecordedCall:
    """What one benchmark call recorded in its ``results.json`` (:func:`read_call`)."""

    path: Path
    config: dict  #: the benchmark's settings (``BenchmarkConfig`` as a dict)
    cells: list[Cell]
    trained_on: dict[str, str]
    environment: dict


def read_call(path: Path) -> RecordedCall:
    """A ``results.json`` read back; InputError naming the file when it cannot be read, is not a benchmark's
    results, or holds a value its tables and report cannot take (:func:`recorded_problem`), before anything
    is built from it."""
    try:
        data = json.loads(path.read_text())
        config = {"noise": "ideal", **dict(data["config"])}  # (recorded since noise could be chosen)
        missing = [k for k in MERGE_KEYS if k not in config]
        if missing:
            raise KeyError(", ".join(missing))
        if not isinstance(data["cells"], list):
            raise TypeError(f"cells is {type(data['cells']).__name__}, not a list")
        if (
            bad := next((i for i, c in enumerate(data["cells"]) if not isinstance(c, dict)), None)
        ) is not None:
            raise TypeError(f"cells[{bad}] is {type(data['cells'][bad]).__name__}, not an object")
        cells = [Cell.from_dict(c) for c in data["cells"]]
        call = RecordedCall(
            path, config, cells, dict(data.get("trained_on", {})), dict(data.get("environment", {}))
        )
    except IsADirectoryError:
        raise InputError(f"is a folder: give its {RESULTS} (another call's results)", path=path) from None
    except OSError as err:
        raise InputError(f"cannot read ({err.strerror or err})", path=path) from None
    except (ValueError, KeyError, TypeError, AttributeError, RecursionError) as err:
        raise InputError(f"not a benchmark's {RESULTS} ({type(err).__name__}: {err})", path=path) from None
    if problem := recorded_problem(call):
        raise InputError(problem, path=path)
    return call


#: a scene's name as the benchmark's folders use it (``datasets/SCENE``, ``runs/SCENE``, figure files): one
#: plain path component, never ``..`` or a path
SCENE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")


def _int(x: Any, low: int) -> bool:
    return isinstance(x, int) and not isinstance(x, bool) and x >= low


def _number(x: Any, low: float = -math.inf) -> bool:
    """A finite JSON number (not a bool) ≥ ``low``."""
    return isinstance(x, int | float) and is_finite(x) and x >= low


def _names(x: Any, ok: Callable[[Any], bool]) -> bool:
    """A non-empty list of distinct items, each ``ok``."""
    return isinstance(x, list) and bool(x) and all(ok(v) for v in x) and len(set(x)) == len(x)


def _scene(x: Any) -> bool:
    return isinstance(x, str) and SCENE_NAME.fullmatch(x) is not None


#: config entry -> (what it must be, its test); a results.json without an entry reads its default
CONFIG_CHECKS: dict[str, tuple[str, Callable[[Any], bool]]] = {
    "scenes": ("a non-empty list of distinct scene names (letters, digits, _ . -; not a path)",
               lambda x: _names(x, _scene)),
    "variants": ("a non-empty list of distinct method variants",
                 lambda x: _names(x, lambda v: isinstance(v, str) and v in VARIANTS)),
    "colors": ("a non-empty list of distinct colours (gray, rgb)", lambda x: _names(x, COLORS.__contains__)),
    "size": ("a positive integer", lambda x: _int(x, 1)),
    "frames": ("a positive integer", lambda x: _int(x, 1)),
    "iters": ("null or a positive integer", lambda x: x is None or _int(x, 1)),
    "seed": ("a non-negative integer", lambda x: _int(x, 0)),
    "seeds": ("null or a non-empty list of distinct non-negative integers",
              lambda x: x is None or _names(x, lambda k: _int(k, 0))),
    "test_views": ("a positive integer", lambda x: _int(x, 1)),
    "jobs": ("a positive integer", lambda x: _int(x, 1)),
    "retries": ("a non-negative integer", lambda x: _int(x, 0)),
    "render": ("true or false", lambda x: isinstance(x, bool)),
    "ship_results": ("true or false", lambda x: isinstance(x, bool)),
    "keep_going": ("true or false", lambda x: isinstance(x, bool)),
    "field_kind": ("a string", lambda x: isinstance(x, str)),
    "device": ("a string", lambda x: isinstance(x, str)),
    "blur_views": ("a string", lambda x: isinstance(x, str)),
    "noise": (f"one of {', '.join(NOISES)}", lambda x: isinstance(x, str) and x in NOISES),
    "noise_params": ("a mapping of realistic noise parameter names to numbers",
                     lambda x: isinstance(x, dict) and all(k in NOISE_RANGES and (_number(v) or v == math.inf)
                                                           for k, v in x.items())),
    "executor": (f"one of {', '.join(EXECUTORS)}", lambda x: isinstance(x, str) and x in EXECUTORS),
    "address": ("null or a string", lambda x: x is None or isinstance(x, str)),
    "extra_train_args": ("a list of strings",
                         lambda x: isinstance(x, list) and all(isinstance(a, str) for a in x)),
    "ray_cpus": ("a positive number", lambda x: _number(x) and x > 0),
}  # fmt: skip
#: a cell's metrics, each a finite number or null (not available, as "–" in the tables), and its times
CELL_METRICS, CELL_TIMES = ("psnr", "ssim", "lpips"), ("eval_seconds", "train_seconds")


def recorded_problem(call: RecordedCall) -> str | None:
    """What makes a read ``results.json`` unusable (None: nothing): a config entry of another type or range
    (:data:`CONFIG_CHECKS`; a scene name that is not one plain path component), a cell whose scene,
    colour or method variant is not one of the config's, whose seed is not a non-negative integer, whose
    metric is not a finite number or null, or a 'trained on' text that is not a string."""
    config = call.config
    for key, (what, ok) in CONFIG_CHECKS.items():
        if key in config and not ok(config[key]):
            return f"config.{key} must be {what}, found {config[key]!r}"
    allowed = {"scene": config["scenes"], "color": config.get("colors", list(COLORS)),
               "variant": config.get("variants", list(VARIANTS))}  # fmt: skip
    for i, cell in enumerate(call.cells):
        for key, names in allowed.items():
            value = getattr(cell, key)
            if value not in names:
                return f"cells[{i}].{key} {value!r} is not one of config.{key}s ({', '.join(names)})"
        if not _int(cell.seed, 0):
            return f"cells[{i}].seed must be a non-negative integer, found {cell.seed!r}"
        for key in CELL_METRICS + CELL_TIMES:
            value = getattr(cell, key)
            if value is not None and not _number(value, 0.0 if key in CELL_TIMES else -math.inf):
                kind = "number ≥ 0" if key in CELL_TIMES else "number"
                return f"cells[{i}].{key} must be a finite {kind} or null, found {value!r}"
    for variant, text in call.trained_on.items():
        if not isinstance(text, str):
            return f"trained_on.{variant} must be a string, found {text!r}"
    return None


def read_results(paths: Sequence[Path]) -> tuple[dict, list[Cell], dict[str, str]]:
    """The shared config (:data:`MERGE_KEYS`), every cell and the 'trained on' texts of several benchmark
    folders' ``results.json`` (``paths``; :func:`merge_calls`)."""
    return merge_calls([read_call(Path(p)) for p in paths])


def merge_calls(calls: Sequence[RecordedCall]) -> tuple[dict, list[Cell], dict[str, str]]:
    """The shared config (:data:`MERGE_KEYS`), every cell and the 'trained on' texts of several calls;
    InputError when a call's config differs from the first's or a cell (scene, colour, variant, seed) is in
    two of them."""
    if not calls:
        raise InputError(f"no {RESULTS} given", param="paths")
    config = {k: calls[0].config[k] for k in MERGE_KEYS}
    cells: list[Cell] = []
    trained_on: dict[str, str] = {}
    seen: dict[tuple, int] = {}  # cell -> the call holding it
    for n, call in enumerate(calls):
        if diff := [k for k in MERGE_KEYS if call.config[k] != config[k]]:
            raise InputError(f"{call.path}: its benchmark differs from {calls[0].path} in {', '.join(diff)}")
        for c in call.cells:
            key = (c.scene, c.color, c.variant, c.seed)
            if key in seen:
                where = "held twice in this file" if seen[key] == n else "also in an earlier file"
                raise InputError(f"{call.path}: cell {'/'.join(map(str, key))} is {where}")
            seen[key] = n
            cells.append(c)
        trained_on.update(call.trained_on)
    return config, cells, trained_on


def merged_markdown(paths: Sequence[Path]) -> str:
    """Tables I/II and the paired differences of the cells of several ``results.json`` taken together (e.g.
    one ``benchmark --seeds K`` call each), as a single ``--seeds 0,1,...`` run would have written them."""
    config, cells, views = read_results(paths)
    colors = sorted({c.color for c in cells}, key=COLORS.index)
    variants = list(dict.fromkeys(c.variant for c in cells))
    seeds = sorted({c.seed for c in cells})
    parts = [f"{len(cells)} cells from {len(paths)} folders; {seed_note(seeds)}\n"]
    t1 = [v for v in variants if v in TABLE1_VARIANTS]
    blocks = [table1_markdown(cells, t1, config["scenes"], c, views) for c in colors]
    parts.append("# Table I\n\n" + "\n\n".join(blocks))
    if any(v in ABLATION_VARIANTS for v in variants):
        parts.append("\n# Table II\n\n" + "\n\n".join(table2_markdown(cells, c, views) for c in colors))
    parts.append("\n" + differences_markdown(differences(cells, colors)))
    return "\n".join(parts)


def extra_differences_markdown(path: Path, per_scene: bool = False) -> str:
    """The paired differences beyond the paper's claims (:data:`~.variants.LEARNED_COMPARISONS`,
    :data:`~.variants.WINDOW_COMPARISONS`) of a benchmark's ``results.json``, pairs it lacks left out; with
    ``per_scene``, each scene's PSNR differences too (the paper's headline pair and the window pairs)."""
    cells = read_call(path).cells
    colors = sorted({c.color for c in cells})
    parts = [
        to_markdown(differences_table(differences(cells, colors, LEARNED_COMPARISONS + WINDOW_COMPARISONS)))
    ]
    if per_scene:
        for color in colors:
            parts.append(f"\n{color}, PSNR (dB):\n")
            parts.append(
                per_scene_table([c for c in cells if c.color == color], COMPARISONS[:1] + WINDOW_COMPARISONS)
            )
    return "\n".join(parts)
