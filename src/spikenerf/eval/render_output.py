"""The files of a ``spikenerf render`` folder: the PNG and depth encodings (:func:`png_bytes`,
:func:`colorize_depth` over :func:`depth_range`), the names of its frames and spike files, the files a render
plans (:func:`planned_files`), and the removal of what an earlier render left (:func:`clear_previous_render`,
from the files its ``render.json`` or its cache lists: :func:`listed_files`)."""

from __future__ import annotations

import contextlib
import io
import json
import re
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from spikenerf.camera.spikecv import CONFIG_NAME as SPIKECV_CONFIG
from spikenerf.core.atomic import clean_stale_temps, write_bytes_atomic
from spikenerf.core.video import to_uint8
from spikenerf.data.dataset import spike_files
from spikenerf.eval.render_cache import CACHE, UNREADABLE
from spikenerf.eval.render_record import read_render_record


def png_bytes(image: np.ndarray) -> bytes:
    """8-bit PNG of a uint8 (H, W) or (H, W, 3) image."""
    return bytes(iio.imwrite("<bytes>", image, extension=".png"))


def depth_range(depths: np.ndarray, opacities: np.ndarray) -> tuple[float, float]:
    """(lo, hi): 1st/99th percentile of depths (N, H, W) where opacity > 0.5 (0, 1 if none)."""
    valid = depths[opacities > 0.5]
    if valid.size == 0:
        return 0.0, 1.0
    lo, hi = np.percentile(valid, [1.0, 99.0])
    return float(lo), float(max(hi, lo + 1e-6))


def colorize_depth(depth: np.ndarray, opacity: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Depth (H, W) → uint8 (H, W, 3): turbo colour map of (depth − lo)/(hi − lo), over white by opacity."""
    from matplotlib import colormaps

    t = np.clip((depth - lo) / (hi - lo), 0.0, 1.0)
    rgb = colormaps["turbo"](t)[..., :3]
    a = np.clip(opacity, 0.0, 1.0)[..., None]
    return to_uint8(rgb * a + (1.0 - a))


def write_npy(path: Path, array: np.ndarray) -> None:
    """Write ``array`` (a depth map (H, W)) to ``path`` as ``.npy``, atomically."""
    buf = io.BytesIO()
    np.save(buf, array)
    write_bytes_atomic(path, buf.getvalue())


#: the names a render gives its frames and depth maps (``00000.png``, ``00000.npy``; more digits past 99999)
FRAME_NAME = re.compile(r"\d{5,}\.(png|npy)")
#: the names of a novel-view spike stream, its preview and its SpikeCV config (``video.write_spikes``)
SPIKE_NAME = re.compile(r"spikes_(gray\.dat|rgb_[rgb]\.dat|tfp\.png)|config\.yaml")


def planned_files(name: str, channels: int, spikes: bool, config: bool = True) -> list[str]:
    """The video and spike files a render of trajectory ``name`` writes (see ``video.write_spikes``; with
    ``config`` its SpikeCV ``config.yaml`` too)."""
    if not spikes:
        return [f"{name}.mp4"]
    streams = spike_files("gray" if channels == 1 else "rgb")
    return [f"{name}.mp4", *streams, "spikes_tfp.png", *([SPIKECV_CONFIG] if config else [])]


def listed_files(out: Path) -> list[object]:
    """The video and spike files of earlier renders into ``out``: those its ``render.json`` lists (a
    malformed one is an InputError naming it: the files it listed would stay), and those an interrupted
    render planned (its cache's ``key.json``; a cache, rebuilt where it is unreadable)."""
    listed: list[object] = []
    if (record := read_render_record(out)) is not None:
        files = record.get("files") or {}
        listed += [files.get("video"), *(files.get("spikes") or [])]
    with contextlib.suppress(*UNREADABLE):
        listed += list(json.loads((out / CACHE / "key.json").read_text())["plan"])
    return listed


def clear_previous_render(out: Path, listed: list[object] | None = None) -> None:
    """Delete what earlier renders left in their folder ``out`` (marked ``render``): the frames and depth
    maps (named as :data:`FRAME_NAME`), ``render.json`` and the video and spike files it lists or an
    interrupted render planned (``listed``: :func:`listed_files`, read before), and temporaries, so no view
    of another trajectory stays beside the new ones and no manifest describes files that are gone. Other
    files stay."""
    listed = listed_files(out) if listed is None else listed
    (out / "render.json").unlink(missing_ok=True)
    for folder in (out, out / "images", out / "depth"):
        clean_stale_temps(folder)
    stale = [p for p in (out / "images").glob("*.png") if FRAME_NAME.fullmatch(p.name)]
    stale += [p for p in (out / "depth").glob("*.*") if FRAME_NAME.fullmatch(p.name)]
    for name in listed:
        if (
            isinstance(name, str)
            and (name == Path(name).name)
            and (SPIKE_NAME.fullmatch(name) or name.endswith(".mp4"))
        ):
            stale.append(out / name)
    for path in stale:
        path.unlink(missing_ok=True)
