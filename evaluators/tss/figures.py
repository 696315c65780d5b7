"""The pictures of ``evaluate.tss``: ``table.png`` (Table 2's analogue: FLIP against relative
cost) and ``frames.png`` (Fig. 6's layout: screen space, the texture resolutions, FLIP maps).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from evaluators.metrics.figures import figure_png
from evaluators.metrics.tonemap import magma, tonemap
from evaluators.tss.simulate import Figure


def table_png(rows: Sequence[dict[str, Any]], title: str) -> bytes:
    """FLIP (mean over frames) against relative cost, one line per resolution, each point
    labelled ``N``; screen-space shading is the point (1, 0). ``rows``: dicts with
    ``resolution``, ``interval``, ``flip_mean``, ``relative_cost``."""

    def draw(fig: Any, ax: Any) -> None:
        for r in sorted({int(row["resolution"]) for row in rows}):
            pts = sorted(
                (float(row["relative_cost"]), float(row["flip_mean"]), int(row["interval"]))
                for row in rows
                if row["resolution"] == r and math.isfinite(float(row["relative_cost"]))
            )
            if not pts:
                continue
            ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=f"{r}$^2$ texels")
            for x, y, n in pts:
                ax.annotate(f"N={n}", (x, y), textcoords="offset points", xytext=(4, 4),
                            fontsize=7)  # fmt: skip
        ax.plot([1.0], [0.0], "k*", markersize=10, label="screen space")
        ax.set_xscale("log")
        ax.set_xlabel("relative cost per frame (kernel time / screen-space shading)")
        ax.set_ylabel("FLIP (mean over frames)")
        ax.set_title(title, fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)

    return figure_png(draw, (7, 4.5))


def frames_png(figure: Figure, title: str) -> bytes:
    """Fig. 6 style: top row the screen-space reference and, per texture resolution, the
    frame at interval ``figure.interval``; bottom row their HDR-FLIP maps (magma). One
    exposure for all: the reference's 99th percentile at 0.8 before the ACES curve."""
    assert figure.reference is not None
    ref = figure.reference
    lit = ref[ref.max(axis=2) > 0.0]
    level = float(np.percentile(lit.max(axis=1), 99)) if lit.size else 1.0
    exposure = math.log2(0.8 / level) if level > 0.0 else 0.0
    res = sorted(figure.frames)
    cols = 1 + len(res)

    def draw(fig: Any, ax: Any) -> None:
        ax.remove()
        panels: list[tuple[int, np.ndarray, str]] = [
            (1, tonemap(ref, exposure=exposure), f"screen space (frame {figure.frame})")
        ]
        for c, r in enumerate(res, start=2):
            panels.append((c, tonemap(figure.frames[r], exposure=exposure),
                           f"{r}$^2$ texels, N={figure.interval}"))  # fmt: skip
            emap = figure.flip_maps[r]
            panels.append((cols + c, magma(emap), f"FLIP {float(emap.mean()):.4f}"))
        for index, img, label in panels:
            sub = fig.add_subplot(2, cols, index)
            sub.imshow(img, interpolation="nearest")
            sub.set_title(label, fontsize=8)
            sub.set_axis_off()
        fig.suptitle(title, fontsize=9)

    return figure_png(draw, (2.4 * cols, 6.0))
