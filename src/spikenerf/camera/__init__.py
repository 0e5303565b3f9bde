"""The spike camera: integrate-and-fire model, noise, .dat I/O, reconstruction (TFP/TFI) and spike masks."""

from spikenerf.core.exports import lazy_exports

#: public name -> defining module (imported on first use)
_EXPORTS = {
    "CameraConfig": "spikenerf.camera.model",
    "SpikeCamera": "spikenerf.camera.model",
    "fire": "spikenerf.camera.model",
    "simulate": "spikenerf.camera.model",
    "read_dat": "spikenerf.camera.io",
    "write_dat": "spikenerf.camera.io",
    "read_dat_rgb": "spikenerf.camera.io",
    "write_dat_rgb": "spikenerf.camera.io",
    "tfp": "spikenerf.camera.reconstruct",
    "tfi": "spikenerf.camera.reconstruct",
    "spike_masks": "spikenerf.camera.masks",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
