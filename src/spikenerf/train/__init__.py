"""Training: losses, methods, trainer and checkpoints."""

from spikenerf.core.exports import lazy_exports

#: public name -> defining module (imported on first use)
_EXPORTS = {
    "TrainConfig": "spikenerf.train.config",
    "load_config": "spikenerf.train.config",
    "Trainer": "spikenerf.train.trainer",
    "train": "spikenerf.train.trainer",
    "load_run": "spikenerf.train.run",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
