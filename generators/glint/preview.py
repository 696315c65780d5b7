"""The labelled preview of a glint dataset: the example, the preview surface, and one NDF
image per level."""

from __future__ import annotations

from typing import Any

import numpy as np

from evaluators.metrics.figures import figure_png


def normal_rgb(normals: np.ndarray) -> np.ndarray:
    """Normals as a picture: ``(n + 1) / 2`` in [0, 1], ``[row = y, column = x]``."""
    return np.clip(0.5 * (np.asarray(normals, dtype=np.float64) + 1.0), 0.0, 1.0)


def preview_png(
    example: np.ndarray, surface: np.ndarray, maps: list[np.ndarray], extent: float, title: str
) -> bytes:
    """One row of panels: the example, the preview surface (its exported normal map), and
    for each level the NDF image of tile (0, 0) over ``[-e, e]^2`` (magma, square-root scale,
    ``n_y`` up)."""
    panels = 2 + len(maps)

    def draw(fig: Any, ax: Any) -> None:
        fig.clf()
        axes = fig.subplots(1, panels)
        axes[0].imshow(normal_rgb(example), interpolation="nearest")
        axes[0].set_title(f"example {example.shape[0]}x{example.shape[0]}", fontsize=8)
        axes[1].imshow(normal_rgb(surface), interpolation="nearest")
        axes[1].set_title(f"surface {surface.shape[0]}x{surface.shape[0]}", fontsize=8)
        for ax_, (level, img) in zip(axes[2:], enumerate(maps), strict=True):
            tile = np.sqrt(np.maximum(img[0, 0].astype(np.float64), 0.0))
            ax_.imshow(
                tile,
                origin="lower",
                cmap="magma",
                extent=(-extent, extent, -extent, extent),
                interpolation="nearest",
            )
            r = img.shape[0]
            ax_.set_title(f"level {level}: {r}x{r} tiles", fontsize=8)
            ax_.set_xlabel("n_x", fontsize=7)
            ax_.tick_params(labelsize=6)
        axes[2].set_ylabel("n_y", fontsize=7)
        for ax_ in axes[:2]:
            ax_.set_xticks([])
            ax_.set_yticks([])
        fig.suptitle(title, fontsize=9)

    return figure_png(draw, size=(2.0 * panels, 2.6))
