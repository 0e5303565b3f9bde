"""Radiance fields: the fast grid field (TensoRF-VM) and the vanilla NeRF MLP."""

from __future__ import annotations

import dataclasses
from typing import Any, Literal, get_args

from torch import Tensor

from spikenerf.core.errors import InputError
from spikenerf.fields.base import Field
from spikenerf.fields.grid import GridField, GridFieldConfig
from spikenerf.fields.mlp import MLPField, MLPFieldConfig
from spikenerf.fields.occupancy import OccupancyGrid

FieldKind = Literal["grid", "mlp"]
FIELD_KINDS: tuple[str, ...] = get_args(FieldKind)
_CONFIGS: dict[str, type] = {"grid": GridFieldConfig, "mlp": MLPFieldConfig}

__all__ = [
    "FIELD_KINDS",
    "Field",
    "FieldKind",
    "GridField",
    "GridFieldConfig",
    "MLPField",
    "MLPFieldConfig",
    "OccupancyGrid",
    "build_field",
    "field_config",
    "field_memory",
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
        values = {k: _checked(kind, k, v, getattr(cls(), k)) for k, v in config.items()}
        return cls(**values)
    raise InputError(f"{kind} field config must be a {cls.__name__} or a dict, got {type(config).__name__}")


def _checked(kind: str, key: str, value: Any, default: Any) -> Any:
    """``value`` for the config entry ``key`` (whose default is ``default``): same type, finite, and ≥ 0
    for numbers (> 0 for sizes and rates; ≥ 8 voxels, R ≥ 2 per axis; ≥ 1 step between occupancy updates;
    a final lr ratio ≤ 1); anything else is an InputError naming the entry."""
    import contextlib
    import math

    where = f"{kind} field config {key!r}"
    if isinstance(default, tuple):
        if not isinstance(value, (list, tuple)) or not all(isinstance(v, int) and v >= 0 for v in value):
            raise InputError(f"{where}: expected a list of integers ≥ 0, found {value!r}")
        return tuple(value)
    if isinstance(default, bool) or isinstance(value, bool):
        if not isinstance(value, bool) or not isinstance(default, bool):
            raise InputError(f"{where}: expected {type(default).__name__}, found {value!r}")
        return value
    if isinstance(default, float) and isinstance(value, str):  # YAML 1.1 reads 1e-3 as a string
        with contextlib.suppress(ValueError):
            value = float(value)
    if isinstance(default, (int, float)):
        ok = isinstance(value, int) or (isinstance(default, float) and isinstance(value, float))
        if not ok or not math.isfinite(value):
            raise InputError(f"{where}: expected a finite {type(default).__name__}, found {value!r}")
        positive = key.startswith(("n_voxels", "lr", "step_", "max_", "batch_", "iterations")) or key in (
            "density_components", "app_components", "app_dim", "hidden", "width", "depth", "distance_scale",
        )  # fmt: skip
        if (positive and value <= 0) or (value < 0 and key != "density_shift"):
            raise InputError(f"{where}: expected a number {'> 0' if positive else '≥ 0'}, found {value!r}")
        least = {"occupancy_every": 1, "n_voxels_init": 8, "n_voxels_final": 8}.get(key)  # 8: R ≥ 2 per axis
        if least is not None and value < least:
            raise InputError(f"{where}: expected ≥ {least}, found {value!r}")
        if key == "lr_final_ratio" and value > 1:
            raise InputError(f"{where}: expected a number in (0, 1], found {value!r}")
        return type(default)(value)
    return value


def field_memory(kind: str, config: Any) -> tuple[float, float, float]:
    """(parameter memory while training, memory per ray, checkpoint bytes) of a field of ``kind``: the
    parameters with their gradient and Adam state; a ray's samples through the network, forward and
    backward (~256 B a sample); parameters and Adam state on disk."""
    cfg = field_config(kind, config)
    if isinstance(cfg, GridFieldConfig):
        r = float(max(cfg.n_voxels_init, cfg.n_voxels_final)) ** (1 / 3)
        params = 3.0 * (cfg.density_components + cfg.app_components) * (r * r + r)
        samples = min(float(cfg.max_samples), r * 3**0.5 / cfg.step_ratio)
    else:
        params = float(cfg.depth) * cfg.width * cfg.width * 2
        samples = float(cfg.n_coarse + cfg.n_fine)
    return params * 16, samples * 256, params * 12


def build_field(kind: str, channels: int, scene_box: Tensor, config: Any = None) -> GridField | MLPField:
    """A field of ``kind`` ("grid" | "mlp") with ``channels`` (1 gray, 3 rgb) over ``scene_box`` (2, 3)."""
    if channels not in (1, 3):
        raise InputError(f"channels must be 1 (gray) or 3 (rgb), got {channels}")
    cfg = field_config(kind, config)
    if kind == "grid":
        return GridField(channels, scene_box, cfg)  # type: ignore[arg-type]
    return MLPField(channels, scene_box, cfg)  # type: ignore[arg-type]
