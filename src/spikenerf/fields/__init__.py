"""Radiance fields: the fast grid field (TensoRF-VM) and the vanilla NeRF MLP."""

from __future__ import annotations

import dataclasses
from typing import Any, Literal, get_args

from torch import Tensor

from spikenerf.core.errors import InputError
from spikenerf.fields.grid import GridField, GridFieldConfig
from spikenerf.fields.mlp import MLPField, MLPFieldConfig
from spikenerf.fields.occupancy import OccupancyGrid

FieldKind = Literal["grid", "mlp"]
FIELD_KINDS: tuple[str, ...] = get_args(FieldKind)
_CONFIGS: dict[str, type] = {"grid": GridFieldConfig, "mlp": MLPFieldConfig}

__all__ = [
    "FIELD_KINDS",
    "FieldKind",
    "GridField",
    "GridFieldConfig",
    "MLPField",
    "MLPFieldConfig",
    "OccupancyGrid",
    "build_field",
    "field_config",
]


def field_config(kind: str, config: Any = None) -> GridFieldConfig | MLPFieldConfig:
    """The typed config of ``kind`` from None (defaults), a dataclass, or a dict (e.g. read from YAML)."""
    if kind not in _CONFIGS:
        raise InputError(f"field kind must be one of {', '.join(FIELD_KINDS)}, got {kind!r}")
    cls = _CONFIGS[kind]
    if config is None:
        return cls()
    if isinstance(config, cls):
        return config
    if isinstance(config, dict):
        names = {f.name: f for f in dataclasses.fields(cls)}
        unknown = sorted(set(config) - set(names))
        if unknown:
            raise InputError(f"unknown {kind} field config keys {unknown}; expected some of {sorted(names)}")
        values = {k: tuple(v) if isinstance(v, list) else v for k, v in config.items()}
        return cls(**values)
    raise InputError(f"{kind} field config must be a {cls.__name__} or a dict, got {type(config).__name__}")


def build_field(kind: str, channels: int, scene_box: Tensor, config: Any = None) -> GridField | MLPField:
    """A field of ``kind`` ("grid" | "mlp") with ``channels`` (1 gray, 3 rgb) over ``scene_box`` (2, 3)."""
    if channels not in (1, 3):
        raise InputError(f"channels must be 1 (gray) or 3 (rgb), got {channels}")
    cfg = field_config(kind, config)
    if kind == "grid":
        return GridField(channels, scene_box, cfg)  # type: ignore[arg-type]
    return MLPField(channels, scene_box, cfg)  # type: ignore[arg-type]
