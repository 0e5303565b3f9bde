"""``OUT/benchmark.json``: the dataset and training settings a benchmark folder was started with.

A resumed benchmark reuses its datasets and finished cells, so it must ask for what they were made with:
a changed ``size``, ``frames``, ``seed``, ``test_views``, ``blur_views``, ``noise``, ``noise_params``,
``color`` (one the
datasets lack), ``iters``, ``field_kind`` or extra train arguments is refused with one line naming the
setting(s) (the CLI shows their flags). The file also holds the folder's ``nonce``, which keys the Ray
workers' scratch copies (``ray_executor.scratch_root``).
A folder written before this file existed is resumed as it is, and gets the file then. The file also
records the field's default config (``field_defaults``); a folder started by a version with other
defaults (before ``step_ratio`` 0.75 and the bf16 decoder, or on a CPU that differs in native bf16) is
refused, since its finished cells would be compared with cells of another field.
"""

from __future__ import annotations

import dataclasses
import json
import uuid
from pathlib import Path
from typing import Any

import torch

from spikenerf.core.atomic import write_text_atomic
from spikenerf.core.errors import InputError
from spikenerf.fields.grid import native_bf16
from spikenerf.fields.registry import field_config
from spikenerf.train.config import TrainConfig
from spikenerf.train.methods import SpikeIntegral
from spikenerf.train.settings import INTEGRAL_SAMPLES, INTEGRAL_SPAN_PX, INTEGRAL_WINDOW, TRACK_HALF

NAME = "benchmark.json"
#: field-config entries added after folders were started, with the value that trains as before they
#: existed: a record without one reads it so (the grid's total-variation prior, off; its packed dynamic march)
ADDED_DEFAULTS: dict[str, Any] = {
    "tv_density": 0.0, "tv_app": 0.0, "tv_every": 4, "static_samples": 0, "static_colors": 0,
    "lookup": "auto", "composite": "torch", "march": "torch",
}  # fmt: skip
#: field-config entries since removed, with the value that trained as the defaults do now: a record with
#: that value reads as without it (``gather_lookup`` false is ``lookup`` "auto")
REMOVED_DEFAULTS: dict[str, Any] = {"gather_lookup": False}
#: field-config entries since removed that nothing read: a record's value of them, whatever it is, is ignored
UNREAD_DEFAULTS = ("batch_rays",)
#: spike-integral's defaults before they were recorded (2048 rays: 1024 windows of 11 steps × 2 renders)
PREVIOUS_INTEGRAL: dict[str, int] = {"window": 11, "samples": 2, "batch": 2048}
#: the settings (``BenchmarkConfig`` parameters, named in messages as they are; the CLI shows their flags)
KEYS = (
    "size", "frames", "seed", "test_views", "blur_views", "noise", "noise_params", "color", "iters",
    "field_kind", "extra_train_args",
)  # fmt: skip
#: settings added after folders were started, with the value those folders were made with
ADDED_SETTINGS: dict[str, Any] = {"noise": "ideal", "noise_params": {}}
#: how a message names a setting that is not a parameter
LABELS = {"extra_train_args": "extra train arguments"}


def settings(cfg: Any) -> dict:
    """What the datasets and cells of ``cfg`` depend on (``color``: the colours each dataset holds;
    ``field_defaults``: the field's default config in this version, with whether this machine's CPU runs
    the bf16 decoder natively, so a version or machine that trains other fields is refused; ``iters``: the
    iterations the cells train, the trainer's default resolved, so a folder started before that default
    changed is refused rather than mixing run lengths)."""
    color = cfg.colors[0] if len(cfg.colors) == 1 else "all"
    defaults = json.loads(json.dumps(dataclasses.asdict(field_config(cfg.field_kind))))
    if "decoder_bf16" in defaults:  # the grid's
        defaults["decoder_bf16"] = bool(defaults["decoder_bf16"] and native_bf16(torch.device("cpu")))
    values = {k: getattr(cfg, k) for k in KEYS if k != "color"}
    values["iters"] = values["iters"] or TrainConfig().iters
    integral = {"window": INTEGRAL_WINDOW, "samples": INTEGRAL_SAMPLES, "batch": SpikeIntegral.default_batch,
                "window_span_px": INTEGRAL_SPAN_PX, "track": TRACK_HALF}  # fmt: skip
    return {"color": color, **values, "field_defaults": defaults, "integral_defaults": integral}


def _differs(key: str, old: Any, new: Any) -> bool:
    return not (old == new or (key == "color" and old == "all"))  # an all-colour dataset serves any colour


def _change(key: str, was: Any, now: Any) -> str:
    """``key was → now``; for argument lists (the extra train arguments a demo derives from its flags) only
    the options whose values differ, e.g. ``--ckpt-every 4 → 5``."""
    if isinstance(was, list) and isinstance(now, list):
        before, after = _options(was), _options(now)
        differ = [f for f in {**before, **after} if before.get(f) != after.get(f)]
        return f"{LABELS.get(key, key)} " + ", ".join(
            f"{f} {before.get(f, '(none)')} → {after.get(f, '(none)')}" for f in differ
        )
    return f"{LABELS.get(key, key)} {was!r} → {now!r}"


