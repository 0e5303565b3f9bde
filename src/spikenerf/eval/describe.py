"""The lines that describe an evaluation, written once: what ``eval`` prints when it finishes and what
``info RUN`` prints of the ``metrics.json`` (or ``metrics_train.json``) it left (docs/metrics.md).

Each function takes the evaluation's result as ``eval`` returns it and ``metrics.json`` stores it (a dict:
``split``, ``views``, ``view_poses``, ``mean``, ``test_pose_optimised``, ``no_reference``, ...)."""

from __future__ import annotations

import json
from pathlib import Path

from spikenerf.core.errors import InputError, is_integer


def number(value: float | None, digits: int) -> str:
    """``value`` to ``digits`` decimals, or ``n/a`` for None (a metric that could not run)."""
    return "n/a" if value is None else f"{value:.{digits}f}"


def scores(mean: dict) -> str:
    """``PSNR 24.01 dB, SSIM 0.8123, LPIPS 0.1234`` of a ``mean`` (or per-view) section."""
    psnr = mean.get("psnr")
    return (
        f"PSNR {number(psnr, 2)}{'' if psnr is None else ' dB'}, SSIM {number(mean.get('ssim'), 4)}, "
        f"LPIPS {number(mean.get('lpips'), 4)}"
    )


def pose_fit_line(result: dict) -> str | None:
    """The test-pose-optimised scores (``eval --test-pose-opt``), or None where eval did not fit poses."""
    opt = result.get("test_pose_optimised")
    if not opt:
        return None
    m, split = opt["mean"], result.get("split", "test")
    return (
        f"test-pose-optimised ({opt['steps']} steps, each {split} pose fitted to its own image, field "
        "frozen): "
        f"{scores(m)}; mean correction {number(m.get('rotation_deg'), 3)}°, "
        f"{number(m.get('translation'), 4)} scene units; {opt['fits_kept']} of {len(opt['per_view'])} fits "
        "kept (a fit that scores lower is not)"
    )


def noref_line(result: dict) -> str | None:
    """The no-reference checks (``eval --noref``): where they were scored (held out or trained on), the
    masked scores against the reconstructions, the interval violations in units of the threshold φ and the
    PIQE image score (where metrics.json has it); None where eval did not run them."""
    nr = result.get("no_reference")
    if not isinstance(nr, dict) or not isinstance(nr.get("mean"), dict):
        return None
    m = nr["mean"]
    steps = nr.get("per_step")
    at = f" at {len(steps)} check steps" if isinstance(steps, list) else ""
    seen = (
        " (trained on: they measure fit, not generalisation)" if nr.get("steps_trained_on") else " (held out)"
    )
    if not nr.get("steps_trained_on") and nr.get("windows_in_guard") is False:
        seen = (
            f" (held out, but their {nr.get('spike_window')}-step spike windows reach past ±"
            f"{nr.get('guard_radius')} into trained steps)"
        )
    line = (
        f"no-reference{at}{seen}: masked PSNR {number(m.get('masked_psnr'), 2)} dB, masked SSIM "
        f"{number(m.get('masked_ssim'), 4)} vs the reconstructions; interval violations "
        f"{number(m.get('interval_violation_rate'), 4)} of windows, mean "
        f"{number(m.get('interval_violation_mean'), 4)} φ (reconstruction held: "
        f"{number(m.get('recon_interval_violation_rate'), 4)})"
    )
    if "piqe_render" in m:  # (metrics.json written before PIQE has no such key)
        line += (
            f"; PIQE {number(m.get('piqe_render'), 1)} (reconstruction: {number(m.get('piqe_recon'), 1)}; "
            "0-100, higher is worse)"
        )
    return line


def per_view(result: dict) -> str:
    """How each view was scored: ", each against the mean of S renders" where eval averaged S > 1 poses
    (``view_poses``; absent in metrics written before it was recorded)."""
    poses = result.get("view_poses") or 1
    return f", each against the mean of {poses} renders" if poses > 1 else ""


def metrics_lines(path: Path, done: int) -> list[str]:
    """``info``'s lines of the metrics file at ``path`` of a run that has trained ``done`` iterations: its
    scores, marked stale where they are of an earlier iteration, the pose-fitted scores and the no-reference
    checks. InputError naming the file when it is unreadable or malformed."""
    try:
        text = path.read_text()
    except OSError as err:
        raise InputError(f"cannot read it ({err.strerror or err})", path=path) from err
    except UnicodeDecodeError as err:
        raise InputError(
            f"malformed metrics (not text: {err}); run eval again to rewrite it", path=path
        ) from err
    try:
        result = json.loads(text)
        if not isinstance(result, dict):
            raise TypeError(f"expected a JSON object, found {type(result).__name__}")
        if not (is_integer(result["views"]) and result["views"] >= 0):
            raise TypeError(f"views is {json.dumps(result['views']):.40}, not a count")
        views = f"{result['views']} view{'' if result['views'] == 1 else 's'}"
        scored = f"{path.name} ({result['split']}, {views}{per_view(result)})"
        if isinstance(scored_at := result.get("iterations"), int) and scored_at < done:
            scored += f" [of iteration {scored_at}, not {done}: run eval again]"
        lines = [f"{scored}: {scores(result['mean'])}"] if result["views"] else []  # (0: the checks alone)
        own = "" if path.name == "metrics.json" else f"{path.name}: "  # eval --split train's file
        lines += [own + line for line in (pose_fit_line(result), noref_line(result)) if line]
    except KeyError as err:
        raise InputError(f"malformed metrics: no {err}; run eval again to rewrite it", path=path) from err
    except (ValueError, TypeError, AttributeError, OverflowError, RecursionError) as err:
        raise InputError(f"malformed metrics ({err}); run eval again to rewrite it", path=path) from err
    return lines
