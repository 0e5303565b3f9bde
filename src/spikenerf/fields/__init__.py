"""Radiance fields: the fast grid field (TensoRF-VM) and the vanilla NeRF MLP.

``choices`` (the field kinds, no torch import), ``registry`` (one :class:`FieldEntry` per kind: its config,
its class, the memory estimates), ``grid`` and ``mlp`` (the fields), ``occupancy``, the fused kernels.
Public names: ``spikenerf.core.exports.PUBLIC_API`` (imported on first use, so that the CLI reads the
kinds without importing torch)."""

from spikenerf.core.exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__)
