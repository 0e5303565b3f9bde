"""``recon-train``: train the reconstructor on a pair folder, resumable, with curves and a final weights file.

Run folder: ``config.json`` (settings + command), ``checkpoint.pt`` (atomic, ``weights_only``: model, Adam,
the sampling generator, iteration), ``curves.csv`` (iteration, train L1, val PSNR of learned and of TFP over
the same window, seconds) and, at the end, ``weights.pt`` (fp16, the shipped format) with ``weights.json``
(how it was made). The starting weights follow the seed, and every later random choice comes from one
``torch.Generator`` of it saved in the checkpoint, so a run is reproducible from its seed and a resumed run
is bit-identical to an uninterrupted one (same thread count).
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from dataclasses import asdict
from pathlib import Path

import torch

from spikenerf.core.atomic import clean_stale_temps, write_text_atomic
from spikenerf.core.csvtable import read_table
from spikenerf.core.errors import InputError, is_finite, is_integer, is_number
from spikenerf.core.limits import check_resources
from spikenerf.core.lock import output_lock
from spikenerf.core.marker import check_output, mark, owned
from spikenerf.core.psnr import mse_to_psnr
from spikenerf.core.replacement import discard_fresh, fresh_state
from spikenerf.recon.config import ReconTrainConfig
from spikenerf.recon.features import brightness_scale, feature_count
from spikenerf.recon.net import NetConfig, ReconNet, read_torch, save_torch, save_weights
from spikenerf.recon.store import PairSet, load_split, read_manifest

CHECKPOINT_FORMAT = "spikenerf-recon-checkpoint-1"
CURVES_HEADER = ["iteration", "train_l1", "val_psnr_learned", "val_psnr_tfp", "seconds"]


def train_memory(cfg: ReconTrainConfig, window: int, size: int) -> float:
    """Estimated peak bytes of a training step on pairs of ``window`` K steps and ``size`` P pixels a side:
    the unpacked batch (B·K·P², uint8 bits then float32), the crops' activations and their gradients (about
    32 maps of ``width`` channels at crop size per sample, in float32), the features, the network's weights
    with gradients and Adam's moments (about 900·width² values), and a validation pass at full size."""
    crop, w = min(cfg.crop, size), cfg.width
    batch = cfg.batch * window * size * size * 6.0
    maps = cfg.batch * crop * crop * 4.0 * (32 * w + feature_count(window) + window)
    weights = 900.0 * w * w * 4 * 4
    val = min(cfg.val_samples, 32) * size * size * 4.0 * 16 * w
    return batch + maps + weights + val


def learning_rate(cfg: ReconTrainConfig, it: int) -> float:
    """Cosine decay from ``lr`` to ``0.05·lr`` over ``iters`` steps (a function of the step only)."""
    return cfg.lr * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(it, cfg.iters) / cfg.iters)))


def sample_batch(pairs: PairSet, cfg: ReconTrainConfig, gen: torch.Generator) -> tuple[torch.Tensor, ...]:
    """A random batch: windows (B, K, c, c), targets (B, c, c), scales (B,) of whole samples; random crops,
    flips and 90° rotations (applied to spikes and target alike)."""
    index = torch.randint(len(pairs), (cfg.batch,), generator=gen)
    win, tgt = pairs.windows(index), pairs.targets[index]
    scale = brightness_scale(win)
    size = tgt.shape[-1]
    c = min(cfg.crop, size)
    ys, xs = torch.randint(size - c + 1, (2, cfg.batch), generator=gen)
    ops = torch.randint(8, (cfg.batch,), generator=gen)
    wins, tgts = [], []
    for b in range(cfg.batch):
        y, x, op = int(ys[b]), int(xs[b]), int(ops[b])
        w, t = win[b, :, y : y + c, x : x + c], tgt[b, y : y + c, x : x + c]
        if op & 4:
            w, t = w.flip(-1), t.flip(-1)
        wins.append(torch.rot90(w, op & 3, (-2, -1)))
        tgts.append(torch.rot90(t, op & 3, (-2, -1)))
    return torch.stack(wins), torch.stack(tgts), scale


