"""Matplotlib figures as deterministic PNG bytes, shared by the training and report kinds."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from storage.formats.png import write_png


def figure_png(draw: Callable[[Any, Any], None], size: tuple[float, float] = (7, 4)) -> bytes:
    """``draw(fig, ax)`` on one Agg figure of ``size`` inches at 100 dpi; the RGB PNG bytes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=size, dpi=100)
    try:
        draw(fig, ax)
        fig.tight_layout()
        fig.canvas.draw()
        rgba = np.asarray(fig.canvas.buffer_rgba())  # type: ignore[attr-defined]
        return write_png(None, np.ascontiguousarray(rgba[..., :3]))
    finally:
        plt.close(fig)


def loss_axes(ax: Any, ylabel: str, title: str) -> None:
    """The common dressing of a loss-against-step plot: log y, grid, legend."""
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
