"""The high-pass correlation of two glint renders: are their glints the same glints?

Glints are fixed to the material: two renders with different sampler seeds show the same
sparkle pattern, while Monte Carlo speckle is new in each. Both live at the scale of a few
pixels, on top of a highlight whose smooth envelope every render of the scene shares
(with or without glints), so the images are compared after:

1. luminance (Rec. 709), divided by its mean and passed through ``log1p``: glints span
   orders of magnitude, and a Pearson correlation of linear values is decided by its few
   brightest pixels;
2. minus a Gaussian blur of :data:`HIGHPASS_SIGMA` pixels: removes the envelope (tens of
   pixels wide), keeps the 1-3 pixel structure where glints at 1-4 example texels per
   pixel, and per-pixel noise, are.

The Pearson correlation of the two high-pass images is then about glint energy / (glint +
noise energy): 1 for noise-free glints, 0 for pure speckle.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

#: Standard deviation (pixels) of the blur that the high-pass filter subtracts.
HIGHPASS_SIGMA = 2.0
_LUMA = np.array([0.2126, 0.7152, 0.0722])


def highpass(image: np.ndarray, sigma: float = HIGHPASS_SIGMA) -> np.ndarray:
    """The high-pass image of an ``(H, W, 3)`` linear render (module docstring)."""
    lum = np.asarray(image, np.float64)[..., :3] @ _LUMA
    x = np.log1p(lum / max(float(lum.mean()), 1e-12))
    return x - gaussian_filter(x, sigma, mode="nearest")


def highpass_correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of the high-pass images of ``a`` and ``b``."""
    ha, hb = highpass(a).ravel(), highpass(b).ravel()
    return float(np.corrcoef(ha, hb)[0, 1])
