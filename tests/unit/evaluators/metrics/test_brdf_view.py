"""The half/diff slice picture: axes, tone mapping, missing bins, determinism.

Oracles: the PNG decoded by Pillow; pixel positions computed from the documented axes
(theta_h to the right, theta_d downwards); the Reinhard curve and sRGB encoding evaluated
here for a constant table.
"""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from evaluators.metrics.brdf_view import MISSING_RGB, halfdiff_slice_png
from storage.formats.merl import MerlTable


def decode(data: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))


def test01_constant_table_and_size() -> None:
    table = MerlTable(rgb=np.full((90, 90, 180, 3), 1.0 / np.pi))  # white Lambertian
    img = decode(halfdiff_slice_png(table, scale=2))
    assert img.shape == (180, 180, 3)
    # x = pi f = 1 -> Reinhard 0.5 -> sRGB 0.7354 -> 188
    assert np.all(img == 188)


def test02_axes_and_missing() -> None:
    rgb = np.zeros((90, 90, 180, 3))
    rgb[0, :, 90, 0] = 10.0  # theta_h = 0 column (left edge) at phi_d = 90 deg, red
    rgb[:, 89, 90, 2] = 10.0  # theta_d = 90 deg row (bottom), blue
    rgb[45, 45, 90] = -1.0  # one missing bin
    rgb[:, :, 10] = 5.0  # another phi_d slice must not show
    img = decode(halfdiff_slice_png(MerlTable(rgb=rgb), scale=1))
    assert np.all(img[:89, 0, 0] > 200) and np.all(img[:89, 0, 2] == 0)
    assert np.all(img[89, 1:, 2] > 200) and np.all(img[89, 1:, 0] == 0)
    assert tuple(img[45, 45]) == MISSING_RGB
    assert img[10, 10].sum() == 0


def test03_deterministic_and_log_mode() -> None:
    rng = np.random.default_rng(0)
    table = MerlTable(rgb=rng.lognormal(-1.0, 2.0, (90, 90, 180, 3)))
    assert halfdiff_slice_png(table) == halfdiff_slice_png(table)
    log_img = decode(halfdiff_slice_png(table, tonemap="log", scale=1))
    assert log_img.max() == 255
    with pytest.raises(ValueError, match="tonemap"):
        halfdiff_slice_png(table, tonemap="aces")  # type: ignore[arg-type]