def rate_psnr(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Per-image PSNR (dB) of rates clipped to [0, 1], peak 1: (N, H, W) → (N,) float64."""
    mse = ((pred.clamp(0, 1) - target.clamp(0, 1)) ** 2).flatten(1).mean(1)
    return mse_to_psnr(mse.clamp_min(1e-10))


@torch.no_grad()
def validate(net: ReconNet, pairs: PairSet, count: int) -> tuple[float, float]:
    """Mean PSNR of the learned and the TFP (same window) rates on the first ``count`` val samples."""
    scores, base = [], []
    for a in range(0, min(count, len(pairs)), 32):
        index = torch.arange(a, min(a + 32, count, len(pairs)))
        win, tgt = pairs.windows(index), pairs.targets[index]
        scores.append(rate_psnr(net(win, brightness_scale(win)), tgt))
        base.append(rate_psnr(win.mean(1), tgt))
    return float(torch.cat(scores).mean()), float(torch.cat(base).mean())


def train_recon(
    pairs_dir: str | Path,
    out: str | Path,
    cfg: ReconTrainConfig,
    command: str = "",
    progress: bool | None = None,
    stop_at: int | None = None,
) -> dict:
    """Train (or resume) a reconstructor into ``out``; returns the summary (also in ``weights.json``).

    ``progress``: a progress bar (None: only on a terminal). ``stop_at`` ends the run after that many steps
    without the final export (an interruption, for tests). A folder this call created is removed again when
    the run fails before it wrote a checkpoint (a refusal, a diverged run): nothing is left to resume.
    """
    cfg.check()
    out = Path(out)
    check_output(out, "recon", overwrite=True)
    with output_lock(out):
        check_output(out, "recon", overwrite=True)
        if owned(out):  # a folder of ours (one recognised by its files alone may be a user's)
            clean_stale_temps(out)
        state = fresh_state(out)
        try:
            return _train_locked(pairs_dir, out, cfg, command, progress, stop_at)
        except Exception:
            if not (out / "checkpoint.pt").exists():
                discard_fresh(out, state)
            raise


def _train_locked(
    pairs_dir: str | Path,
    out: Path,
    cfg: ReconTrainConfig,
    command: str,
    progress: bool | None,
    stop_at: int | None,
) -> dict:
    from spikenerf.core.progress import bar as progress_bar

    manifest = read_manifest(pairs_dir)
    if manifest.get("complete") is not True:
        raise InputError(
            "unfinished pair folder (recon-data stopped before its last shard): run the recon-data command "
            "in its manifest.json again to finish it",
            path=pairs_dir,
        )
    train, val = load_split(pairs_dir, "train", manifest), load_split(pairs_dir, "val", manifest)
    memory = train_memory(cfg, train.window, int(train.targets.shape[-1]))
    check_resources(memory, 0.0, out, "batch/crop/width")  # before anything is written
    with torch.random.fork_rng(devices=[]):  # the starting weights follow --seed; the global RNG is kept
        torch.manual_seed(cfg.seed)
        net = ReconNet(NetConfig(window=train.window, width=cfg.width))
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    gen = torch.Generator().manual_seed(cfg.seed)
    pairs_hash = _pairs_hash(manifest)
    legacy = {k: v for k, v in manifest.items() if k != "complete"}  # what checkpoints before it hashed
    legacy_hash = hashlib.sha256(json.dumps(legacy, sort_keys=True).encode()).hexdigest()
    start, elapsed, running = _resume(out, cfg, net, opt, gen, (pairs_hash, legacy_hash))
    rows = _curves(out, start)  # before anything is written: a garbled one is refused
    mark(out, "recon")
    write_text_atomic(
        out / "config.json",
        json.dumps({"config": asdict(cfg), "pairs": str(pairs_dir), "command": command}, indent=2),
    )
    t0, it, end = (
        time.perf_counter() - elapsed,
        start,
        cfg.iters if stop_at is None else min(stop_at, cfg.iters),
    )
    saved = start or None  # the iteration of the folder's checkpoint (None: it has none)
    bar = progress_bar(total=cfg.iters, initial=start, unit="it", desc="recon-train", show=progress)
    while it < end:
        win, tgt, scale = sample_batch(train, cfg, gen)
        for group in opt.param_groups:
            group["lr"] = learning_rate(cfg, it)
        loss = ((net(win, scale) - tgt) / scale.view(-1, 1, 1)).abs().mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        it += 1
        value = float(loss.detach())
        if not math.isfinite(value):  # diverged: nothing of it is saved (the last checkpoint stays)
            bar.close()  # its last line ends before the error's
            raise _diverged(out, value, it, saved)
        running = value if math.isnan(running) else 0.95 * running + 0.05 * value
        bar.update(1)
        bar.set_postfix(l1=f"{running:.4f}")
        if it % cfg.eval_every == 0 or it == cfg.iters:
            learned, tfp = validate(net.eval(), val, cfg.val_samples)
            net.train()
            rows.append(
                [it, f"{running:.5f}", f"{learned:.3f}", f"{tfp:.3f}", f"{time.perf_counter() - t0:.1f}"]
            )
            _write_curves(out, rows)
            bar.write(f"iter {it}: val PSNR learned {learned:.2f} dB, TFP {tfp:.2f} dB")
        if it % cfg.ckpt_every == 0 or it == end:
            save_torch(
                out / "checkpoint.pt",
                {
                    "format": CHECKPOINT_FORMAT,
                    "iteration": it,
                    "elapsed": time.perf_counter() - t0,
                    "model": net.state_dict(),
                    "optimizer": opt.state_dict(),
                    "rng": gen.get_state(),
                    "config": asdict(cfg),
                    "pairs": pairs_hash,  # the pair folder's manifest: a resume on other pairs is refused
                    "running_l1": running,  # the curve's running L1 continues as without the interruption
                },
            )
            saved = it
    bar.close()
    if it < cfg.iters:
        return {"iteration": it}
    learned, tfp = validate(net.eval(), val, len(val))
    summary = {
        "command": command,
        "pairs": manifest,
        "train_samples": len(train),
        "val_samples": len(val),
        "config": asdict(cfg),
        "seconds": round(time.perf_counter() - t0, 1),
        "val_psnr_learned": round(learned, 3),
        "val_psnr_tfp": round(tfp, 3),
        "threads": torch.get_num_threads(),
    }
    save_weights(out / "weights.pt", net, list(manifest["config"]["modes"]), summary)
    write_text_atomic(out / "weights.json", json.dumps(summary, indent=2))
    return summary


def _diverged(out: Path, value: float, it: int, saved: int | None) -> InputError:
    """The error of a run whose loss became ``value`` (not finite) at step ``it``, saying how to go on.

    ``saved``: the iteration of the folder's checkpoint. It resumes only with the same settings (and would
    diverge again), so a lower rate needs a new folder. Without one the folder holds nothing to resume
    (:func:`train_recon` removes a folder it created), so the same command with a lower rate serves.
    """
    head = f"the training loss is {value} at iteration {it}: the run diverged"
    if saved is None:
        return InputError(
            f"{head}; lower lr and train again (it wrote no checkpoint: nothing is kept)",
            path=out,
            param="lr",
        )
    return InputError(
        f"{head}; lower lr and train again into a new out folder, or delete this one (its checkpoint of "
        f"iteration {saved} resumes only with the same settings)",
        path=out,
        param=("lr", "out"),
    )


def _pairs_hash(manifest: dict) -> str:
    """The pair folder's identity for a resume: its manifest without the command line that wrote it (which
    global flags such as ``--threads`` change) and without its completion flag."""
    same = {k: v for k, v in manifest.items() if k not in ("command", "complete")}
    return hashlib.sha256(json.dumps(same, sort_keys=True).encode()).hexdigest()


def _resume(
    out: Path, cfg: ReconTrainConfig, net: ReconNet, opt, gen: torch.Generator, pairs: tuple[str, str]
) -> tuple[int, float, float]:
    """Load ``out/checkpoint.pt`` if present; returns (iteration, elapsed seconds, running L1). ``pairs``:
    the pair folder's hash (:func:`_pairs_hash`) and the one checkpoints before it stored."""
    if not (out / "checkpoint.pt").is_file():
        return 0, 0.0, float("nan")
    data = read_torch(out / "checkpoint.pt", "checkpoint", CHECKPOINT_FORMAT)
    it, elapsed, running = (
        data.get("iteration", 0),
        data.get("elapsed", 0.0),
        data.get("running_l1", math.nan),
    )
    if not (
        is_integer(it) and it >= 0 and is_finite(elapsed) and elapsed >= 0
        and (is_finite(running) or (is_number(running) and running != running))  # (NaN: no step yet)
    ):  # fmt: skip
        found = f"iteration {it!r:.40}, elapsed {elapsed!r:.40}, running_l1 {running!r:.40}"
        raise InputError(f"malformed checkpoint ({found})", path=out / "checkpoint.pt")
    if not isinstance(data.get("pairs", pairs[0]), str) or data.get("pairs", pairs[0]) not in pairs:
        raise InputError(
            "out holds a run trained on another pair folder (its manifest differs)", path=out, param="out"
        )
    if it > cfg.iters:
        raise InputError(
            f"out holds a run of {it} iterations, more than iters {cfg.iters}; pass "
            "at least that many, or use a new folder",
            path=out,
            param=("out", "iters"),
        )
    stored = data.get("config", {})
    stored = stored if isinstance(stored, dict) else {}
    now = asdict(cfg)
    changed = [
        k
        for k in (*now, *(k for k in stored if k not in now))
        if k != "iters" and stored.get(k) != now.get(k)
    ]
    if changed:
        named = ", ".join(f"{k} {stored.get(k)!r} → {now.get(k)!r}" for k in changed)
        raise InputError(
            f"out holds a run with other settings ({named}): give the same ones to resume it (only iters "
            "may change), or use a new folder",
            path=out,
            param=("out", *changed, "iters"),
        )
    if not all(isinstance(data.get(key), dict) for key in ("model", "optimizer")):
        raise InputError("checkpoint does not fit this reconstructor (no model or optimizer state)", path=out)
    try:
        net.load_state_dict(data["model"])
        opt.load_state_dict(data["optimizer"])
        gen.set_state(data["rng"])
    except (KeyError, RuntimeError, ValueError, TypeError, OverflowError) as err:  # (an Adam step of 10**400)
        raise InputError(
            f"checkpoint does not fit this reconstructor ({type(err).__name__})", path=out
        ) from err
    return int(it), float(elapsed), float(running)


