"""``preview.png`` of a BTF: a grid of slices, and one texel's apparent BRDF unfolded into a
2D image (light direction down, view direction across), as in Xu et al.'s Fig. 9."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from evaluators.metrics.figures import figure_png
from evaluators.metrics.tonemap import tonemap
from materials.btf.directions import to_angles
from storage.formats.btf import read_shard

#: At most this many slices in the grid.
GRID_SLICES = 36
#: Longest side of a slice in the grid, texels (larger slices are box-filtered down).
GRID_TEXELS = 64


def grid_indices(count: int, limit: int = GRID_SLICES) -> list[int]:
    """The slices shown: all of them up to ``limit``, else ``limit`` evenly spaced."""
    if count <= limit:
        return list(range(count))
    return sorted({int(round(v)) for v in np.linspace(0, count - 1, limit)})


def shrink(rgb: np.ndarray, side: int = GRID_TEXELS) -> np.ndarray:
    """Box-filter an ``(H, W, 3)`` slice down by an integer factor to at most ``side``."""
    f = max(1, math.ceil(max(rgb.shape[:2]) / side))
    h, w = rgb.shape[0] // f * f, rgb.shape[1] // f * f
    x = np.asarray(rgb[:h, :w], np.float64)
    return x.reshape(h // f, f, w // f, f, 3).mean(axis=(1, 3))


def unfold(wi: np.ndarray, wo: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The apparent BRDF of one texel as an image ``(n_lights, n_views, 3)``: rows are the
    distinct light directions, columns the distinct view directions, both in order of first
    appearance; pairs that were not measured are NaN."""

    def ids(w: np.ndarray) -> tuple[np.ndarray, int]:
        _, first, inverse = np.unique(
            np.round(w, 5), axis=0, return_index=True, return_inverse=True
        )
        order = np.argsort(np.argsort(first))  # rank of each unique row by first appearance
        return order[inverse.ravel()], len(first)

    li, nl = ids(np.asarray(wi))
    vi, nv = ids(np.asarray(wo))
    img = np.full((nl, nv, 3), np.nan)
    img[li, vi] = values
    return img


#: At most this many labelled ticks on each axis of the unfolded BRDF.
MAX_TICKS = 12


def direction_ticks(w: np.ndarray, limit: int = MAX_TICKS) -> tuple[list[int], list[str]]:
    """Ticks of an axis of :func:`unfold`: positions (the distinct directions of ``w`` in
    order of first appearance, at most ``limit`` of them evenly spaced) and their labels,
    polar and azimuth angles in degrees (``"30°/90°"``; the axis showed indices 0-5)."""
    _, first = np.unique(np.round(np.asarray(w), 5), axis=0, return_index=True)
    rows = np.asarray(w)[np.sort(first)]
    theta, phi = to_angles(rows)
    shown = grid_indices(len(rows), limit)
    return shown, [f"{theta[i]:.0f}°/{phi[i]:.0f}°" for i in shown]


def _display(rgb: np.ndarray) -> np.ndarray:
    # BTF values are radiance / irradiance: times pi, an albedo of 1 under normal light is 1.
    return tonemap(np.nan_to_num(rgb, nan=0.0), exposure=math.log2(math.pi), curve="aces")


def preview_png(
    slices: list[tuple[int, np.ndarray]],
    wi: np.ndarray,
    wo: np.ndarray,
    texel_values: np.ndarray,
    texel: tuple[int, int],
    title: str,
) -> bytes:
    """The figure: left, the grid of ``slices`` (``(index, (h, w, 3))``, labelled with
    their angles); right, the unfolded apparent BRDF of ``texel`` (``texel_values`` ``(N,
    3)``, one per slice)."""
    cols = max(1, math.ceil(math.sqrt(len(slices))))
    rows = max(1, math.ceil(len(slices) / cols))
    ti, pi_ = to_angles(wi)
    to, po = to_angles(wo)
    brdf = unfold(wi, wo, texel_values)

    def draw(fig: Any, ax: Any) -> None:
        fig.clf()
        grid = fig.add_gridspec(rows, cols + max(2, cols // 2 + 1))
        for k, (i, img) in enumerate(slices):
            a = fig.add_subplot(grid[k // cols, k % cols])
            a.imshow(_display(img), origin="lower", interpolation="nearest")
            # light and view directions (polar/azimuth, degrees), legible at 1:1
            a.set_title(f"in {ti[i]:.0f}°/{pi_[i]:.0f}°\nout {to[i]:.0f}°/{po[i]:.0f}°",
                        fontsize=7, pad=2)  # fmt: skip
            a.set_xticks([])
            a.set_yticks([])
        b = fig.add_subplot(grid[:, cols:])
        shown = _display(brdf)
        shown[np.isnan(brdf).any(axis=2)] = 90
        b.imshow(shown, interpolation="nearest", aspect="auto")
        b.set_title(f"texel {texel}: apparent BRDF", fontsize=8)
        b.set_xlabel("view direction (polar/azimuth)", fontsize=7)
        b.set_ylabel("light direction (polar/azimuth)", fontsize=7)
        xs, xl = direction_ticks(wo)
        ys, yl = direction_ticks(wi)
        b.set_xticks(xs, xl, rotation=90)
        b.set_yticks(ys, yl)
        b.tick_params(labelsize=6)
        fig.suptitle(title, fontsize=9)

    width = 1.5 * cols + 1.5 * max(2, cols // 2 + 1)
    return figure_png(draw, size=(max(6.0, width), max(3.5, 1.7 * rows + 1.2)))


class PreviewCollector:
    """Gathers what the preview needs while shards stream past (``on_result`` of
    :meth:`jobapi.context.JobContext.map_artifact_shards`): the centre texel of every slice,
    the grid's slices (shrunk), and every slice's Monte Carlo error."""

    def __init__(self, counts: list[int], names: list[str], resolution: tuple[int, int]) -> None:
        self.names = names
        self.starts = np.cumsum([0, *counts])
        n = int(self.starts[-1])
        self.shown = set(grid_indices(n))
        self.texel = (resolution[0] // 2, resolution[1] // 2)
        self.texel_values = np.zeros((n, 3))
        self.stderr = np.zeros(n)
        self.grid: dict[int, np.ndarray] = {}

    def __call__(self, k: int, path: Path) -> None:
        shard = read_shard(path, self.names[k])
        ty, tx = self.texel
        for j in range(len(shard)):
            i = int(self.starts[k]) + j
            self.texel_values[i] = shard.rgb[j, ty, tx]
            self.stderr[i] = shard.stderr[j]
            if i in self.shown:
                self.grid[i] = shrink(shard.rgb[j].astype(np.float32))

    def png(self, wi: np.ndarray, wo: np.ndarray, title: str) -> bytes:
        """The preview of everything collected."""
        return preview_png(sorted(self.grid.items()), wi, wo, self.texel_values, self.texel, title)
