"""Device-memory estimates of a field's rays: the bytes one ray's samples take through the network.

Used to size render chunks from the free GPU memory (``render.inference``) and to refuse, before training,
a batch that cannot fit in it (``train.preflight``). An estimate, not a measurement: a grid ray is taken to
cross the scene box side to side (a cube's mean chord is 2/3 of its side; occupancy skipping and colour
culling usually keep fewer samples), and training keeps each layer's activations for the backward pass.
"""

from __future__ import annotations

from typing import Any

from spikenerf.fields.registry import field_config

#: float32 bytes
F32 = 4
#: per-sample bookkeeping of the marcher and compositor: positions, t, deltas, σ, weights, transmittance,
#: ray and step indices (int64), in float32 words
GEOMETRY_WORDS = 24


def samples_per_ray(kind: str, config: Any = None) -> float:
    """Samples of one ray (the field config's own ``samples_per_ray``): the grid's march across the box's
    side at its final resolution (capped by ``max_samples``), or the MLP's coarse + fine samples (the fine
    pass re-evaluates the coarse ones)."""
    return field_config(kind, config).samples_per_ray()


def sample_words(kind: str, config: Any = None, training: bool = True) -> float:
    """float32 words one sample holds at the peak (the layer inputs of the field config's
    ``layer_widths``): training keeps every layer's input (and its gradient while the backward pass runs,
    counted as a second copy); inference holds about two layers at once."""
    layers = field_config(kind, config).layer_widths()
    if training:
        return GEOMETRY_WORDS + 2.0 * sum(layers)
    return GEOMETRY_WORDS + 2.0 * max(layers)


def ray_bytes(kind: str, config: Any = None, training: bool = True) -> float:
    """Estimated device bytes of one ray (all its samples) through a field of ``kind`` with ``config``."""
    return samples_per_ray(kind, config) * sample_words(kind, config, training) * F32
