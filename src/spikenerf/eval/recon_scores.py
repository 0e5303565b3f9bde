"""Score spike-to-image reconstructions (TFP, TFI, TFSTP, learned) against a simulated dataset's sharp GT
frames.

``spikenerf recon-eval DATASET``: each selected ``gt/`` step is reconstructed from the dataset's own stream by
each method (:func:`spikenerf.data.reconstruction.reconstructor`, the one dispatch) and compared with the GT
render of that step as ``eval`` compares a render (docs/metrics.md): display values, linear radiance →
sRGB-encoded [0, 1]; a gray stream against the gray of the linear GT; PSNR, SSIM (mip-NeRF) and LPIPS when its
weights are installed. Beside them the mean and largest absolute error in linear units (the reconstruction
clipped to [0, 1], as the GT is stored). A Bayer stream is scored as its one-channel RGGB mosaic against the
GT sampled through the same filter array. Means are plain averages over the steps.

Each method reconstructs all the selected GT frames in one call
(:func:`spikenerf.data.reconstruction.frames_reconstructor`: TFSTP scans the stream from frame 0 once, not
once per frame; TFP and TFI read each run of nearby frames once; learned a window per frame), holding those
frames only; a method's ``seconds`` are that call plus its scoring.
"""

from __future__ import annotations

import csv
import io
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from spikenerf.camera.bayer import bayer_mosaic
from spikenerf.camera.frame_range import resolve_frames
from spikenerf.camera.io import read_dat
from spikenerf.camera.layout import to_camera_layout, to_channels_last
from spikenerf.camera.reconstruct import DEFAULT_WINDOW, check_window
from spikenerf.core.atomic import atomic_path
from spikenerf.core.errors import InputError, as_path, check_choice, comma_list
from spikenerf.core.progress import bar as progress_bar
from spikenerf.data.dataset import SpikeDataset, load_dataset, spike_files
from spikenerf.data.reconstruction import RECONS, frames_reconstructor
from spikenerf.eval.evaluate import SPACE, display, lpips_status, score_view
from spikenerf.eval.metrics import mean_or_none

#: what ``recon-eval`` writes into its output folder
SCORES_JSON, SCORES_CSV = "scores.json", "scores.csv"
#: the per-step metrics, in the order of the CSV columns and the table
METRICS = ("psnr", "ssim", "lpips", "mae", "max_error")


def parse_methods(methods: str | list[str] | tuple[str, ...]) -> list[str]:
    """``"tfp,learned"`` or a list → the method names, each one of ``RECONS``; InputError naming
    ``methods``."""
    spec = methods if isinstance(methods, str) else ",".join(map(str, methods))
    known = ", ".join(RECONS)
    return comma_list(
        spec, RECONS, lambda bad: f"methods: expected names among {known}, found {', '.join(bad) or 'none'}",
        param="methods",
    )  # fmt: skip


def gt_indices(dataset: SpikeDataset) -> np.ndarray:
    """Stream indices (N,) int64 of the dataset's GT frames (their steps looked up on the trajectory);
    InputError when it has none: an imported recording has no sharp truth to score against."""
    steps = dataset.gt.steps
    if steps is None or len(steps) == 0:
        raise InputError(
            "scoring needs ground truth: the dataset has no sharp gt/ frames (an imported recording has "
            "none: score a simulated dataset, or a run trained on this one with the no-reference checks)",
            path=dataset.root,
        )
    idx = np.searchsorted(dataset.trajectory.steps, steps)
    if not np.array_equal(dataset.trajectory.steps[np.minimum(idx, len(dataset.trajectory) - 1)], steps):
        raise InputError("gt frame steps are not on the trajectory", path=dataset.root)
    return idx.astype(np.int64)


