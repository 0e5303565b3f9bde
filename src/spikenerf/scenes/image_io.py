"""Image loading for sequence import: any supported file → linear RGB on white, resampled in linear space.

Colour handling:

* 8-bit and 16-bit integer images (PNG, JPEG, anything Pillow reads) are sRGB-encoded: they are scaled to
  [0, 1] and linearised with :func:`~spikenerf.core.color.srgb_decode`. Alpha is linear coverage.
* float images (``.npy``; ``.exr`` when an imageio plugin can read it) are linear radiance, used as they are
  (values above 1 kept), but negative values are 0 (no negative light), before any resampling.
* RGBA is composited on white *after* linearising: ``rgb·a + (1 − a)``. Gray images are repeated to RGB.

Pillow reduces 16-bit colour PNGs to 8 bits, so 16-bit PNGs are decoded here: the filtered scanlines are
split into the high and low bytes of each sample, each half is unfiltered by Pillow as an 8-bit PNG with the
same per-row filters (the PNG filters act bytewise on the byte one pixel to the left/above, which the split
preserves), and the halves are joined again.
"""

from __future__ import annotations

import contextlib
import os
import struct
import tokenize
from collections.abc import Iterator
from pathlib import Path, PureWindowsPath

import numpy as np
from PIL import Image

from spikenerf.core.color import srgb_decode
from spikenerf.core.errors import InputError
from spikenerf.core.png16 import decode_png16, is_png16

#: extensions tried, in order, for a ``file_path`` written without one (NeRF synthetic: "./train/r_0").
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".exr", ".npy", ".PNG", ".JPG", ".JPEG", ".EXR")


def _read_pillow(path: Path) -> np.ndarray:
    """8-bit (or 16-bit gray) image through Pillow: (H, W, C) uint8/uint16, or float32 for mode F."""
    with Image.open(path) as im:
        mode = im.mode
        if mode in ("P", "PA"):
            im = im.convert("RGBA" if mode == "PA" or "transparency" in im.info else "RGB")
        elif mode in ("1", "CMYK", "YCbCr", "LAB", "HSV"):
            im = im.convert("L" if mode == "1" else "RGB")
        elif mode.startswith("I;16"):
            return np.asarray(im).astype(np.uint16)[..., None]
        elif mode not in ("L", "LA", "RGB", "RGBA", "F"):
            raise InputError(f"unsupported image mode {mode!r} (expected 8/16-bit gray, RGB or RGBA)", path)
        arr = np.asarray(im)
    return arr[..., None] if arr.ndim == 2 else arr


@contextlib.contextmanager
def _reading(path: Path) -> Iterator[None]:
    """Turn a failed read of the image ``path`` into one InputError (an InputError passes as it is)."""
    try:
        yield
    except InputError:
        raise
    except FileNotFoundError as err:
        raise InputError("image file not found", path=path) from err
    except (
        OSError,
        ValueError,
        SyntaxError,
        EOFError,
        struct.error,
        tokenize.TokenError,
        Image.DecompressionBombError,
    ) as err:  # (a cut .npy header: EOF, TokenError; Pillow: struct)
        raise InputError(f"cannot read image ({err})", path=path) from err


def _read_array(path: Path) -> np.ndarray:
    """The stored pixels of ``path``, as (H, W[, C]) integers or floats; format errors → InputError."""
    suffix = path.suffix.lower()
    with _reading(path):
        if suffix == ".npy":
            arr = np.array(np.load(path, mmap_mode="r", allow_pickle=False))  # (a header's size: checked)
            if not np.issubdtype(arr.dtype, np.floating):
                raise InputError(f".npy images must hold linear floats, found dtype {arr.dtype}", path=path)
            return arr
        if suffix == ".exr":
            import imageio.v3 as iio

            try:
                return np.asarray(iio.imread(path), dtype=np.float32)
            except (OSError, ValueError, RuntimeError) as err:
                raise InputError(
                    "cannot read EXR: no imageio plugin for it is installed here; convert the frames to "
                    ".npy (linear float32) or 16-bit PNG",
                    path=path,
                ) from err
        data = path.read_bytes()
        if is_png16(data):
            return decode_png16(data, path)
        return _read_pillow(path)


def read_image(path: str | Path) -> np.ndarray:
    """Read an image as linear RGBA.

    Returns:
        (H, W, 4) float32: linear RGB (sRGB-decoded for integer inputs, as stored for float inputs) and
        alpha in [0, 1] (1 where the file has no alpha).
    """
    path = Path(path)
    return to_linear_rgba(_read_array(path), path)


def check_shape(shape: tuple[int, ...], path: str | Path | None = None) -> None:
    """InputError unless ``shape`` is an image's: (H, W) or (H, W, C∈{1,2,3,4}), H and W ≥ 1."""
    shape = tuple(int(n) for n in shape)
    hwc = (*shape, 1) if len(shape) == 2 else shape
    if len(hwc) != 3 or hwc[2] not in (1, 2, 3, 4) or hwc[0] == 0 or hwc[1] == 0:
        raise InputError(f"expected an (H, W) or (H, W, 1-4) image, found shape {shape}", path=path)


