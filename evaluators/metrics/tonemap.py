"""Display mapping: from linear scene-referred RGB to 8-bit sRGB, and error-map colouring.

The pipeline of :func:`tonemap` is explicit and fixed, so previews are reproducible:

1. **Exposure**: multiply by ``2**exposure`` (``exposure`` in photographic stops).
2. **Tone curve**, per channel, mapping ``[0, inf)`` into ``[0, 1]``:

   - ``"aces"``: Narkowicz's fit of the ACES filmic reference rendering transform,
     ``f(x) = x (2.51 x + 0.03) / (x (2.43 x + 0.59) + 0.14)``, clamped to ``[0, 1]``
     (K. Narkowicz, "ACES Filmic Tone Mapping Curve", 2015). This is also the default curve
     HDR-FLIP uses (with a 0.6 pre-exposure), so previews look like what FLIP judged.
   - ``"reinhard"``: ``f(x) = x / (1 + x)`` (Reinhard et al., "Photographic Tone Reproduction
     for Digital Images", SIGGRAPH 2002, Eq. 3 without the white point).
   - ``"clamp"``: ``f(x) = min(x, 1)``, for images that are already display-referred.

3. **Encoding**: the sRGB transfer function (IEC 61966-2-1) from colour-science, then
   quantisation by rounding to the nearest of 256 levels.

NaN and negative values become 0 and ``+inf`` becomes 1 before the curve, so a broken pixel
shows as black or white instead of breaking the preview.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

ToneCurve = Literal["aces", "reinhard", "clamp"]
TONE_CURVES: tuple[str, ...] = ("aces", "reinhard", "clamp")


def aces_filmic(x: np.ndarray) -> np.ndarray:
    """Narkowicz (2015) ACES filmic fit, ``[0, inf) -> [0, 1]``, elementwise (float64)."""
    x = np.asarray(x, dtype=np.float64)
    return np.clip(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0)


def reinhard(x: np.ndarray) -> np.ndarray:
    """Reinhard et al. (2002) global operator ``x / (1 + x)``, elementwise (float64)."""
    x = np.asarray(x, dtype=np.float64)
    return x / (1.0 + x)


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer function (IEC 61966-2-1) on values in ``[0, 1]`` (float64 out).

    Uses ``colour.cctf_encoding(..., function="sRGB")``; inputs are clipped to ``[0, 1]``.
    """
    import colour  # imported here: colour-science takes ~1 s to import

    x = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    return np.asarray(colour.cctf_encoding(x, function="sRGB"), dtype=np.float64)


def quantize8(display: np.ndarray) -> np.ndarray:
    """Display values in ``[0, 1]`` to uint8 by rounding half to even (``np.rint``)."""
    return np.rint(np.clip(display, 0.0, 1.0) * 255.0).astype(np.uint8)


def tonemap(rgb: np.ndarray, *, exposure: float = 0.0, curve: ToneCurve = "aces") -> np.ndarray:
    """Map a linear ``(H, W, 3)`` RGB image to an ``(H, W, 3)`` uint8 sRGB image.

    Parameters
    ----------
    rgb
        Linear scene-referred radiance, any float or integer dtype, shape ``(H, W, 3)``.
    exposure
        Exposure adjustment in stops: values are scaled by ``2**exposure`` first.
    curve
        The tone curve, one of :data:`TONE_CURVES` (see the module docstring).
    """
    arr = np.asarray(rgb)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ValueError(f"tonemap needs shape (H, W, 3), got {arr.shape}")
    if curve not in TONE_CURVES:
        raise ValueError(f"unknown tone curve {curve!r}; known: {', '.join(TONE_CURVES)}")
    if not np.isfinite(exposure):
        raise ValueError(f"exposure must be finite, got {exposure}")
    x = np.nan_to_num(arr.astype(np.float64), nan=0.0, posinf=np.inf, neginf=0.0)
    x = np.maximum(x, 0.0) * 2.0 ** float(exposure)
    if curve == "aces":
        mapped = aces_filmic(np.minimum(x, 1e30))
    elif curve == "reinhard":
        mapped = reinhard(np.minimum(x, 1e300))
    else:
        mapped = np.minimum(x, 1.0)
    return quantize8(srgb_encode(mapped))


def magma(values: np.ndarray) -> np.ndarray:
    """Colour an ``(H, W)`` map of values in ``[0, 1]`` with the magma colormap, as uint8.

    Uses matplotlib's 256-entry magma table with the index ``round(255 v)``: the colormap
    NVIDIA's FLIP uses for its error maps (its own table agrees to within 2/255). NaN maps
    to index 0; values are clipped to ``[0, 1]``. Returns ``(H, W, 3)`` uint8 sRGB.
    """
    v = np.asarray(values, dtype=np.float64)
    if v.ndim == 3 and v.shape[2] == 1:
        v = v[..., 0]
    if v.ndim != 2:
        raise ValueError(f"magma needs an (H, W) map, got shape {v.shape}")
    idx = np.rint(np.clip(np.nan_to_num(v, nan=0.0), 0.0, 1.0) * 255.0).astype(np.intp)
    return magma_table()[idx]


def magma_table() -> np.ndarray:
    """The ``(256, 3)`` uint8 sRGB table :func:`magma` colours with (matplotlib's magma)."""
    from matplotlib import colormaps  # imported here: only error-map users need it

    return quantize8(np.asarray(colormaps["magma"](np.linspace(0.0, 1.0, 256)))[:, :3])


def magma_values(rgb: np.ndarray) -> np.ndarray:
    """The values in ``[0, 1]`` that :func:`magma` coloured: the inverse of ``magma`` on its
    own output, exact to the table step (``1/255``), for the compare view's readout of a FLIP
    map. ``rgb`` is ``(H, W, 3)``: uint8 levels, or floats in ``[0, 1]`` (as ``read_png``
    gives). A colour not in the table maps to its nearest entry (squared sRGB distance).
    Returns ``(H, W)`` float32."""
    a = np.asarray(rgb)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"magma_values needs an (H, W, 3) image, got shape {a.shape}")
    levels = a if a.dtype == np.uint8 else np.rint(np.clip(a, 0.0, 1.0) * 255.0).astype(np.uint8)
    keys = levels.astype(np.int32) @ np.array([65536, 256, 1], np.int32)
    unique, inverse = np.unique(keys.ravel(), return_inverse=True)
    colours = np.stack([unique >> 16, (unique >> 8) & 255, unique & 255], axis=1).astype(np.int32)
    table = magma_table().astype(np.int32)
    nearest = np.empty(len(unique), np.intp)
    for i in range(0, len(unique), 4096):  # bounds the (n, 256) distances
        d = ((colours[i : i + 4096, None, :] - table[None]) ** 2).sum(axis=2)
        nearest[i : i + 4096] = d.argmin(axis=1)
    return (nearest[inverse].reshape(keys.shape) / 255.0).astype(np.float32)
