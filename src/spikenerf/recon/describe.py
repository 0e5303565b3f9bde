"""``spikenerf info`` of a ``recon-data`` pair folder and of a ``recon-train`` folder: what they hold, how far
they got, and how to go on. Each reads only the small JSON/CSV files those commands write; a damaged one is
an InputError naming it."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

from spikenerf.core.errors import InputError, is_integer
from spikenerf.recon.store import MANIFEST, SPLITS, read_manifest


def describe_pairs(root: str | Path) -> str:
    """The summary lines of a pair folder: its pair size and window, colour modes and noises, the draws and
    shards written so far, the held-out scenes, whether it is finished, and the command that wrote it."""
    root = Path(root)
    manifest = read_manifest(root)
    config = manifest["config"]
    shards = {split: len(list((root / split).glob("shard-*.npz"))) for split in SPLITS}
    modes, noises = config.get("modes", []), config.get("noises", [])
    for key, value in (("config.noises", noises), ("val_scenes", manifest.get("val_scenes", []))):
        if not isinstance(value, list):  # (a list in what recon-data writes: shown joined)
            problem = f"{key} must be a list, found {json.dumps(value):.40}"
            raise InputError(f"malformed {MANIFEST}: {problem}", path=root / MANIFEST)
    lines = [
        f"recon-data pair folder: {config['size']}×{config['size']} pairs of a {config['window']}-step "
        f"window; colour {', '.join(map(str, modes))}; noise {', '.join(map(str, noises))}",
        f"draws: {manifest.get('train_draws', '?')} training{_added(manifest)} ({_files(shards['train'])}), "
        f"{manifest.get('val_draws', '?')} held-out ({_files(shards['val'])})",
    ]
    if scenes := manifest.get("val_scenes"):
        lines.append(f"held-out scenes: {', '.join(map(str, scenes))}")
    if manifest.get("complete") is True:
        lines.append(f"finished: train a reconstructor on it with `spikenerf recon-train {root} --out RUN`")
    else:
        lines.append("unfinished: run its command again to complete it (the written shards are kept)")
    if command := manifest.get("command"):
        lines.append(f"command: {command}")
    return "\n".join(lines)


def describe_recon(root: str | Path) -> str:
    """The summary lines of a recon-train folder: its settings, the last row of its curves (iteration,
    held-out PSNR of the network and of TFP), and whether it has written its weights (and how to use them)."""
    root = Path(root)
    config = _json(root / "config.json").get("config")
    config = config if isinstance(config, dict) else {}
    got = {key: config.get(key, "?") for key in ("iters", "batch", "crop", "width", "lr")}
    lines = [
        f"recon-train folder: {got['iters']} iterations of {got['batch']} crops of {got['crop']} px, width "
        f"{got['width']}, learning rate {got['lr']}"
    ]
    if (last := _last_curve_row(root / "curves.csv")) is not None:
        learned, tfp = last.get("val_psnr_learned"), last.get("val_psnr_tfp")
        held = f"; held-out PSNR learned {learned} dB, TFP {tfp} dB" if learned and tfp else ""
        lines.append(
            f"curves: iteration {last.get('iteration', '?')}, train L1 {last.get('train_l1', '?')}{held}"
        )
    weights = root / "weights.pt"
    summary = _json(root / "weights.json") if weights.is_file() else {}
    done = summary.get("config", {}).get("iters") if isinstance(summary.get("config"), dict) else None
    if weights.is_file() and is_integer(done) and is_integer(got["iters"]) and done < got["iters"]:
        # a finished run resumed with more --iters and stopped before its end: its weights.pt is the
        # earlier run's, not this one's
        lines.append(
            f"unfinished: continued to {got['iters']} iterations; run its command again to resume from its "
            f"last checkpoint (weights.pt is the earlier run's, of {done} iterations)"
        )
    elif weights.is_file():
        if "val_psnr_learned" in summary:
            learned, tfp = summary["val_psnr_learned"], summary.get("val_psnr_tfp")
            lines.append(
                f"finished in {summary.get('seconds', '?')} s: on all held-out pairs PSNR learned {learned} "
                f"dB, TFP {tfp} dB"
            )
        lines.append(f"use it: spikenerf reconstruct REC.dat --method learned --weights {weights}")
    else:
        lines.append("unfinished: run its command again to resume from its last checkpoint")
    if command := _json(root / "config.json").get("command"):
        lines.append(f"command: {command}")
    return "\n".join(lines)


def _added(manifest: dict) -> str:
    """`` + N from photographs`` and `` + N from each of SOURCES``: the train draws beyond the random ones
    (``--natural``, ``--scene``/``--sequence``), "" when there are none."""
    added = ""
    if isinstance(natural := manifest.get("natural_draws"), int) and natural > 0:
        added += f" + {natural} from photographs"
    sources, each = manifest.get("extra_sources"), manifest.get("extra_draws")
    if isinstance(sources, list) and sources and isinstance(each, int) and each > 0:
        added += f" + {each} from each of {', '.join(map(str, sources))}"
    return added


def _files(count: int) -> str:
    return f"{count} shard file{'' if count == 1 else 's'}"


def _json(path: Path) -> dict[str, Any]:
    """A JSON object file ({} when missing); InputError naming it when it is not one."""
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as err:  # (nested beyond the stack)
        raise InputError(f"malformed JSON ({type(err).__name__})", path=path) from err
    if not isinstance(data, dict):
        raise InputError("malformed JSON (not an object)", path=path)
    return data


def _last_curve_row(path: Path) -> dict[str, str] | None:
    """The last row of a curves.csv as {column: text}; None when there is none (or the file is unreadable:
    the trainer's resume names a damaged one)."""
    try:
        with path.open(newline="", encoding="utf-8") as f:
            rows = list(csv.DictReader(f))
    except (OSError, UnicodeDecodeError, csv.Error):
        return None
    return rows[-1] if rows else None