def to_linear_rgba(arr: np.ndarray, path: str | Path | None = None) -> np.ndarray:
    """(H, W) or (H, W, C∈{1,2,3,4}) array → (H, W, 4) float32 linear RGB + alpha (see module doc)."""
    check_shape(arr.shape, path)
    if arr.ndim == 2:
        arr = arr[..., None]
    colour_channels = 1 if arr.shape[2] <= 2 else 3
    if arr.dtype in (np.uint8, np.uint16):
        x = arr.astype(np.float32) / float(np.iinfo(arr.dtype).max)
        colour = srgb_decode(x[..., :colour_channels])
    elif np.issubdtype(arr.dtype, np.floating):
        if not np.isfinite(arr).all():
            raise InputError("image holds NaN or infinite values", path=path)
        with np.errstate(over="ignore"):
            x = arr.astype(np.float32)
        if not np.isfinite(x).all():
            raise InputError("image holds values beyond float32's range (3.4e38)", path=path)
        colour = np.maximum(x[..., :colour_channels], 0.0)  # no negative light, before any resampling
    else:
        raise InputError(f"unsupported pixel type {arr.dtype} (expected uint8, uint16 or float)", path=path)
    alpha = x[..., -1:] if arr.shape[2] in (2, 4) else np.ones_like(x[..., :1])
    rgb = np.broadcast_to(colour, (*colour.shape[:2], 3))
    return np.concatenate([rgb, np.clip(alpha, 0.0, 1.0)], axis=-1).astype(np.float32)


def image_size(path: str | Path) -> tuple[int, int]:
    """(width, height) of an image file from its header (the whole file only for .exr); a .npy/.exr array
    that is no image (:func:`check_shape`) is an InputError."""
    path = Path(path)
    suffix = path.suffix.lower()
    with _reading(path):
        if suffix == ".exr":
            shape = _read_array(path).shape
        elif suffix == ".npy":
            shape = np.load(path, mmap_mode="r", allow_pickle=False).shape
        else:
            with Image.open(path) as im:
                return im.size
    check_shape(shape, path)
    return int(shape[1]), int(shape[0])


def composite_on_white(rgba: np.ndarray) -> np.ndarray:
    """(H, W, 4) linear RGBA → (H, W, 3) linear RGB over a white background: ``rgb·a + (1 − a)``."""
    alpha = rgba[..., 3:4]
    return (rgba[..., :3] * alpha + (1.0 - alpha)).astype(np.float32)


def resample(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """Resample a linear (H, W, C) float image to (height, width, C).

    Integer downscale factors average whole blocks (a reshape-mean); other downscales use Pillow's box
    filter (exact area averaging); upscales use bicubic interpolation, clipped at 0. All in linear space.
    """
    h, w, c = image.shape
    if (w, h) == (width, height):
        return image.astype(np.float32, copy=False)
    if w % width == 0 and h % height == 0:
        fy, fx = h // height, w // width
        return image.reshape(height, fy, width, fx, c).mean(axis=(1, 3), dtype=np.float64).astype(np.float32)
    downscale = width <= w and height <= h
    method = Image.Resampling.BOX if downscale else Image.Resampling.BICUBIC
    channels = [
        np.asarray(
            Image.fromarray(np.ascontiguousarray(image[..., i], dtype=np.float32)).resize(
                (width, height), method
            )
        )
        for i in range(c)
    ]
    out = np.stack(channels, axis=-1).astype(np.float32)
    return out if downscale else np.maximum(out, 0.0)


def load_frame(path: str | Path, size: tuple[int, int] | None = None) -> np.ndarray:
    """Read an image, composite it on white and resample it to ``size = (width, height)``.

    Returns:
        (H, W, 3) float32 linear RGB.
    """
    rgb = composite_on_white(read_image(path))
    return rgb if size is None else resample(rgb, size[0], size[1])


def find_image(root: Path, file_path: object, field: str, json_path: Path) -> Path:
    """The image named by a transforms.json ``file_path``: relative to ``root``, extension optional.

    Absolute paths and paths that resolve outside ``root`` (``..`` or a symlink leading out) are rejected;
    without an image extension, ``IMAGE_EXTENSIONS`` are tried in order ("./train/r_0" → train/r_0.png),
    the first that lies inside ``root`` is taken, and one found only outside it is named as such.
    """
    if not isinstance(file_path, str) or not file_path.strip():
        raise InputError(f"{field}: expected a relative path string, found {file_path!r}", path=json_path)
    windows = PureWindowsPath(file_path)
    if (
        os.path.isabs(file_path)
        or windows.is_absolute()
        or windows.drive
        or file_path.startswith(("/", "\\"))
    ):
        raise InputError(f"{field}: absolute paths are not allowed, found {file_path!r}", path=json_path)
    candidate = root / file_path.replace("\\", "/")
    base = root.resolve()
    if not candidate.resolve().is_relative_to(base):
        raise InputError(f"{field}: {file_path!r} points outside the folder of the JSON file", path=json_path)
    tried = [candidate]
    if candidate.suffix.lower() not in {e.lower() for e in IMAGE_EXTENSIONS}:
        tried += [candidate.with_name(candidate.name + ext) for ext in IMAGE_EXTENSIONS]
    outside = None  # the first file found that resolves out of the folder (a symlink leading out)
    for option in tried:
        if option.is_file():
            if option.resolve().is_relative_to(base):
                return option
            outside = outside or option
    if outside is not None:
        raise InputError(
            f"{field}: {file_path!r} ({outside.name}) points outside the folder of the JSON file",
            path=json_path,
        )
    also = f" (also tried {', '.join(IMAGE_EXTENSIONS[:5])})" if len(tried) > 1 else ""
    raise InputError(f"{field}: image {file_path!r} not found{also}", path=json_path)
