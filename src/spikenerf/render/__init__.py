"""Renderers: volume rendering of the fields and the spiking volume renderer.

Public names: ``spikenerf.core.exports.PUBLIC_API`` (imported on first use, so that the CLI reads the
inference precisions of ``render.choices`` without importing torch)."""

from spikenerf.core.exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__)