def _options(args: list) -> dict[str, str]:
    """``["--a", "1", "--flag", "--set", "k=2"]`` → ``{"--a": "1", "--flag": "", "--set k": "2"}`` (each
    ``--set`` item by its key, so that repeated ones are told apart)."""
    found: dict[str, str] = {}
    for i, arg in enumerate(map(str, args)):
        if arg.startswith("--"):
            value = str(args[i + 1]) if i + 1 < len(args) and not str(args[i + 1]).startswith("--") else ""
            if arg == "--set" and "=" in value:
                key, _, value = value.partition("=")
                arg = f"--set {key.strip()}"
            found[arg] = value
    return found


def check_settings(cfg: Any) -> str | None:
    """The folder's nonce (None for a new or pre-``benchmark.json`` folder); InputError when ``cfg`` asks for
    other settings than the folder was started with."""
    path = cfg.out / NAME
    if not path.is_file():
        return None
    stored = read_stored(path)
    old, nonce = {**ADDED_SETTINGS, **stored["settings"]}, stored["nonce"]
    new = settings(cfg)
    if "iters" in old and old["iters"] is None:  # started without --iters when that was not recorded
        if cfg.iters is None:
            raise InputError(
                "this benchmark recorded no iteration count (started without one under an earlier "
                "default: 3000 iterations in stops 9–10, 1500 before); pass that count as iters to "
                "resume it, or a new out",
                path=cfg.out,
                param=("iters", "out"),
            )
        old = {**old, "iters": cfg.iters}  # the caller states which default trained the cells
    bad = [k for k in KEYS if _differs(k, old.get(k), new[k])]
    if bad:
        changes = "; ".join(_change(k, old.get(k), new[k]) for k in bad)
        raise InputError(
            f"this benchmark was started with other settings: pass the same values to resume it, or a new "
            f"out ({changes})",
            path=cfg.out,
            param=(*bad, "out"),
        )
    was = old.get("field_defaults")
    if was is not None:
        was = {**{k: v for k, v in ADDED_DEFAULTS.items() if k in new["field_defaults"]}, **was}
        was = {k: v for k, v in was.items() if k not in REMOVED_DEFAULTS or v != REMOVED_DEFAULTS[k]}
        was = {k: v for k, v in was.items() if k not in UNREAD_DEFAULTS}
    if was != new["field_defaults"]:
        what = "unrecorded (an earlier version)" if was is None else ", ".join(
            f"{k} {was.get(k)!r} → {new['field_defaults'].get(k)!r}"
            for k in {**was, **new["field_defaults"]} if was.get(k) != new["field_defaults"].get(k)
        )  # fmt: skip
        raise InputError(
            f"this benchmark's cells were trained with other field defaults ({what}); finish it with the "
            "version and machine that started it, or use a new out",
            path=cfg.out,
            param="out",
        )
    was = old.get("integral_defaults", PREVIOUS_INTEGRAL)
    if "spike-integral" in cfg.variants and integral_trained(cfg) and was != new["integral_defaults"]:
        new_integral = new["integral_defaults"].items()
        what = ", ".join(f"{k} {was.get(k)!r} → {v!r}" for k, v in new_integral if was.get(k) != v)
        raise InputError(
            f"this benchmark's spike-integral cells were trained with other defaults ({what}); finish it "
            "with the version that started it, or use a new out",
            path=cfg.out,
            param="out",
        )
    return nonce


def read_stored(path: Path) -> dict:
    """``benchmark.json`` read back: an object with a non-empty string ``nonce`` and an object ``settings``
    (its ``field_defaults``, where not null, and ``integral_defaults``, where present, objects); InputError
    naming the file otherwise."""
    try:
        stored = json.loads(path.read_text(encoding="utf-8"))
        old, nonce = stored["settings"], stored["nonce"]
        if not (isinstance(old, dict) and isinstance(nonce, str) and nonce):
            raise TypeError("expected an object settings and a string nonce")
        if not (
            isinstance(old.get("field_defaults"), dict | None)
            and isinstance(old.get("integral_defaults", {}), dict)
        ):
            raise TypeError("expected objects field_defaults and integral_defaults")
    except (OSError, ValueError, KeyError, TypeError, RecursionError) as err:  # (nested beyond the stack)
        raise InputError(f"malformed benchmark settings ({type(err).__name__}: {err}); delete the file to "
                         "adopt the current flags", path=path) from None  # fmt: skip
    return stored


def integral_trained(cfg: Any) -> bool:
    """Whether the folder holds a spike-integral cell that has begun training (a checkpoint)."""
    return any(cfg.out.glob("runs/*/*/spike-integral*/checkpoint.pt"))


def adopt_integral_defaults(cfg: Any) -> None:
    """Record this version's spike-integral defaults in a folder with no spike-integral cell yet (one
    started before the method joined it, e.g. a four-method demo): its cells train with them now. Call
    under the folder's lock, after :func:`check_settings` accepted it."""
    path = cfg.out / NAME
    if "spike-integral" not in cfg.variants or integral_trained(cfg) or not path.is_file():
        return
    stored = read_stored(path)
    current = settings(cfg)["integral_defaults"]
    if stored["settings"].get("integral_defaults") != current:
        stored["settings"]["integral_defaults"] = current
        write_text_atomic(path, json.dumps(stored, indent=2) + "\n")


def write_settings(cfg: Any, nonce: str | None) -> str:
    """Write ``benchmark.json`` (a new nonce when ``nonce`` is None); the nonce."""
    nonce = nonce or uuid.uuid4().hex
    text = json.dumps({"settings": settings(cfg), "nonce": nonce}, indent=2) + "\n"
    write_text_atomic(cfg.out / NAME, text)
    return nonce
