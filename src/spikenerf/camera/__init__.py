"""The spike camera: integrate-and-fire model, noise, .dat I/O, reconstruction (TFP/TFI) and spike masks.

Public names: ``spikenerf.core.exports.PUBLIC_API`` (imported on first use)."""

from spikenerf.core.exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__)
