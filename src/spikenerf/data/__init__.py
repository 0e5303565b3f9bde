"""Dataset folder I/O, the simulate pipeline, rays, training targets and samplers."""

from spikenerf.core.exports import lazy_exports

#: public name -> defining module (imported on first use)
_EXPORTS = {
    "SpikeDataset": "spikenerf.data.dataset",
    "load_dataset": "spikenerf.data.dataset",
    "SimulateOptions": "spikenerf.data.simulate",
    "simulate_dataset": "spikenerf.data.simulate",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
