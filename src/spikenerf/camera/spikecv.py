"""A recording's SpikeCV ``config.yaml``: the frame size (``spike_h``, ``spike_w``) and what else is known.

SpikeCV keeps a ``config.yaml`` beside (or one folder above) its ``.dat`` recordings with at least ``spike_h``
and ``spike_w``. spikenerf also reads ``fps``, ``threshold`` and ``raw_width`` (the stored row width of raw
sps10 files, 416) when present. Every other key is ignored. This is the one reader (and writer: ``simulate
--raw-width``, ``render --spikes``) of that file for all commands (``import``, ``info``, ``reconstruct``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import yaml

from spikenerf.camera.modes import LAYOUTS
from spikenerf.core.errors import InputError, is_finite
from spikenerf.core.yamlio import load_yaml

CONFIG_NAME = "config.yaml"


@dataclass(frozen=True)
class RecordingConfig:
    """What a SpikeCV config says about a recording; ``None`` where it says nothing."""

    height: int | None = None
    width: int | None = None
    fps: float | None = None
    threshold: float | None = None
    raw_width: int | None = None
    path: Path | None = None
    #: the row order, where the config says (spikenerf's datasets do; SpikeCV's configs do not)
    layout: str | None = None


def find_spikecv_config(dat: str | Path) -> Path | None:
    """The ``config.yaml`` beside a ``.dat`` file, else one folder up (SpikeCV's layout), else None."""
    dat = Path(dat)
    for folder in (dat.parent, dat.parent.parent):
        if (folder / CONFIG_NAME).is_file():
            return folder / CONFIG_NAME
    return None


def _value(data: dict, key: str, path: Path, integer: bool) -> float | int | None:
    if data.get(key) is None:
        return None
    v = data[key]
    ok = isinstance(v, (int, float)) and is_finite(v) and v > 0
    if not ok or (integer and v != int(v)):
        kind = "a positive integer" if integer else "a positive number"
        raise InputError(f"field {key!r}: expected {kind}, found {v!r}", path=path)
    return int(v) if integer else float(v)


def read_spikecv_config(path: str | Path) -> RecordingConfig:
    """Parse a SpikeCV ``config.yaml``; InputError (naming the file and field) on malformed values."""
    path = Path(path)
    try:
        data = load_yaml(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError("no such file", path=path) from None
    except (OSError, yaml.YAMLError, UnicodeDecodeError) as err:
        raise InputError(f"cannot read YAML ({err})", path=path) from err
    if data is None:
        raise InputError("is empty: expected spike_h and spike_w (a SpikeCV config.yaml)", path=path)
    if not isinstance(data, dict):
        raise InputError(f"expected a mapping at the top level, found {type(data).__name__}", path=path)
    config = RecordingConfig(
        height=_value(data, "spike_h", path, True),
        width=_value(data, "spike_w", path, True),
        fps=_value(data, "fps", path, False),
        threshold=_value(data, "threshold", path, False),
        raw_width=_value(data, "raw_width", path, True),
        path=path,
        layout=_layout(data, path),
    )
    if config.raw_width is not None and config.width is not None and config.raw_width < config.width:
        raise InputError(
            f"field 'raw_width': expected ≥ spike_w {config.width}, found {config.raw_width}", path=path
        )
    return config


def _layout(data: dict, path: Path) -> str | None:
    """The config's ``layout`` (None where it has none); InputError naming the field when it is no layout."""
    layout = data.get("layout")
    if layout is not None and layout not in LAYOUTS:
        raise InputError(f"field 'layout': expected one of {', '.join(LAYOUTS)}, found {layout!r}", path=path)
    return layout


def write_spikecv_config(
    folder: str | Path,
    height: int,
    width: int,
    fps: float,
    threshold: float | None = None,
    raw_width: int | None = None,
) -> Path:
    """Write the SpikeCV ``config.yaml`` of the recordings in ``folder`` (atomically): spike_h, spike_w,
    raw_width (when given), fps and threshold (when given), the keys :func:`read_spikecv_config` reads.
    Returns its path."""
    from spikenerf.core.atomic import write_text_atomic

    config: dict[str, int | float] = {"spike_h": int(height), "spike_w": int(width)}
    if raw_width is not None:
        config["raw_width"] = int(raw_width)
    config["fps"] = float(fps)
    if threshold is not None:
        config["threshold"] = float(threshold)
    path = Path(folder) / CONFIG_NAME
    write_text_atomic(path, yaml.safe_dump(config, sort_keys=False))
    return path


def size_conflicts(
    path: str | Path | None, height: int | None, width: int | None, raw_width: int | None = None
) -> list[tuple[str, int, str, int]]:
    """``(param, given, key, value)`` for each given ``height``, ``width`` or ``raw_width`` that differs from
    the ``key`` of the SpikeCV config at ``path`` (``("width", 16, "spike_w", 32)``); none where ``path`` is
    None or cannot be read. A mismatch is more often a typo than a wrong file: ``info`` warns of it,
    ``reconstruct`` and ``import``, which write what they read, refuse it (:func:`refuse_size_conflicts`)."""
    if path is None:
        return []
    try:
        own = read_spikecv_config(path)
    except InputError:
        return []
    pairs = (("width", width, "spike_w", own.width), ("height", height, "spike_h", own.height),
             ("raw_width", raw_width, "raw_width", own.raw_width))  # fmt: skip
    return [(p, g, k, v) for p, g, k, v in pairs if g is not None and v is not None and g != v]


def refuse_size_conflicts(
    path: str | Path | None, height: int | None, width: int | None, raw_width: int | None = None
) -> None:
    """InputError naming the first of ``height``, ``width``, ``raw_width`` that differs from the SpikeCV
    config at ``path`` (:func:`size_conflicts`): a command that writes what it reads would write garbage."""
    if conflicts := size_conflicts(path, height, width, raw_width):
        param, given, key, value = conflicts[0]
        raise InputError(
            f"{param} {given} differs from {key} {value} in {path}, which describes this recording: "
            "leave it out, or correct that file if it is wrong",
            param=param,
        )


def recording_config(
    dat: str | Path,
    height: int | None = None,
    width: int | None = None,
    config: str | Path | None = None,
) -> RecordingConfig:
    """The recording's config: explicit ``height``/``width`` win over ``config`` (default: beside ``dat``);
    the config's ``raw_width`` (stored row width) applies only to its own frame width.

    A config found beside the recording (not given as ``config``) that cannot be parsed is ignored when
    ``height`` and ``width`` are both given: an unrelated file does not block a command that needs nothing
    from it.

    Raises:
        InputError: the size is known from neither (naming both ways to give it), or ``config`` is malformed.
    """
    if Path(dat).is_dir():
        inside = sorted(p.name for p in Path(dat).glob("*.dat"))
        hint = f"give a recording file in it ({', '.join(inside[:3])})" if inside else "it holds no .dat file"
        raise InputError(f"is a folder, not a .dat recording: {hint}", path=dat)
    if not Path(dat).exists():
        raise InputError("file not found", path=dat)
    found = Path(config) if config is not None else find_spikecv_config(dat)
    try:
        base = read_spikecv_config(found) if found is not None else RecordingConfig()
    except InputError:
        if config is not None or height is None or width is None:
            raise
        base, found = RecordingConfig(), None
    h = height if height is not None else base.height
    w = width if width is not None else base.width
    if h is None or w is None:
        where = f"{found} has no spike_h/spike_w" if found else f"no {CONFIG_NAME} beside the recording"
        missing = [name for name, value in (("height", h), ("width", w)) if value is None]
        wanted = " and ".join(missing) + (" too" if len(missing) == 1 else "")
        raise InputError(f"frame size unknown ({where}): pass {wanted}", path=dat, param=tuple(missing))
    raw = base.raw_width if width is None or width == base.width else None  # the config's rows: its width's
    return RecordingConfig(h, w, base.fps, base.threshold, raw, found, base.layout)
