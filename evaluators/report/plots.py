"""``pareto.png`` of ``report.pareto``: one panel per dataset, scene, metric and cost.

Each panel: every candidate at its median cost and mean error over seeds, error bars from
the minimum to the maximum over seeds; points on the front filled and joined by a dashed
line, dominated points hollow and grey. The x axis is logarithmic and labelled with the
cost column's name and meaning (:data:`evaluators.report.fronts.COST_LABELS`).
Deterministic bytes for the same numbers (:func:`evaluators.metrics.figures.figure_png`).
"""

from __future__ import annotations

import math
from typing import Any

from evaluators.metrics.figures import figure_png

FRONT, DOMINATED, LINE = "#d95f02", "#999999", "#7570b3"


def _short(ref: Any) -> str:
    """A dataset ref shortened for a title: ``job:0123abcd…/image.exr``."""
    text = str(ref)
    if text.startswith("job:") and len(text) > 16:
        return f"{text[:12]}…{text[36:]}"
    return text


def _panel(ax: Any, panel: dict[str, Any]) -> None:
    for p in panel["points"]:
        x, y = p["cost"], p["mean"]
        err = [[y - p["min"]], [p["max"] - y]]
        on = p["front"]
        ax.errorbar([x], [y], yerr=err, fmt="o", ms=6, capsize=3,
                    color=FRONT if on else DOMINATED,
                    markerfacecolor=FRONT if on else "white")  # fmt: skip
        ax.annotate(f"{p['candidate']} (n={p['n']})", (x, y), textcoords="offset points",
                    xytext=(5, 5), fontsize=7)  # fmt: skip
    front = sorted((p for p in panel["points"] if p["front"]), key=lambda p: p["cost"])
    if len(front) > 1:
        ax.plot([p["cost"] for p in front], [p["mean"] for p in front], "--", color=LINE)
    if all(p["cost"] > 0 for p in panel["points"]):
        ax.set_xscale("log")
    ax.set_xlabel(panel["cost_label"], fontsize=8)
    ax.set_ylabel(f"{panel['metric']} (mean over seeds)", fontsize=8)
    where = _short(panel["dataset"]) if panel.get("dataset") else "-"
    scene = f", {panel['scene']}" if panel.get("scene") else ""
    ax.set_title(f"{panel['metric']} vs {panel['cost']}: {where}{scene}", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(True, which="both", alpha=0.3)


def pareto_png(panels: list[dict[str, Any]], title: str) -> bytes:
    """The panels in a grid of two columns, as PNG bytes."""
    cols = 1 if len(panels) == 1 else 2
    rows = max(1, math.ceil(len(panels) / cols))

    def draw(fig: Any, ax: Any) -> None:
        fig.delaxes(ax)
        for i, panel in enumerate(panels):
            _panel(fig.add_subplot(rows, cols, i + 1), panel)
        fig.suptitle(title, fontsize=10)

    return figure_png(draw, (6.0 * cols, 3.6 * rows + 0.4))


def select_png(ladders: list[dict[str, Any]], target: float) -> bytes:
    """Per ladder: the rungs' values as bars in order of increasing cost (labelled with the
    cost), the target as a dashed line, the chosen rung highlighted."""
    cols = 1 if len(ladders) == 1 else 2
    rows = max(1, math.ceil(len(ladders) / cols))

    def draw(fig: Any, ax: Any) -> None:
        fig.delaxes(ax)
        for i, lad in enumerate(ladders[:6]):
            a = fig.add_subplot(rows, cols, i + 1)
            rungs = lad["rungs"]
            xs = range(len(rungs))
            colours = [FRONT if r["candidate"] == lad["chosen"] else DOMINATED for r in rungs]
            a.bar(xs, [r["value"] for r in rungs], color=colours)
            a.axhline(target, ls="--", color=LINE, label=f"target {target:g}")
            names = [f"{r['candidate']}\n{r['cost']:.3g}" for r in rungs]
            a.set_xticks(list(xs), names, fontsize=7)
            a.set_xlabel(f"rungs by {lad['cost_label']}", fontsize=8)
            a.set_ylabel(lad["metric"], fontsize=8)
            a.set_title(f"{_short(lad['dataset'])}: {lad['chosen'] or 'none'} chosen", fontsize=8)
            a.legend(fontsize=7)

    return figure_png(draw, (6.0 * cols, 3.6 * rows + 0.3))
