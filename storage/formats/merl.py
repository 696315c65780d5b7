"""MERL isotropic BRDF tables (``.binary``): reader, writer and validation.

The layout is that of Matusik et al. 2003, "A Data-Driven Reflectance Model", as read by
MERL's reference code ``BRDFRead.cpp``:

1. three little-endian int32 dimensions, ``(90, 90, 180)``; matforge also accepts the
   unfolded ``(90, 90, 360)`` variant;
2. three float64 planes, R then G then B, each ``90 * 90 * P`` values in index order
   ``(theta_h, theta_d, phi_d)`` with ``phi_d`` fastest (see :mod:`materials.halfdiff` for
   the index mapping).

Scales: the reference lookup returns ``red = brdf[ind] * RED_SCALE`` with
``RED_SCALE = 1/1500``, ``GREEN_SCALE = 1.15/1500`` and ``BLUE_SCALE = 1.66/1500``. So the
file stores ``physical / scale`` (``physical * 1500`` for red) and the reader returns
``stored * scale``: :class:`MerlTable` always holds **physical** BRDF values in 1/sr.
Because ``(x / s) * s`` is not always ``x`` in floating point, a table survives a write and a
read to within one ulp (relative 2.3e-16), not bit for bit.

Negative entries mark missing or below-horizon data and are kept negative through the scale.
Anything else is refused with a :class:`~storage.errors.FormatError` naming the file: a file
shorter than the header, other dimensions, a size that does not match the dimensions, or a
NaN or infinite value.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from storage.errors import FormatError
from storage.formats.media import MEDIA_TYPES

#: Per-channel scales of the reference code: physical = stored * scale.
SCALES = (1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0)
#: The accepted dimension headers.
ACCEPTED_DIMS = ((90, 90, 180), (90, 90, 360))
#: Media type used by the artifact store and the upload route.
MEDIA_TYPE = MEDIA_TYPES[".binary"]
HEADER_BYTES = 12


@dataclass(frozen=True, eq=False)
class MerlTable:
    """An isotropic BRDF table in the MERL layout.

    Attributes
    ----------
    rgb
        ``(90, 90, phi_d_bins, 3)`` float64, physical BRDF values in 1/sr (no cosine),
        indexed ``(theta_h, theta_d, phi_d, channel)``; negative entries are missing.
    phi_d_bins
        180 (canonical, phi_d folded by reciprocity) or 360.
    """

    rgb: np.ndarray
    phi_d_bins: int = 180

    def __post_init__(self) -> None:
        if self.phi_d_bins not in (180, 360):
            raise ValueError(f"phi_d_bins must be 180 or 360, got {self.phi_d_bins}")
        shape = (90, 90, self.phi_d_bins, 3)
        if np.shape(self.rgb) != shape:
            raise ValueError(f"rgb must have shape {shape}, got {np.shape(self.rgb)}")
        object.__setattr__(self, "rgb", np.ascontiguousarray(self.rgb, dtype=np.float64))

    @property
    def missing(self) -> np.ndarray:
        """``(90, 90, P)`` bool: bins where any channel is negative."""
        return np.any(self.rgb < 0, axis=-1)


def merl_bytes(table: MerlTable) -> bytes:
    """The file contents of ``table``: deterministic, identical for identical arrays."""
    header = struct.pack("<3i", 90, 90, table.phi_d_bins)
    planes = [
        np.ascontiguousarray(table.rgb[..., c] / SCALES[c], dtype="<f8").tobytes() for c in range(3)
    ]
    return header + b"".join(planes)


def write_merl(path: str | os.PathLike[str], table: MerlTable) -> None:
    """Write ``table`` to ``path`` in the MERL layout (see the module docstring)."""
    Path(path).write_bytes(merl_bytes(table))


def merl_from_bytes(data: bytes, filename: str = "<bytes>") -> MerlTable:
    """Parse and validate MERL file contents; ``filename`` names the source in errors.

    Raises
    ------
    FormatError
        For a short file, unexpected dimensions, a size mismatch, or non-finite values.
    """
    if len(data) < HEADER_BYTES:
        raise FormatError(
            filename,
            f"not a MERL BRDF: {len(data)} bytes is shorter than "
            f"the {HEADER_BYTES}-byte header of three int32 dimensions",
        )
    dims = struct.unpack("<3i", data[:HEADER_BYTES])
    if dims not in ACCEPTED_DIMS:
        raise FormatError(
            filename, f"unexpected MERL dimensions {dims}; expected (90, 90, 180) or (90, 90, 360)"
        )
    n = dims[0] * dims[1] * dims[2]
    expected = HEADER_BYTES + 3 * n * 8
    if len(data) != expected:
        raise FormatError(
            filename,
            f"size mismatch for MERL dimensions {dims}: expected {expected} bytes, got {len(data)}",
        )
    stored = np.frombuffer(data, dtype="<f8", count=3 * n, offset=HEADER_BYTES)
    bad = ~np.isfinite(stored)
    if bad.any():
        first = int(np.argmax(bad))
        raise FormatError(
            filename,
            f"{int(bad.sum())} non-finite values (NaN or inf); first "
            f"in the {'RGB'[first // n]} plane at entry {first % n}",
        )
    planes = stored.reshape(3, dims[0], dims[1], dims[2])
    rgb = np.stack([planes[c] * SCALES[c] for c in range(3)], axis=-1)
    return MerlTable(rgb=rgb, phi_d_bins=dims[2])


def read_merl(path: str | os.PathLike[str], name: str | None = None) -> MerlTable:
    """Read and validate a MERL ``.binary`` file; errors are :class:`FormatError`.

    ``name`` is how errors name the file (e.g. the user's upload name); default ``path``.
    """
    label = str(path) if name is None else name
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise FormatError(label, f"cannot read file: {exc.strerror or exc}") from exc
    return merl_from_bytes(data, label)


def validate_merl(path: str | os.PathLike[str], name: str | None = None) -> None:
    """Raise :class:`FormatError` unless ``path`` is a valid MERL table.

    Signature of the ``storage.formats.VALIDATORS`` entries: ``(path, name)``.
    """
    read_merl(path, name)
