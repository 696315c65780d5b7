"""OpenEXR images: linear RGB, float32, with deterministic bytes.

Conventions: arrays are ``(H, W, 3)`` float32, row 0 at the top, channels R, G, B in linear
(scene-referred) units. Files are single-part scanline images with ZIP compression and a
minimal header (no timestamps, no software tags), so the same pixels always give the same
bytes on the same OpenEXR version; matforge's content-addressed store and its byte-for-byte
reproducibility rely on that.

Reading accepts any scanline or tiled EXR with ``R``, ``G`` and ``B`` channels (half, float
or uint; an ``A`` channel is ignored) and raises :class:`storage.errors.FormatError`, naming
the file, on anything else.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenEXR

from storage.errors import FormatError

#: The largest image read or validated, per side, in pixels (a guard against huge headers).
MAX_SIDE = 32768
#: The most pixels read or validated (8192 x 4096): checked from the header before any
#: pixel is decoded, so a small file cannot claim gigabytes of pixels.
MAX_PIXELS = 1 << 25
_MAGIC = b"\x76\x2f\x31\x01"


@dataclass(frozen=True)
class ExrInfo:
    """What :func:`validate_exr` found: size in pixels and channel names."""

    width: int
    height: int
    channels: tuple[str, ...]


def _header() -> dict:
    # A fresh dict each time: OpenEXR.File fills the dict it is given in place
    # (dataWindow, channels, ...), so a shared header would leak one image's size into
    # the next write.
    return {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}


def _check_rgb(rgb: np.ndarray) -> np.ndarray:
    arr = np.asarray(rgb)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ValueError(f"an RGB image must have shape (H, W, 3), got {arr.shape}")
    if arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ValueError(f"an RGB image must not be empty, got shape {arr.shape}")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise ValueError(f"an RGB image must be numeric, got dtype {arr.dtype}")
    return np.ascontiguousarray(arr, dtype=np.float32)


def exr_bytes(rgb: np.ndarray) -> bytes:
    """Encode an ``(H, W, 3)`` linear RGB image as EXR bytes (float32, ZIP, deterministic).

    The input is converted to float32 (non-finite values are stored as they are).
    """
    arr = _check_rgb(rgb)
    buf = io.BytesIO()
    with OpenEXR.File(_header(), {"RGB": arr}) as f:
        f.write(buf)
    return buf.getvalue()


def write_exr(path: str | Path, rgb: np.ndarray) -> None:
    """Write an ``(H, W, 3)`` linear RGB image to ``path`` (see :func:`exr_bytes`)."""
    Path(path).write_bytes(exr_bytes(rgb))


def _open(path: Path, name: str, header_only: bool) -> OpenEXR.File:
    try:
        with open(path, "rb") as fh:
            magic = fh.read(4)
    except OSError as exc:
        raise FormatError(name, f"cannot read: {exc.strerror or exc}") from None
    if magic != _MAGIC:
        raise FormatError(name, "not an OpenEXR file (bad magic number)")
    try:
        return OpenEXR.File(str(path), separate_channels=True, header_only=header_only)
    except Exception as exc:  # OpenEXR raises RuntimeError/ValueError with C++ messages
        raise FormatError(name, f"unreadable OpenEXR file: {_first_line(exc)}") from None


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def check_exr_size(width: int, height: int, name: str) -> None:
    """Refuse a size :func:`read_exr` would not decode (over :data:`MAX_SIDE` per side or
    :data:`MAX_PIXELS` in all), naming ``name`` and the size."""
    if width > MAX_SIDE or height > MAX_SIDE:
        raise FormatError(
            name,
            f"image of {width}x{height} pixels exceeds the limit of {MAX_SIDE} pixels per side",
        )
    if width * height > MAX_PIXELS:
        raise FormatError(
            name,
            f"image of {width}x{height} pixels exceeds the limit of {MAX_PIXELS} pixels",
        )


def _info(f: OpenEXR.File, name: str, check_limits: bool = True) -> ExrInfo:
    header = f.header()
    try:
        (x0, y0), (x1, y1) = (tuple(int(v) for v in corner) for corner in header["dataWindow"])
    except (KeyError, TypeError, ValueError):
        raise FormatError(name, "OpenEXR header has no valid dataWindow") from None
    width, height = x1 - x0 + 1, y1 - y0 + 1
    if width < 1 or height < 1:
        raise FormatError(name, f"empty image ({width}x{height} pixels)")
    if check_limits:
        check_exr_size(width, height, name)
    channels = tuple(str(getattr(c, "name", c)) for c in header.get("channels", ()))
    missing = [c for c in ("R", "G", "B") if c not in channels]
    if missing:
        found = ", ".join(channels) or "none"
        raise FormatError(
            name,
            f"needs R, G and B channels; missing {', '.join(missing)} (channels found: {found})",
        )
    return ExrInfo(width=width, height=height, channels=channels)


def validate_exr(path: str | Path, name: str | None = None) -> ExrInfo:
    """Check that ``path`` is a readable RGB OpenEXR image and return its size and channels.

    Reads every pixel (so a truncated file is caught) but does not judge pixel values:
    NaN and infinity are legal in EXR and are refused later by the consumers that care.
    ``name`` is the file name used in error messages (default: the path).

    Raises
    ------
    FormatError
        Not an EXR, unreadable or truncated, empty, larger than :data:`MAX_SIDE` per side,
        or without R, G and B channels.
    """
    _, info = _read(Path(path), name or str(path))
    return info


def exr_header_info(
    path: str | Path, name: str | None = None, *, check_limits: bool = True
) -> ExrInfo:
    """Size and channels from the header alone (no pixels read): a cheap first check of
    many files. Raises :class:`FormatError` as :func:`validate_exr` does for the header;
    with ``check_limits`` false, a size over the readers' limits is returned, not refused
    (the caller checks it later with :func:`check_exr_size`)."""
    label = name or str(path)
    return _info(_open(Path(path), label, header_only=True), label, check_limits)


def read_exr(path: str | Path, name: str | None = None) -> np.ndarray:
    """Read an RGB OpenEXR image as an ``(H, W, 3)`` float32 array in linear units.

    Half and uint channels are converted to float32; alpha and other channels are ignored.
    Non-finite pixels are returned as they are. Raises :class:`FormatError` as
    :func:`validate_exr` does.
    """
    rgb, _ = _read(Path(path), name or str(path))
    return rgb


def _read(path: Path, name: str) -> tuple[np.ndarray, ExrInfo]:
    info = _info(_open(path, name, header_only=True), name)
    f = _open(path, name, header_only=False)
    try:
        channels = f.channels()
        planes = [np.asarray(channels[c].pixels) for c in ("R", "G", "B")]
    except Exception as exc:
        raise FormatError(
            name, f"cannot read pixels (truncated or corrupt?): {_first_line(exc)}"
        ) from None
    for plane in planes:
        if plane.shape != (info.height, info.width):
            raise FormatError(
                name,
                f"channel of shape {plane.shape} does not match the "
                f"{info.width}x{info.height} data window",
            )
    rgb = np.stack([p.astype(np.float32, copy=False) for p in planes], axis=-1)
    return np.ascontiguousarray(rgb), info
