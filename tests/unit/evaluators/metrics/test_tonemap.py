"""Display mapping against closed forms.

Oracles: the sRGB transfer function written out from IEC 61966-2-1 (12.92 x below
0.0031308, 1.055 x^(1/2.4) - 0.055 above), Narkowicz's ACES polynomial and Reinhard's
x / (1 + x) evaluated by hand, and matplotlib's magma table.
"""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib import colormaps

from evaluators.metrics.tonemap import aces_filmic, magma, reinhard, srgb_encode, tonemap


def srgb_closed_form(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def test01_curves_and_encoding() -> None:
    x = np.array([0.0, 0.001, 0.0031308, 0.18, 0.5, 1.0])
    np.testing.assert_allclose(srgb_encode(x), srgb_closed_form(x), atol=1e-12)
    assert reinhard(np.array([1.0]))[0] == 0.5
    assert aces_filmic(np.array([1.0]))[0] == pytest.approx(2.54 / 3.16)
    assert aces_filmic(np.array([1e6]))[0] == 1.0 and aces_filmic(np.array([0.0]))[0] == 0.0


def test02_tonemap_pipeline() -> None:
    rgb = np.array([[[0.18, 0.5, 2.0], [np.nan, -1.0, np.inf]]], dtype=np.float32)
    out = tonemap(rgb, curve="reinhard", exposure=1.0)
    assert out.dtype == np.uint8 and out.shape == (1, 2, 3)
    expected = np.rint(srgb_closed_form(reinhard(np.array([0.36, 1.0, 4.0]))) * 255)
    np.testing.assert_array_equal(out[0, 0], expected.astype(np.uint8))
    np.testing.assert_array_equal(out[0, 1], [0, 0, 255])  # NaN and negative -> 0, inf -> 1
    assert tonemap(np.ones((2, 2, 3)), curve="clamp")[0, 0, 0] == 255
    with pytest.raises(ValueError, match="tone curve"):
        tonemap(rgb, curve="drago")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        tonemap(rgb[..., 0])


def test03_magma_matches_matplotlib() -> None:
    values = np.array([[0.0, 0.5, 1.0, 2.0]])
    out = magma(values)
    table = colormaps["magma"](np.linspace(0, 1, 256))[:, :3]
    for v, px in zip([0.0, 0.5, 1.0, 1.0], out[0], strict=True):
        np.testing.assert_array_equal(px, np.rint(table[round(v * 255)] * 255).astype(np.uint8))
