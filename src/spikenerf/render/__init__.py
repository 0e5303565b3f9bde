"""Renderers: volume rendering of the fields and the spiking volume renderer."""

from spikenerf.render.base import RadianceModel
from spikenerf.render.grid_model import GridModel
from spikenerf.render.mlp_model import MLPModel
from spikenerf.render.model import (
    MODELS,
    build_model,
    model_from_hparams,
    ray_bounds,
    render_image,
    render_mean,
    render_rays_chunked,
)
from spikenerf.render.spiking import (
    SpikeWindow,
    fire_sequence,
    iter_spike_states,
    iter_spike_stream,
    render_spike_stream,
    render_spike_window,
)
from spikenerf.render.volume import RenderOutput

__all__ = [
    "MODELS",
    "GridModel",
    "MLPModel",
    "RadianceModel",
    "RenderOutput",
    "SpikeWindow",
    "build_model",
    "fire_sequence",
    "iter_spike_states",
    "iter_spike_stream",
    "model_from_hparams",
    "ray_bounds",
    "render_image",
    "render_mean",
    "render_rays_chunked",
    "render_spike_stream",
    "render_spike_window",
]
