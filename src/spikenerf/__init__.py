"""spikenerf: 3D reconstruction and novel-view synthesis from spike cameras.

The public API (each name is imported on first use)::

    from spikenerf import simulate, read_dat, write_dat, tfp, tfi, load_dataset, TrainConfig, load_run
    from spikenerf.train import train  # (``spikenerf.train`` is the subpackage)

Subpackages export more: ``spikenerf.camera``, ``spikenerf.scenes``, ``spikenerf.data``,
``spikenerf.render``, ``spikenerf.train``, ``spikenerf.eval``.
"""

from spikenerf.core.exports import lazy_exports

__version__ = "0.1.0"

#: public name -> defining module (imported on first use)
_EXPORTS = {
    "simulate": "spikenerf.camera",
    "read_dat": "spikenerf.camera",
    "write_dat": "spikenerf.camera",
    "tfp": "spikenerf.camera",
    "tfi": "spikenerf.camera",
    "load_dataset": "spikenerf.data",
    "simulate_dataset": "spikenerf.data",
    "TrainConfig": "spikenerf.train",
    "load_run": "spikenerf.train",
    "evaluate_run": "spikenerf.eval",
}
__all__ = ["__version__", *sorted(_EXPORTS)]
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
