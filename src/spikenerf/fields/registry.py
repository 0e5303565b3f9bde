"""The registry of field kinds: each kind is one :class:`FieldEntry` in :data:`FIELD_REGISTRY`, which every
dispatch site reads (config parsing, building, the memory estimates, the trainer's schedule, checkpoints); its
config class carries the per-kind estimates (``training_size``, ``samples_per_ray``, ``layer_widths``) and
``for_iterations``. The renderer pairs each kind with its sampler in ``spikenerf.render.model.MODELS``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from torch import Tensor

from spikenerf.core.config import check_config, from_mapping
from spikenerf.core.errors import InputError, is_integer
from spikenerf.fields.base import Field
from spikenerf.fields.grid import GridField
from spikenerf.fields.grid_config import GridFieldConfig
from spikenerf.fields.mlp import MLPField, MLPFieldConfig


@dataclass(frozen=True)
class FieldEntry:
    """One field kind.

    Attributes:
        config: its typed config dataclass (with ``for_iterations`` and the memory estimates).
        field: its :class:`Field` class, built as ``field(channels, scene_box, config)``.
        saved_defaults: config values that a checkpoint saved before the key existed trained with.
        renamed: keys since renamed → a function of the old value giving the entries that replace it, so
            that checkpoints and ``config.yaml`` files written before the rename still load.
    """

    config: type
    field: type[Field]
    saved_defaults: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    renamed: Mapping[str, Callable[[Any], dict[str, Any]]] = dataclasses.field(default_factory=dict)


def _batch_rays(rays: Any) -> dict[str, Any]:
    """``batch_rays`` (removed): nothing read it (a step's rays are train's ``batch``); a config that
    holds it still loads."""
    return {}


def _gather_lookup(on: Any) -> dict[str, Any]:
    """``gather_lookup`` (before ``lookup``): true was ``lookup`` "gather", false the default."""
    if not isinstance(on, bool):
        raise InputError(
            f"field_config.gather_lookup must be true or false, got {on!r}",
            param="field_config.gather_lookup",
        )
    return {"lookup": "gather"} if on else {}


#: field kind -> its entry, in :data:`FIELD_KINDS` order
FIELD_REGISTRY: dict[str, FieldEntry] = {
    "grid": FieldEntry(
        GridFieldConfig,
        GridField,
        {"decoder_bf16": False},
        {"gather_lookup": _gather_lookup, "batch_rays": _batch_rays},
    ),
    "mlp": FieldEntry(MLPFieldConfig, MLPField, renamed={"batch_rays": _batch_rays}),
}


def field_entry(kind: str) -> FieldEntry:
    """The registry entry of ``kind`` (InputError for an unknown one)."""
    if kind not in FIELD_REGISTRY:
        raise InputError(f"field kind must be one of {', '.join(FIELD_REGISTRY)}, got {kind!r}", param="kind")
    return FIELD_REGISTRY[kind]


def field_config(kind: str, config: Any = None) -> Any:
    """The typed config of ``kind`` from None (defaults), a dataclass, or a dict (e.g. read from YAML)."""
    entry = field_entry(kind)
    cls = entry.config
    if config is None:
        return cls()
    if isinstance(config, cls):
        return config
    if isinstance(config, dict):  # checked like every config: types and BOUNDS (spikenerf.core.config)
        cfg = from_mapping(cls, _renamed(entry, config), f"{kind} field config")
        check_config(cfg, "field_config.")
        if hasattr(cfg, "check"):  # relations between keys
            cfg.check()
        return cfg
    raise InputError(f"{kind} field config must be a {cls.__name__} or a dict, got {type(config).__name__}")


def _renamed(entry: FieldEntry, config: dict) -> dict:
    """``config`` with the keys that ``entry`` renamed written the new way (an explicit new key wins)."""
    out = {k: v for k, v in config.items() if k not in entry.renamed}
    for old, new in entry.renamed.items():
        if old in config:
            out = {**new(config[old]), **out}
    return out


def field_memory(kind: str, config: Any) -> tuple[float, float, float]:
    """(parameter memory while training, memory per ray, checkpoint bytes) of a field of ``kind``: the
    parameters with their gradient and Adam state; a ray's samples through the network, forward and
    backward (~256 B a sample); parameters and Adam state on disk."""
    params, samples = field_config(kind, config).training_size()
    return params * 16, samples * 256, params * 12


def build_field(kind: str, channels: int, scene_box: Tensor, config: Any = None) -> Field:
    """A field of ``kind`` (a :data:`FIELD_REGISTRY` key: "grid" | "mlp") with ``channels`` (1 gray, 3 rgb)
    over ``scene_box`` (2, 3)."""
    if not is_integer(channels) or channels not in (1, 3):  # (True == 1: a TypeError deep in nn.Linear)
        raise InputError(f"channels must be 1 (gray) or 3 (rgb), got {channels!r}", param="channels")
    cfg = field_config(kind, config)
    return FIELD_REGISTRY[kind].field(channels, scene_box, cfg)  # type: ignore[call-arg]
