"""Pictures of MERL tables: the half/difference slice view.

The standard way to look at an isotropic BRDF table (Burley 2012, "Physically-Based Shading
at Disney", Sec. 3, after Matusik et al. 2003): the slice at ``phi_d = 90 deg`` drawn as an
image with ``theta_h`` along the horizontal axis (0 at the left, 90 deg at the right, in
the table's square-root spacing, so the specular peak is a band along the left edge) and
``theta_d`` along the vertical axis (0 at the top, 90 deg at the bottom, where Fresnel
grazing effects show). One pixel per bin, enlarged by ``scale`` with nearest-neighbour
repetition.
"""

from __future__ import annotations

import io
from typing import Literal

import numpy as np
from PIL import Image

from storage.formats.merl import MerlTable

#: Colour of missing (negative) bins, sRGB 8-bit: a dark blue-grey.
MISSING_RGB = (40, 44, 64)


def _srgb_encode(x: np.ndarray) -> np.ndarray:
    """Linear [0, 1] to sRGB-encoded [0, 1] (IEC 61966-2-1)."""
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def halfdiff_slice(table: MerlTable, *, phi_d_deg: float = 90.0) -> np.ndarray:
    """The ``(90, 90, 3)`` slice ``[theta_d, theta_h, channel]`` of physical values (1/sr).

    ``phi_d_deg`` picks the 1-degree phi_d bin containing it (both variants use 1-degree
    bins); negative values mark missing bins as in the table.
    """
    n_p = table.phi_d_bins
    period = 180.0 if n_p == 180 else 360.0
    k = min(int(np.floor((phi_d_deg % period) / period * n_p)), n_p - 1)
    return np.transpose(table.rgb[:, :, k, :], (1, 0, 2))


def halfdiff_slice_png(
    table: MerlTable,
    *,
    phi_d_deg: float = 90.0,
    scale: int = 4,
    tonemap: Literal["reinhard", "log"] = "reinhard",
    exposure: float = 1.0,
) -> bytes:
    """PNG bytes of the tone-mapped half/diff slice (see the module docstring for axes).

    Tone mapping, on ``x = exposure * pi * f`` per channel (so a white Lambertian maps to
    ``x = exposure``):

    - ``"reinhard"``: ``x / (1 + x)``, then the sRGB transfer curve; independent of the
      table's range, so pictures of different tables compare directly;
    - ``"log"``: ``log(1 + x) / log(1 + x_max)`` with ``x_max`` the slice maximum, then
      sRGB; shows the structure of very glossy tables.

    Missing bins are drawn in :data:`MISSING_RGB`. The output is deterministic (8-bit RGB,
    no metadata, fixed compression level). Returns a ``(90 scale) x (90 scale)`` image.
    """
    if scale < 1:
        raise ValueError(f"scale must be >= 1, got {scale}")
    values = halfdiff_slice(table, phi_d_deg=phi_d_deg)
    missing = np.any(values < 0, axis=-1)
    x = np.where(values < 0, 0.0, values) * (exposure * np.pi)
    if tonemap == "reinhard":
        y = x / (1.0 + x)
    elif tonemap == "log":
        top = float(np.max(x)) if x.size else 0.0
        y = np.log1p(x) / np.log1p(top) if top > 0 else np.zeros_like(x)
    else:
        raise ValueError(f"tonemap must be 'reinhard' or 'log', got {tonemap!r}")
    pixels = np.round(_srgb_encode(y) * 255.0).astype(np.uint8)
    pixels[missing] = MISSING_RGB
    pixels = np.repeat(np.repeat(pixels, scale, axis=0), scale, axis=1)
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format="PNG", compress_level=6)
    return buffer.getvalue()