def select_steps(
    indices: np.ndarray, total: int, steps: slice | None = None, count: int | None = None
) -> np.ndarray:
    """Which GT frames (positions into ``indices`` (N,)) to score: those whose stream index lies in ``steps``
    (a slice of the ``total``-step stream; negatives from the end), at most ``count`` of them evenly spread.
    InputError naming ``steps`` when the range holds no GT frame, ``count`` unless it is an integer ≥ 1."""
    chosen = resolve_frames(steps, total, param="steps")
    keep = np.flatnonzero((indices >= chosen.start) & (indices < chosen.stop))
    if len(keep) == 0:
        raise InputError(
            f"steps: {chosen.start}:{chosen.stop} holds none of the dataset's {len(indices)} gt frames "
            f"(at steps {indices[0]}..{indices[-1]})",
            param="steps",
        )
    if count is not None:
        if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 1:
            raise InputError(f"count must be an integer ≥ 1, found {count!r}", param="count")
        if count < len(keep):
            keep = keep[np.unique(np.round(np.linspace(0, len(keep) - 1, count)).astype(np.int64))]
    return keep


def _truth(gt: np.ndarray, color: str) -> np.ndarray:
    """A linear GT (H, W, 3) as the stream of ``color`` sees it: (H, W, 3) rgb or (H, W, 3) for gray
    (``display`` makes it gray), the RGGB mosaic (H, W, 1) for bayer."""
    if color == "bayer":
        return bayer_mosaic(to_camera_layout(gt, frame=True, name="gt"))[..., None]
    return gt


def _errors(recon: torch.Tensor, truth: torch.Tensor) -> dict[str, float]:
    """Mean and largest absolute error of linear (H, W, C) images, the reconstruction clipped to [0, 1]."""
    diff = (recon.double().clamp(0.0, 1.0) - truth.double()).abs()
    return {"mae": float(diff.mean()), "max_error": float(diff.max())}