def _curves(out: Path, start: int) -> list[list]:
    """Curve rows up to the resumed iteration (later rows came after the checkpoint and are redone); none
    for a run that starts afresh, or from a file of zero bytes (what a crash may leave). InputError naming
    the file when it is not such a table (as ``train --resume`` treats its curves.csv): a header that is
    not :data:`CURVES_HEADER`, a row that is not numbers, bytes that are not text."""
    path = out / "curves.csv"
    if not path.is_file() or start == 0 or path.stat().st_size == 0:
        return []

    def header_problem(header: list[str]) -> str | None:
        if header == CURVES_HEADER:
            return None
        return f"its header is {','.join(header)!r}, expected {','.join(CURVES_HEADER)!r}"

    aside = "move it aside to resume without the earlier curve points"
    rows = read_table(path, "curve table of recon-train", header_problem, lambda _, row: _numbers(row), aside)
    return [row for row in rows if int(row[0]) <= start]


def _numbers(row: list[str]) -> list[str]:
    """``row`` (kept as written) when it is a curve row: an integer iteration and numbers; else ValueError."""
    if len(row) != len(CURVES_HEADER):
        raise ValueError(f"{len(row)} values, expected {len(CURVES_HEADER)}")
    int(row[0])
    for value in row[1:]:
        float(value)
    return row


def _write_curves(out: Path, rows: list[list]) -> None:
    text = ",".join(CURVES_HEADER) + "\n" + "".join(",".join(str(v) for v in r) + "\n" for r in rows)
    write_text_atomic(out / "curves.csv", text)
