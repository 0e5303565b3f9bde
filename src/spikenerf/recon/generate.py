"""``recon-data``: write a pair folder (train and held-out val splits), resumable shard by shard.

Train pairs come from random procedural scenes (seeded by ``seed``), plus optional Blender scenes, image
sequences and natural photographs (``recon/natural.py``); val pairs come from scenes never used for training:
the named analytic scenes (:data:`VAL_SCENES`), random scenes of another seed stream and, with photographs,
the held-out ones.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from dataclasses import asdict
from pathlib import Path

import numpy as np

from spikenerf.camera.model import CameraConfig
from spikenerf.core.atomic import clean_stale_temps, write_text_atomic
from spikenerf.core.errors import InputError
from spikenerf.core.limits import check_resources
from spikenerf.core.lock import output_lock
from spikenerf.core.marker import check_output, mark
from spikenerf.core.replacement import discard_fresh, fresh_state
from spikenerf.recon.natural import (
    NATURAL_HELDOUT,
    NATURAL_TRAIN,
    load_images,
    natural_pairs,
    require_skimage,
)
from spikenerf.recon.pairs import PairConfig, Sample, analytic_pairs, source_pairs
from spikenerf.recon.store import MANIFEST, SPLITS, read_manifest, shard_ok, shard_path, write_shard
from spikenerf.scenes.base import FrameSource

#: named analytic scenes held out for validation (never in the train split)
VAL_SCENES = ["analytic-orbs", "analytic-blocks"]
#: random draws per shard
DRAWS_PER_SHARD = 24
#: the seed stream of held-out random scenes is ``seed + VAL_SEED_OFFSET``
VAL_SEED_OFFSET = 7919
#: the largest brightness scale: the camera collects the scaled radiance as float32 charge over the window
#: (and the targets are float32 rates), which must stay finite; far past it a pixel fires every step anyway
MAX_BRIGHTNESS = 1e6
#: manifest entries that follow from the others (not compared on a resume)
DERIVED = ("val_scenes",)


Job = tuple[str, Callable[[range], Iterator[Sample]], int]


def plan(
    cfg: PairConfig,
    train_draws: int,
    val_draws: int,
    seed: int,
    extra: dict[str, FrameSource],
    extra_draws: int,
    natural_draws: int = 0,
) -> list[Job]:
    """The jobs (split, draw function of a range of draw indices, draw count) of a pair folder, in order.
    ``natural_draws`` > 0 adds that many photograph draws to train and a quarter of ``val_draws`` of the
    held-out photographs to val."""
    jobs: list[Job] = [("train", lambda d: analytic_pairs(None, d, cfg, seed), train_draws)]
    for k, name in enumerate(sorted(extra)):
        src_seed = seed * 1000 + k + 1
        jobs.append(("train", lambda d, s=extra[name], q=src_seed: source_pairs(s, d, cfg, q), extra_draws))
    if natural_draws > 0:
        train, held = load_images(NATURAL_TRAIN), load_images(NATURAL_HELDOUT)
        jobs.append(("train", lambda d: natural_pairs(train, d, cfg, seed * 1000 + 999), natural_draws))
        held_seed = seed + 3 * VAL_SEED_OFFSET
        jobs.append(("val", lambda d: natural_pairs(held, d, cfg, held_seed), natural_val_draws(val_draws)))
    half = val_draws // 2
    jobs.append(
        ("val", lambda d: analytic_pairs(VAL_SCENES, d, cfg, seed + VAL_SEED_OFFSET), val_draws - half)
    )
    jobs.append(("val", lambda d: analytic_pairs(None, d, cfg, seed + 2 * VAL_SEED_OFFSET), half))
    return jobs


def natural_val_draws(val_draws: int) -> int:
    """Draws of held-out photographs in the val split of a folder with photographs: a quarter of its val
    draws (none below 4)."""
    return val_draws // 4


def val_scenes(val_draws: int, seed: int, natural: bool) -> list[str]:
    """What the val split of :func:`plan` draws: the named analytic scenes its draws reach (round robin), the
    random scenes of their seed where it draws any, and the held-out photographs its draws reach."""
    named = val_draws - val_draws // 2
    scenes = VAL_SCENES[: min(named, len(VAL_SCENES))]
    scenes += [f"random scenes of seed {seed + 2 * VAL_SEED_OFFSET}"] if val_draws // 2 else []
    photos = sorted(NATURAL_HELDOUT)[: natural_val_draws(val_draws)] if natural else []
    return scenes + [f"natural:{name}" for name in photos]


def check_brightness(brightness: tuple[float, float]) -> tuple[float, float]:
    """``brightness`` (LO, HI) when 0 < LO ≤ HI ≤ :data:`MAX_BRIGHTNESS`; else InputError naming it."""
    lo, hi = brightness
    if 0 < hi < lo <= MAX_BRIGHTNESS:
        raise InputError(f"brightness LO:HI must have LO ≤ HI, found {lo:g}:{hi:g}", param="brightness")
    if not (0 < lo <= hi <= MAX_BRIGHTNESS):  # (NaN fails too)
        raise InputError(
            f"brightness must be LO:HI with 0 < LO ≤ HI ≤ {MAX_BRIGHTNESS:g}, found {lo:g}:{hi:g} (the "
            "camera collects the scaled radiance as float32 charge, which must stay finite; a pixel fires "
            "every step long before that scale)",
            param="brightness",
        )
    return lo, hi


def pairs_resources(cfg: PairConfig, draws: int) -> tuple[float, float]:
    """Estimated (peak memory, disk) bytes of ``draws`` random draws of pairs: at most 4 samples a draw
    (Bayer), each a packed K-step window of P² bits and a float32 P² target; in memory one shard's samples
    unpacked and the frames a draw simulates (K steps at 2P a side, a few float32 copies)."""
    k, p = cfg.window, cfg.size
    sample = k * p * -(-p // 8) + 4.0 * p * p
    memory = DRAWS_PER_SHARD * 4 * 5.0 * k * p * p + 16.0 * k * (2 * p) ** 2 * 4
    return memory, draws * 4 * sample


def write_pairs(
    out: str | Path,
    cfg: PairConfig,
    train_draws: int,
    val_draws: int,
    seed: int = 0,
    extra: dict[str, FrameSource] | None = None,
    extra_draws: int = 0,
    command: str = "",
    progress: bool | None = None,
    natural_draws: int = 0,
) -> dict:
    """Generate (or finish) the pair folder ``out``; returns the manifest.

    Args:
        cfg: pair settings. train_draws / val_draws: random draws per split (a draw gives 1, 3 or 4 samples).
        extra: named FrameSources (Blender scenes, sequences) added to the train split, ``extra_draws`` each.
        seed: seeds the draws (validation draws from their own offset seed). command: the command line,
            recorded in the manifest. progress: a progress bar over the shards (None: only on a terminal).
        natural_draws: photograph draws added to the train split (``recon/natural.py``; needs scikit-image).
    Raises:
        InputError: ``out`` holds pairs made with other settings (named); a brightness past
            :data:`MAX_BRIGHTNESS`; a draw whose targets are not finite (no shard of it is written, and a
            folder this call created is removed).
    """
    out = Path(out)
    CameraConfig(threshold=cfg.threshold)  # a φ the camera refuses (past float32): refused before writing
    check_brightness(cfg.brightness)
    if natural_draws > 0:
        require_skimage()  # before anything is written
    draws = train_draws + val_draws + extra_draws * len(extra or {}) + natural_draws
    check_output(out, "pairs", overwrite=True)  # first: an unwritable --out is not a size problem
    sized = ["train_draws", "val_draws"] + ["extra_draws"] * bool(extra and extra_draws)
    sized += ["natural_draws"] * (natural_draws > 0) + ["window", "size"]
    check_resources(*pairs_resources(cfg, draws), out, "/".join(sized))
    with output_lock(out):
        check_output(out, "pairs", overwrite=True)
        for folder in (out, *(out / s for s in SPLITS)):  # a killed writer's temporaries, shards' included
            clean_stale_temps(folder)
        state = fresh_state(out)
        try:
            return _write_locked(
                out, cfg, train_draws, val_draws, seed, extra, extra_draws, command, progress, natural_draws
            )
        except InputError:  # refused while writing (a draw that is not finite): a folder it made goes
            discard_fresh(out, state)
            raise


def settings_changed(old: dict, new: dict) -> list[tuple[str, object, object]]:
    """(name, recorded, asked) of each setting of a pair folder's manifest that differs: the manifest's own
    keys and those of its ``config`` (named without the prefix, as their parameters are)."""

    def flat(manifest: dict) -> dict:
        config = manifest.get("config") if isinstance(manifest.get("config"), dict) else {}
        rest = {k: v for k, v in manifest.items() if k not in ("config", "command", "complete")}
        return {**config, **rest}

    was, now = flat(old), flat(new)
    keys = [*now, *(k for k in was if k not in now)]
    return [(k, was.get(k), now.get(k)) for k in keys if was.get(k) != now.get(k)]


def _write_locked(
    out: Path, cfg: PairConfig, train_draws: int, val_draws: int, seed: int,
    extra: dict[str, FrameSource] | None, extra_draws: int, command: str, progress: bool, natural_draws: int,
) -> dict:  # fmt: skip
    from spikenerf.core.progress import bar as progress_bar

    manifest = {
        "config": asdict(cfg),
        "train_draws": train_draws,
        "val_draws": val_draws,
        "seed": seed,
        "extra_sources": sorted(extra or {}),
        "extra_draws": extra_draws,
        "val_scenes": val_scenes(val_draws, seed, natural_draws > 0),
    }
    if natural_draws > 0:  # only then, so that folders made before photographs existed still resume
        manifest.update(natural_draws=natural_draws, natural_train=list(NATURAL_TRAIN))
    path = out / MANIFEST
    if path.is_file():
        # val_scenes follows from the settings compared (and older folders of fewer than 4 val draws listed
        # photographs that they never drew: such a folder still resumes, its manifest corrected)
        old = {k: v for k, v in read_manifest(out).items() if k not in DERIVED}
        new = {k: v for k, v in json.loads(json.dumps(manifest)).items() if k not in DERIVED}
        if {k: old.get(k) for k in new} != new:
            changed = settings_changed(old, new)
            named = ", ".join(f"{name} {was!r} → {now!r}" for name, was, now in changed) or "its manifest"
            raise InputError(
                f"out holds pairs made with other settings ({named}): give the same ones to finish it, or "
                "use a new folder",
                path=out,
                param=("out", *(name for name, _, _ in changed)),
            )
    mark(out, "pairs")
    write_text_atomic(path, json.dumps({**manifest, "command": command}, indent=2))
    counters = dict.fromkeys(SPLITS, 0)
    jobs = plan(cfg, train_draws, val_draws, seed, extra or {}, extra_draws, natural_draws)
    total = sum(-(-n // DRAWS_PER_SHARD) for _, _, n in jobs)
    with progress_bar(total=total, unit="shard", desc="recon pairs", show=progress) as bar:
        for split, draw, count in jobs:
            for start in range(0, count, DRAWS_PER_SHARD):
                target = shard_path(out, split, counters[split])
                counters[split] += 1
                if not shard_ok(target, cfg.window, cfg.size):  # missing, or damaged: written again
                    with np.errstate(over="ignore", invalid="ignore"):  # (refused below, not warned about)
                        samples = list(draw(range(start, min(start + DRAWS_PER_SHARD, count))))
                    if bad := next((s for s in samples if not np.isfinite(s.target).all()), None):
                        raise InputError(
                            f"a {split} draw ({bad.info.get('scene', '?')}) has targets that are not finite "
                            "(its radiance scaled and divided by φ overflows float32): lower brightness or "
                            "raise threshold",
                            path=out,
                            param=("brightness", "threshold"),
                        )
                    if samples:
                        write_shard(target, samples)
                bar.update(1)
    manifest["complete"] = True  # every shard written: recon-train refuses a folder without it
    write_text_atomic(path, json.dumps({**manifest, "command": command}, indent=2))
    return manifest
