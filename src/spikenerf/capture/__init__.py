"""Making a dataset by simulation: a scene filmed by a virtual spike camera (and a conventional blur camera)
into a dataset folder (``spikenerf simulate``), optionally with a raw camera-style recording.

Public names: ``spikenerf.core.exports.PUBLIC_API`` (imported on first use)."""

from spikenerf.core.exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__)
