"""Evaluation: image metrics and metrics.json (LPIPS: ``spikenerf.eval.lpips.lpips``).

Public names: ``spikenerf.core.exports.PUBLIC_API`` (imported on first use)."""

from spikenerf.core.exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__)
