"""The public API, in one table, exported lazily by the package ``__init__`` files (PEP 562).

``spikenerf.camera.tfp`` imports ``spikenerf.camera.reconstruct`` only when first used, so ``import
spikenerf`` and the CLI stay fast and the ``__init__`` files add no import edges (no cycles). Names are
strings here: this module imports nothing of spikenerf.
"""

from __future__ import annotations

import importlib
import importlib.util
from collections.abc import Callable
from typing import Any

#: package → {defining module → its public names}
PUBLIC_API: dict[str, dict[str, str]] = {
    "spikenerf": {
        "spikenerf.camera": "simulate read_dat write_dat tfp tfi",
        "spikenerf.data": "load_dataset",
        "spikenerf.capture": "SimulateOptions simulate_dataset",
        "spikenerf.train": "TrainConfig load_run",  # train(): spikenerf.train is the subpackage
        "spikenerf.eval": "evaluate_run",
    },
    "spikenerf.camera": {
        "spikenerf.camera.model": "CameraConfig SpikeCamera",
        "spikenerf.camera.firing": "fire",
        "spikenerf.camera.simulation": "simulate",
        "spikenerf.camera.io": "read_dat write_dat read_dat_rgb write_dat_rgb",
        "spikenerf.camera.reconstruct": "tfp tfi",
        "spikenerf.camera.masks": "spike_masks",
        "spikenerf.camera.layout": "to_camera_layout to_channels_last",
    },
    "spikenerf.scenes": {
        "spikenerf.scenes.trajectory": "Intrinsics Trajectory orbit novel_views",
        "spikenerf.scenes.distortion": "Distortion",
        "spikenerf.scenes.registry": "list_scenes make_scene_source",
    },
    "spikenerf.data": {
        "spikenerf.data.dataset": "SpikeDataset load_dataset",
    },
    "spikenerf.capture": {
        "spikenerf.capture.options": "SimulateOptions",
        "spikenerf.capture.simulate": "simulate_dataset",
    },
    "spikenerf.train": {
        "spikenerf.train.config": "TrainConfig",
        "spikenerf.train.config_file": "load_config",
        "spikenerf.train.trainer": "Trainer train",
        "spikenerf.train.run": "load_run",
        "spikenerf.train.losses": "recon_loss spike_interval_loss window_mean_loss paper_spike_loss",
    },
    "spikenerf.fields": {
        "spikenerf.fields.choices": "FIELD_KINDS FieldKind",
        "spikenerf.fields.registry": (
            "FIELD_REGISTRY FieldEntry build_field field_config field_entry field_memory"
        ),
        "spikenerf.fields.base": "Field",
        "spikenerf.fields.grid": "GridField",
        "spikenerf.fields.grid_config": "GridFieldConfig",
        "spikenerf.fields.mlp": "MLPField MLPFieldConfig",
        "spikenerf.fields.occupancy": "OccupancyGrid",
    },
    "spikenerf.render": {
        "spikenerf.render.base": "RadianceModel",
        "spikenerf.render.grid_model": "GridModel",
        "spikenerf.render.mlp_model": "MLPModel",
        "spikenerf.render.model": (
            "MODELS build_model model_from_hparams ray_bounds render_image render_mean render_rays_chunked"
        ),
        "spikenerf.render.spiking": (
            "SpikeWindow fire_sequence iter_spike_states iter_spike_stream render_spike_stream "
            "render_spike_window"
        ),
        "spikenerf.render.volume": "RenderOutput",
    },
    "spikenerf.eval": {
        "spikenerf.eval.metrics": "psnr ssim",
        "spikenerf.eval.evaluate": "evaluate_run",
        "spikenerf.core.color": "srgb_encode srgb_decode",  # the metrics compare sRGB images
    },
}


def lazy_exports(package: str) -> tuple[Callable[[str], Any], Callable[[], list[str]], list[str]]:
    """``(__getattr__, __dir__, __all__)`` for ``package`` from :data:`PUBLIC_API`."""
    exports = {name: module for module, names in PUBLIC_API[package].items() for name in names.split()}

    def getattr_(name: str) -> Any:
        if name not in exports:
            if not name.startswith("_") and importlib.util.find_spec(f"{package}.{name}") is not None:
                return importlib.import_module(f"{package}.{name}")  # a submodule: ``spikenerf.render.model``
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(exports[name]), name)

    def dir_() -> list[str]:  # the lazy names and what the package itself defines (``__version__``)
        return sorted({*exports, *vars(importlib.import_module(package))})

    return getattr_, dir_, sorted(exports)