def score_reconstructions(
    dataset_root: str | Path,
    methods: str | list[str] | tuple[str, ...] = RECONS,
    color: str | None = None,
    window: int | None = None,
    steps: slice | None = None,
    count: int | None = None,
    weights: str | Path | None = None,
    lpips_backbone: str | None = "alex",
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Reconstruct the selected GT steps of a dataset by each method and score them against the GT.

    Args:
        dataset_root: a dataset folder with ``gt/`` frames (simulated).
        methods: names of ``RECONS`` (tfp, tfi, tfstp, learned), a list or a comma-separated string.
        color: the stream to reconstruct (gray, rgb or bayer; one of the dataset's; None = its first).
        window: TFP's window (odd, at most the stream's length; None = 41). TFI and TFSTP have none;
            learned uses the window it was trained on.
        steps, count: which GT steps (see :func:`select_steps`); None = all.
        weights: learned: a weights file (None = the shipped one).
        lpips_backbone: ``alex``, ``vgg`` or None (skip LPIPS).
        progress: show a bar of frames scored; it advances per frame as each is scored, after the
            method's one reconstruction call (which it does not divide).
    Returns:
        ``{"dataset", "color", "threshold", "space", "steps", "lpips_backbone", "lpips_reason",
        "methods": {name: {"window", "seconds", "mean": {metric: value}}}, "rows": [{"method", "step",
        metric: value}]}``; a metric that cannot be computed (LPIPS without its weights or on images under
        its minimum size, SSIM under 11 px) is None, and so is its mean.
    """
    root = as_path(dataset_root, "dataset_root")
    names = parse_methods(methods)
    if window is not None and "tfp" not in names:
        raise InputError("window: sets TFP's window, and tfp is not among the methods", param="window")
    if window is not None:  # a bad value is the parameter's, not the stream's (checked before any reading)
        check_window(window)
    if weights is not None and "learned" not in names:
        raise InputError(
            "weights: apply to the learned method, which is not among the methods", param="weights"
        )
    dataset = load_dataset(root)
    color = dataset.modes[0] if color is None else color
    check_choice(color, dataset.modes, "color", "color (a stream of this dataset)")
    indices = gt_indices(dataset)
    total = len(dataset.trajectory)
    keep = select_steps(indices, total, steps, count)
    if window is not None and window > total:  # (as reconstruct: every window would be the whole stream)
        path = root / spike_files(color)[0]
        raise InputError(
            f"window {window} is longer than the {total}-frame stream", path=path, param="window"
        )
    backbone, reason = lpips_status(lpips_backbone, dataset.intrinsics.height, dataset.intrinsics.width)
    if reason and log and lpips_backbone is not None:
        log(f"spikenerf: warning: LPIPS not computed: {reason}")
    k = dataset.intrinsics
    files = [root / name for name in spike_files(color)]
    planes = [
        (lambda a, b, path=path: read_dat(path, k.height, k.width, slice(a, b))) for path in files
    ]  # one reader per file: rgb's three channels, else one stream
    recons = {}
    for name in names:  # every method checked (weights, window, φ) before any work
        tfp_window = (DEFAULT_WINDOW if window is None else window) if name == "tfp" else None
        if name != "learned":
            recons[name] = (frames_reconstructor(name, tfp_window, dataset.threshold), tfp_window)
            continue
        from spikenerf.recon.net import load_weights

        net = load_weights(weights, color)[0]  # read once: it reconstructs and says its trained window
        learned = frames_reconstructor(name, None, dataset.threshold, weights=net, color=color)
        recons[name] = (learned, int(net.config.window))
    truths = {int(i): display(_truth(dataset.gt.images[i], color), 1 if color != "rgb" else 3) for i in keep}
    linear = {int(i): torch.as_tensor(_truth(dataset.gt.images[i], color), dtype=torch.float32) for i in keep}
    if color == "gray":
        from spikenerf.core.color import rgb_to_gray

        linear = {i: rgb_to_gray(x, channel_axis=-1)[..., None] for i, x in linear.items()}
    frames = np.unique(indices[keep])  # the stream frames to reconstruct, each once, ascending
    at = np.searchsorted(frames, indices[keep])  # GT position → row of the reconstruction
    rows: list[dict[str, Any]] = []
    summary: dict[str, Any] = {}
    bar = progress_bar(total=len(names) * len(keep), unit="frame", desc="recon-eval", show=progress and None)
    with bar:
        for name in names:
            recon, used_window = recons[name]
            start, own = time.perf_counter(), []
            try:  # all the method's frames at once (TFSTP: one scan from frame 0, not one per frame)
                parts = [recon(read, total, frames) for read in planes]
            except InputError as err:  # about the stream (e.g. shorter than the network's window)
                if err.path is not None:
                    raise
                raise InputError(err.message, path=files[0], param=err.params) from None
            for i, row_at in zip(keep, at, strict=True):
                image = np.stack([p[row_at] for p in parts]) if color == "rgb" else parts[0][row_at]
                pred = torch.as_tensor(to_channels_last(image, frame=True), dtype=torch.float32)
                scores = score_view(display(pred, pred.shape[-1]), truths[int(i)], backbone)
                row = {"method": name, "step": int(dataset.gt.steps[i]), **scores,
                       **_errors(pred, linear[int(i)])}  # fmt: skip
                own.append(row)
                bar.update(1)
            del parts
            rows += own
            summary[name] = {
                "window": used_window,
                "seconds": round(time.perf_counter() - start, 3),
                "mean": {m: mean_or_none([r[m] for r in own]) for m in METRICS},
            }
    return {
        "dataset": str(root.resolve()),
        "color": color,
        "threshold": dataset.threshold,
        "space": SPACE,
        "linear_errors": "mean and largest |clip(recon, 0, 1) - GT| in linear units",
        "steps": [int(dataset.gt.steps[i]) for i in keep],
        "lpips_backbone": backbone,
        "lpips_reason": reason,
        "methods": summary,
        "rows": rows,
    }


def scores_csv(result: dict[str, Any]) -> str:
    """The per-step rows as CSV: method, step, then :data:`METRICS` (empty where not computed)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["method", "step", *METRICS])
    for row in result["rows"]:
        writer.writerow(
            [row["method"], row["step"], *("" if row[m] is None else f"{row[m]:.6g}" for m in METRICS)]
        )
    return out.getvalue()


