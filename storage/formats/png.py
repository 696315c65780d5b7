"""PNG images: 8-bit sRGB previews and error maps, with deterministic bytes.

Conventions: arrays are ``(H, W, 3)``, row 0 at the top. :func:`write_png` takes uint8
display values (already tone-mapped and sRGB-encoded); :func:`read_png` returns float32
values in ``[0, 1]``, still sRGB-encoded (divide by 255, or by 65535 for 16-bit files).

Written files carry no metadata (no text chunks, no timestamps, no gamma or ICC chunks) and
use a fixed zlib level, so the same pixels always give the same bytes with the same Pillow
and zlib.
"""

from __future__ import annotations

import io
import struct
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from storage.errors import FormatError

#: The largest image read, per side, in pixels (a guard against decompression bombs).
MAX_SIDE = 32768
#: The most pixels decoded (8192 x 4096), checked from the header first.
MAX_PIXELS = 1 << 25
_MAGIC = b"\x89PNG\r\n\x1a\n"
_COMPRESS_LEVEL = 6


def write_png(path: str | Path | None, rgb8: np.ndarray) -> bytes:
    """Encode an ``(H, W, 3)`` uint8 image as PNG; write it to ``path`` unless ``None``.

    Returns the encoded bytes either way.
    """
    arr = np.asarray(rgb8)
    if arr.dtype != np.uint8:
        raise ValueError(f"write_png needs uint8 pixels, got dtype {arr.dtype}")
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ValueError(f"write_png needs shape (H, W, 3), got {arr.shape}")
    img = Image.fromarray(np.ascontiguousarray(arr), mode="RGB")
    buf = io.BytesIO()
    img.save(buf, format="PNG", optimize=False, compress_level=_COMPRESS_LEVEL)
    data = buf.getvalue()
    if path is not None:
        Path(path).write_bytes(data)
    return data


def read_png(path: str | Path, name: str | None = None) -> np.ndarray:
    """Read a PNG as an ``(H, W, 3)`` float32 array of sRGB-encoded values in ``[0, 1]``.

    Grey images are replicated to three channels, palette images expanded, and alpha is
    dropped (not composited). ``name`` is the file name used in error messages.

    Raises
    ------
    FormatError
        Not a PNG, truncated or corrupt, empty, or larger than :data:`MAX_SIDE` per side.
    """
    levels, top = read_png_levels(path, name)
    return levels_to_float(levels, level_table(top))


def read_png_levels(path: str | Path, name: str | None = None) -> tuple[np.ndarray, int]:
    """A PNG's integer levels and the top level: ``(levels, 255)`` with uint8 ``(H, W, 3)``
    levels for 8-bit (and palette, 1-bit, alpha) images, ``(levels, 65535)`` with uint16
    ``(H, W)`` grey levels for 16-bit grey images (clipped to ``[0, 65535]``).

    The smallest form of the pixels: a slice decoder maps them through a 256 or 65536 entry
    table (:func:`levels_to_float`) instead of doing float64 arithmetic on every pixel,
    which took several full-size float64 copies of an 8192 x 4096 image. Raises
    :class:`FormatError` as :func:`read_png` does.
    """
    p = Path(path)
    label = name or str(p)
    width, height = png_size(p, label)
    check_png_size(width, height, label)  # before Pillow opens it: its bomb guard says less
    try:
        with Image.open(p, formats=["PNG"]) as img:
            img.load()
            if img.mode in ("I;16", "I;16B", "I;16L", "I"):
                # 16-bit grey: Pillow keeps it as integers (32-bit for mode "I").
                grey = np.asarray(img)
                if grey.dtype != np.uint16:
                    grey = np.clip(grey, 0, 65535).astype(np.uint16)
                return grey, 65535
            return np.asarray(img.convert("RGB"), dtype=np.uint8), 255
    except FormatError:
        raise
    except (
        UnidentifiedImageError,
        OSError,
        SyntaxError,
        ValueError,
        Image.DecompressionBombError,
    ) as exc:
        raise FormatError(label, f"unreadable PNG (truncated or corrupt?): {exc}") from None


def level_table(top: int) -> np.ndarray:
    """float32 ``level / top`` for every level ``0 .. top`` (computed in float64, rounded
    once: the values :func:`read_png` has always returned)."""
    return (np.arange(top + 1, dtype=np.float64) / float(top)).astype(np.float32)


def levels_to_float(levels: np.ndarray, table: np.ndarray) -> np.ndarray:
    """``(H, W, 3)`` float32 ``table[levels]``; grey ``(H, W)`` levels are replicated to
    three channels. One float32 image is allocated (plus a grey plane for grey images)."""
    if levels.ndim == 2:
        return np.ascontiguousarray(np.repeat(table[levels][..., None], 3, axis=-1))
    return np.ascontiguousarray(table[levels])


def png_size(path: str | Path, name: str | None = None) -> tuple[int, int]:
    """``(width, height)`` from the PNG header alone (no pixels decoded, no limit applied):
    the ``IHDR`` chunk, which the format puts first, read as 24 bytes. A size that no reader
    accepts (a 100000 x 100000 header in a 300-byte file) is reported to the caller, which
    names it (:func:`check_png_size`); Pillow's own decompression-bomb guard is not in the
    way of saying so."""
    p = Path(path)
    label = name or str(p)
    try:
        with open(p, "rb") as fh:
            head = fh.read(len(_MAGIC) + 16)
    except OSError as exc:
        raise FormatError(label, f"cannot read: {exc.strerror or exc}") from None
    if head[: len(_MAGIC)] != _MAGIC:
        raise FormatError(label, "not a PNG file (bad signature)")
    length, chunk, width, height = struct.unpack(">I4sII", head[len(_MAGIC) :].ljust(16, b"\0"))
    if len(head) < len(_MAGIC) + 16 or chunk != b"IHDR" or length != 13:
        raise FormatError(label, "unreadable PNG header: the first chunk is not a whole IHDR")
    if width < 1 or height < 1:
        raise FormatError(label, f"empty image ({width}x{height} pixels)")
    return int(width), int(height)


def check_png_size(width: int, height: int, name: str) -> None:
    """Refuse a size :func:`read_png_levels` would not decode (over :data:`MAX_SIDE` per side
    or :data:`MAX_PIXELS` in all), naming ``name`` and the size."""
    if width > MAX_SIDE or height > MAX_SIDE:
        raise FormatError(
            name,
            f"image of {width}x{height} pixels exceeds the limit of {MAX_SIDE} pixels per side",
        )
    if width * height > MAX_PIXELS:
        raise FormatError(
            name, f"image of {width}x{height} pixels exceeds the limit of {MAX_PIXELS} pixels"
        )


def validate_png(path: str | Path, name: str | None = None) -> tuple[int, int]:
    """Check that ``path`` is a readable PNG (every pixel decoded); returns
    ``(width, height)``."""
    levels, _ = read_png_levels(path, name)
    return levels.shape[1], levels.shape[0]
