"""Normal maps: the tiny examples of the glint kinds (``*.normal.exr``, ``*.normal.png``).

Conventions (those of :mod:`materials.glints.examples`): ``(n, n, 3)`` tangent-space unit
normals, z up, ``[row = y, column = x]``; the side a power of two; ``z > 0``. An EXR stores
the normals themselves as float; an 8-bit PNG stores ``(n + 1) / 2``. Uploads whose name
ends in ``.normal.exr`` or ``.normal.png`` are checked as normal maps, not just as images,
and refused with a :class:`FormatError` naming the file and what is wrong.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from storage.errors import FormatError
from storage.formats.exr import read_exr
from storage.formats.png import read_png

#: How far a stored normal may be from unit length: float EXR maps, and 8-bit PNG maps
#: (quantisation of ``(n + 1) / 2`` to 1/255 moves the length by up to about 0.7 %).
UNIT_TOL_FLOAT = 1e-3
UNIT_TOL_8BIT = 0.02
#: The file-name endings that mark a normal map.
SUFFIXES = (".normal.exr", ".normal.png")


def check_normal_map(normals: np.ndarray, name: str, *, tol: float = UNIT_TOL_FLOAT) -> None:
    """Refuse a normal map that breaks the conventions: :class:`FormatError` naming ``name``
    and saying what is wrong (shape, size, length, z)."""
    a = np.asarray(normals)
    if a.ndim != 3 or a.shape[2] != 3:
        raise FormatError(name, f"a normal map has shape (n, n, 3), got {a.shape}")
    if a.shape[0] != a.shape[1]:
        raise FormatError(name, f"a normal map must be square, got {a.shape[1]}x{a.shape[0]}")
    n = a.shape[0]
    if n < 2 or n & (n - 1):
        raise FormatError(name, f"the side must be a power of two, got {n}")
    if not np.all(np.isfinite(a)):
        raise FormatError(name, "the normal map holds NaN or infinite values")
    length = np.linalg.norm(a.astype(np.float64), axis=-1)
    worst = float(np.abs(length - 1.0).max())
    if worst > tol:
        iy, ix = np.unravel_index(int(np.abs(length - 1.0).argmax()), length.shape)
        raise FormatError(
            name,
            f"normals must have unit length (within {tol:g}); texel (x={ix}, y={iy}) "
            f"has length {length[iy, ix]:.4f}",
        )
    if float(a[..., 2].min()) <= 0.0:
        iy, ix = np.unravel_index(int(a[..., 2].argmin()), a.shape[:2])
        raise FormatError(
            name,
            f"tangent-space normals must point up (z > 0); texel (x={ix}, y={iy}) "
            f"has z = {a[iy, ix, 2]:.4f}",
        )


def normals_from_rgb(rgb: np.ndarray, name: str, *, encoded: bool) -> np.ndarray:
    """A user's normal map as ``(n, n, 3)`` float32 unit normals, checked.

    ``encoded=True`` for 8-bit images (PNG), which store ``(n + 1) / 2`` in [0, 1]; they are
    decoded, checked with the quantisation tolerance :data:`UNIT_TOL_8BIT`, and renormalised.
    ``encoded=False`` for float images (EXR), which store the normals themselves and are
    checked to :data:`UNIT_TOL_FLOAT`. :class:`FormatError` names ``name`` on any violation.
    """
    a = np.asarray(rgb, dtype=np.float64)
    if encoded:
        a = 2.0 * a - 1.0
    check_normal_map(a, name, tol=UNIT_TOL_8BIT if encoded else UNIT_TOL_FLOAT)
    return (a / np.linalg.norm(a, axis=-1, keepdims=True)).astype(np.float32)


def read_normal_map(path: str | Path, name: str | None = None) -> np.ndarray:
    """Read and check a normal map (EXR: float normals; PNG: ``(n + 1) / 2``), returning
    ``(n, n, 3)`` float32 unit normals. :class:`FormatError` names ``name`` on any problem."""
    p = Path(path)
    label = name or str(p)
    if label.lower().endswith(".png") or p.suffix.lower() == ".png":
        return normals_from_rgb(read_png(p, label), label, encoded=True)
    return normals_from_rgb(read_exr(p, label), label, encoded=False)


def validate_normal_map(path: str | Path, name: str | None = None) -> None:
    """Check that ``path`` is a normal map (see :func:`read_normal_map`)."""
    read_normal_map(path, name)
