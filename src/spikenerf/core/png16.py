"""16-bit PNG encode/decode (Pillow writes and reads only 8 bits per channel for colour PNGs).

Encoding writes Up-filtered rows with zlib; decoding lets Pillow unfilter the high and low byte planes as two
8-bit images (PNG filters act byte-wise with no carry, so this is exact).
"""

from __future__ import annotations

import io
import struct
import zlib
from pathlib import Path

import numpy as np
from PIL import Image

from spikenerf.core.errors import InputError

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_CHANNELS = {0: 1, 2: 3, 4: 2, 6: 4}  # colour type -> samples per pixel (palette never has 16 bits)
#: the most bytes a 16-bit PNG may inflate to (a 12000 × 12000 RGB image), checked on its header
MAX_PNG_BYTES = 1 << 30


def _chunk(kind: bytes, data: bytes) -> bytes:
    return (
        struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
    )


def _png_chunks(data: bytes, path: Path) -> tuple[tuple[int, ...], bytes]:
    """IHDR fields (width, height, depth, colour type, interlace) and the joined IDAT payload."""
    pos, ihdr, idat = 8, None, []
    while pos + 8 <= len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        kind, body = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + length]
        if kind == b"IHDR" and len(body) == 13:
            w, h, depth, ctype, _, _, interlace = struct.unpack(">IIBBBBB", body)
            ihdr = (w, h, depth, ctype, interlace)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
        pos += 12 + length
    if ihdr is None or not idat:
        raise InputError("PNG has no IHDR or IDAT chunk (truncated file?)", path=path)
    return ihdr, b"".join(idat)


def decode_png16(data: bytes, path: Path) -> np.ndarray:
    """Decode a non-interlaced 16-bit PNG.

    Returns:
        (H, W, C) uint16 with C = 1 (gray), 2 (gray+alpha), 3 (RGB) or 4 (RGBA).
    """
    (w, h, depth, ctype, interlace), payload = _png_chunks(data, path)
    if depth != 16 or ctype not in _PNG_CHANNELS:
        raise InputError(f"expected a 16-bit PNG, found bit depth {depth}, colour type {ctype}", path=path)
    if interlace:
        raise InputError("interlaced 16-bit PNGs are not supported: save it without interlacing", path=path)
    c = _PNG_CHANNELS[ctype]
    expected = h * (1 + w * 2 * c)
    if expected > MAX_PNG_BYTES:  # checked on the header, before anything is inflated
        raise InputError(
            f"a {w}×{h} 16-bit PNG inflates to {expected} bytes, over the {MAX_PNG_BYTES}-byte limit "
            "(a decompression bomb, or an image far too large)",
            path=path,
        )
    try:
        inflater = zlib.decompressobj()
        raw = inflater.decompress(payload, expected)  # never more than the header allows
        if inflater.unconsumed_tail and inflater.decompress(inflater.unconsumed_tail, 1):
            raise InputError(f"PNG holds more data than its {w}×{h} header allows", path=path)
    except zlib.error as err:
        raise InputError(f"corrupt PNG data ({err})", path=path) from err
    raw = np.frombuffer(raw, dtype=np.uint8)
    if raw.size != expected:
        raise InputError(f"PNG data has {raw.size} bytes, expected {expected}", path=path)
    rows = raw.reshape(h, 1 + w * 2 * c)
    filters, samples = rows[:, :1], rows[:, 1:].reshape(h, w, c, 2)
    halves = []
    for byte in (0, 1):  # big-endian: high byte, then low byte
        half = np.concatenate([filters, samples[..., byte].reshape(h, w * c)], axis=1)
        png8 = (
            _PNG_SIGNATURE
            + _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, ctype, 0, 0, 0))
            + _chunk(b"IDAT", zlib.compress(half.tobytes(), 1))
            + _chunk(b"IEND", b"")
        )
        with Image.open(io.BytesIO(png8)) as im:
            halves.append(np.asarray(im).reshape(h, w, c).astype(np.uint16))
    return (halves[0] << 8) | halves[1]


def _png(width: int, height: int, depth: int, ctype: int, scanlines: bytes, level: int = 6) -> bytes:
    ihdr = struct.pack(">IIBBBBB", width, height, depth, ctype, 0, 0, 0)
    return (
        _PNG_SIGNATURE
        + _chunk(b"IHDR", ihdr)
        + _chunk(b"IDAT", zlib.compress(scanlines, level))
        + _chunk(b"IEND", b"")
    )


def encode_png16(image: np.ndarray) -> bytes:
    """A 16-bit RGB PNG (Up-filtered rows) of display values in [0, 1] (H, W, 3), rounded to 1/65535."""
    q = np.round(np.clip(image, 0.0, 1.0) * 65535.0).astype(">u2")
    h, w, c = q.shape
    rows = q.reshape(h, w * c).view(np.uint8)  # big-endian bytes, 2·W·C per row
    up = np.diff(rows, axis=0, prepend=np.zeros((1, rows.shape[1]), np.uint8))  # uint8 wraps: PNG "Up"
    return _png(w, h, 16, 2, np.concatenate([np.full((h, 1), 2, np.uint8), up], axis=1).tobytes())


def is_png16(data: bytes) -> bool:
    """True when ``data`` starts like a PNG whose IHDR says 16 bits per sample."""
    return data[:8] == _PNG_SIGNATURE and len(data) > 24 and data[24] == 16
