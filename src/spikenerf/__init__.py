"""spikenerf: 3D reconstruction and novel-view synthesis from spike cameras.

The public API (each name is imported on first use)::

    from spikenerf import simulate, read_dat, write_dat, tfp, tfi, load_dataset, TrainConfig, load_run
    from spikenerf.train import train  # (``spikenerf.train`` is the subpackage)

Subpackages export more: ``spikenerf.camera``, ``spikenerf.scenes``, ``spikenerf.data``,
``spikenerf.capture`` (simulate a dataset), ``spikenerf.render``, ``spikenerf.train``, ``spikenerf.eval``.
"""

from spikenerf.core.exports import lazy_exports

__version__ = "0.1.0"

__getattr__, __dir__, _names = lazy_exports(__name__)  # the table: spikenerf.core.exports.PUBLIC_API
__all__ = ["__version__", *_names]