def write_scores(out: str | Path, result: dict[str, Any]) -> list[str]:
    """Write the pair ``scores.csv`` + ``scores.json`` into the folder ``out``; returns their names.

    Both are written to temporaries first; then the old ``scores.json`` is removed, the CSV renamed into
    place and the JSON last, as the commit: at every moment a ``scores.json`` in ``out`` belongs with the
    ``scores.csv`` beside it, and an interruption leaves at worst a CSV without its JSON
    (:func:`read_scores` refuses it; ``recon-eval`` writes it again)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_path(out / SCORES_JSON) as json_tmp:
        json_tmp.write_text(json.dumps(result, indent=1, allow_nan=False) + "\n", encoding="utf-8")
        with atomic_path(out / SCORES_CSV) as csv_tmp:
            csv_tmp.write_text(scores_csv(result), encoding="utf-8")
            (out / SCORES_JSON).unlink(missing_ok=True)  # (the old pair is no longer committed)
    return [SCORES_CSV, SCORES_JSON]


def pair_problem(out: str | Path) -> str:
    """Why the ``scores.json`` + ``scores.csv`` pair in the folder ``out`` is not a finished, matching pair
    ("" when it is; "absent" when neither file is there): a CSV without its JSON (an interrupted write), a
    JSON without its CSV, an unreadable JSON, or a CSV that is not the JSON's rows."""
    out = Path(out)
    has_json, has_csv = (out / SCORES_JSON).is_file(), (out / SCORES_CSV).is_file()
    if not (has_json or has_csv):
        return "absent"
    if not has_json:
        return f"{SCORES_CSV} has no {SCORES_JSON} beside it (an interrupted recon-eval)"
    if not has_csv:
        return f"{SCORES_JSON} has no {SCORES_CSV} beside it"
    try:
        result = json.loads((out / SCORES_JSON).read_text(encoding="utf-8"))
        expected = scores_csv(result)
    except (OSError, ValueError, TypeError, KeyError, RecursionError) as err:
        return f"{SCORES_JSON} is unreadable ({type(err).__name__})"
    if (out / SCORES_CSV).read_bytes() != expected.encode("utf-8"):
        return f"{SCORES_CSV} does not hold the rows of {SCORES_JSON} beside it (a mismatched pair)"
    return ""


def read_scores(out: str | Path) -> dict[str, Any]:
    """The result :func:`write_scores` wrote into the folder ``out`` (``scores.json``'s content), checked
    against ``scores.csv``. InputError naming ``out`` for a missing, unfinished or mismatched pair."""
    problem = pair_problem(out)
    if problem:
        what = f"no {SCORES_JSON}" if problem == "absent" else problem
        raise InputError(f"recon-eval scores: {what}; run recon-eval into it again", path=out)
    return json.loads((Path(out) / SCORES_JSON).read_text(encoding="utf-8"))


def _cell(value: float | None, digits: int) -> str:
    return "not computed" if value is None else f"{value:.{digits}f}"


def scores_table(result: dict[str, Any]) -> list[str]:
    """The per-method table (mean PSNR dB, SSIM, LPIPS, linear MAE and largest error) as aligned lines."""
    header = ["method", "window", "PSNR (dB)", "SSIM", "LPIPS", "MAE (linear)", "max error", "seconds"]
    digits = {"psnr": 2, "ssim": 4, "lpips": 4, "mae": 4, "max_error": 4}
    body = [
        [name, "-" if s["window"] is None else str(s["window"]),
         *(_cell(s["mean"][m], digits[m]) for m in METRICS), f"{s['seconds']:.2f}"]
        for name, s in result["methods"].items()
    ]  # fmt: skip
    widths = [max(len(r[c]) for r in [header, *body]) for c in range(len(header))]
    return [
        "  ".join(cell.ljust(w) for cell, w in zip(r, widths, strict=True)).rstrip() for r in [header, *body]
    ]
