"""Evaluation: image metrics and metrics.json (LPIPS: ``spikenerf.eval.lpips.lpips``)."""

from spikenerf.core.exports import lazy_exports

#: public name -> defining module (imported on first use)
_EXPORTS = {
    "psnr": "spikenerf.eval.metrics",
    "ssim": "spikenerf.eval.metrics",
    "evaluate_run": "spikenerf.eval.evaluate",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
