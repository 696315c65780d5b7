"""Pictures of a fabric dataset: the Fig. 2-style component preview and the per-material
normal and orientation maps (Chen, Wang & Wang 2024)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from evaluators.metrics.tonemap import magma
from materials.fabric.aggregate import FootprintQueries, estimate
from materials.fabric.params import FabricParams
from materials.fabric.yarn import rasterize
from storage.formats.exr import exr_bytes
from storage.formats.png import write_png

if TYPE_CHECKING:
    from generators.fabric.kind import PlannedFabric

PREVIEW_GRID, PREVIEW_SIZE, PREVIEW_SAMPLES, PREVIEW_ROWS = 32, 1.0 / 32.0, 64, 8
_PREVIEW_WI = np.array([0.5, 0.2, 0.8426149773176358])  # theta_i ~ 33 deg, unit
_PREVIEW_WO = np.array([-0.4, -0.3, 0.8660254037844386])  # theta_o = 30 deg, unit


def map_images(params: FabricParams, resolution: int) -> tuple[bytes, bytes]:
    """Normal and orientation EXR bytes of one tile, row 0 at the top (highest ``t``)."""
    maps = rasterize(params, resolution)
    return exr_bytes(np.flipud(maps.normal)), exr_bytes(np.flipud(maps.tangent))


def preview_png(materials: Sequence[PlannedFabric], seed: int) -> bytes:
    """Fig. 2-style preview: components (columns) over the tile, one row per material.

    Each panel is the estimate at ``PREVIEW_GRID^2`` footprint centres, footprint
    ``PREVIEW_SIZE`` tiles, light ``_PREVIEW_WI``, view ``_PREVIEW_WO`` (numpy backend),
    each component scaled by its 99th percentile over the rows and coloured with magma; ``t`` up.
    """
    g = PREVIEW_GRID
    c = (np.arange(g) + 0.5) / g
    t, s = np.meshgrid(c, c, indexing="ij")
    n = g * g
    queries = FootprintQueries(
        np.stack([s.ravel(), t.ravel()], axis=1),
        np.full(n, PREVIEW_SIZE),
        np.tile(_PREVIEW_WI, (n, 1)),
        np.tile(_PREVIEW_WO, (n, 1)),
    )
    panels = []
    for m in materials:
        est = estimate(m.params, queries, samples=PREVIEW_SAMPLES, seed=seed, backend="numpy")
        panels.append(est.mean.T.reshape(4, g, g)[:, ::-1])  # rows: t down the image
    values = np.stack(panels)  # (rows, 4, g, g)
    scale = np.ones(4)
    for k in range(4):  # each component on its own scale, as Fig. 2 shows them
        positive = values[:, k][values[:, k] > 0]
        scale[k] = float(np.percentile(positive, 99)) if positive.size else 1.0
    scaled = values / scale[None, :, None, None]
    colours = magma(scaled.reshape(-1, g)).reshape(len(materials), 4, g, g, 3)
    big = colours.repeat(2, axis=2).repeat(2, axis=3)  # 64 px panels
    gap, side = 2, 2 * g
    top, left = _HEADER_PX, _LABEL_PX
    h = top + len(materials) * (side + gap) + gap
    w = left + 4 * (side + gap) + gap
    image = np.full((h, w, 3), 255, dtype=np.uint8)
    for r in range(len(materials)):
        for k in range(4):
            y, x = top + gap + r * (side + gap), left + gap + k * (side + gap)
            image[y : y + side, x : x + side] = big[r, k]
    return write_png(None, _labelled(image, [m.pattern for m in materials], side, gap))


#: Space for the component names above the panels and the pattern names left of them.
_HEADER_PX, _LABEL_PX = 14, 64
_COMPONENT_LABELS = ("C warp", "C weft", "S warp", "S weft")


def _labelled(image: np.ndarray, rows: Sequence[str], side: int, gap: int) -> np.ndarray:
    """``image`` with the component names over the columns and the patterns by the rows
    (Pillow's built-in bitmap font, so the bytes do not depend on installed fonts)."""
    from PIL import Image, ImageDraw, ImageFont

    pic = Image.fromarray(image)
    draw = ImageDraw.Draw(pic)
    font = ImageFont.load_default_imagefont()
    for k, label in enumerate(_COMPONENT_LABELS):
        draw.text((_LABEL_PX + gap + k * (side + gap) + 2, 1), label, fill=(0, 0, 0), font=font)
    for r, label in enumerate(rows):
        y = _HEADER_PX + gap + r * (side + gap) + side // 2 - 5
        draw.text((2, y), label[:10], fill=(0, 0, 0), font=font)
    return np.asarray(pic)
