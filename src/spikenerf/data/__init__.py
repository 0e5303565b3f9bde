"""Dataset folder I/O, rays, training targets and samplers (simulating a dataset: ``spikenerf.capture``).

Public names: ``spikenerf.core.exports.PUBLIC_API`` (imported on first use)."""

from spikenerf.core.exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__)
