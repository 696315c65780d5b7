"""Pictures of ``report.brdf``: ``pareto.png`` and ``families.png`` (matplotlib, Agg).

Deterministic bytes for the same numbers: fixed figure size and DPI, no timestamps
(:func:`storage.formats.png.write_png` of the rendered RGBA buffer).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from evaluators.metrics.figures import figure_png

#: One colour per model type.
COLOURS = {"analytic": "#4d4d4d", "hybrid": "#d95f02", "neural": "#1b9e77"}
#: Tick labels of the families the paper singles out (Fig. 12).
SHORT = {"iridescent": "thin film", "blend": "multi-lobe"}


def _minor_tick(v: float, _: Any) -> str:
    """Label the minor ticks 2 and 5 of each decade of a log axis."""
    lead = round(v / 10 ** math.floor(math.log10(v))) if v > 0 else 0
    return f"{v:g}" if lead in (2, 5) else ""


def pareto_png(points: list[dict[str, Any]], front: list[str], title: str) -> bytes:
    """Mean SMAPE (error bars: min-max over seeds) against fused ns/eval, log x; the
    Pareto front joined by a line. Points without a timing are listed in the caption."""
    timed = [p for p in points if p.get("ns_per_eval") is not None]

    def draw(fig: Any, ax: Any) -> None:
        for p in timed:
            x, y = p["ns_per_eval"], p["smape_mean"]
            err = [[y - p["smape_min"]], [p["smape_max"] - y]]
            ax.errorbar([x], [y], yerr=err, fmt="o", ms=7, capsize=4,
                        color=COLOURS.get(p["model"], "k"))  # fmt: skip
            ax.annotate(f"{p['config']} (n={p['n']})", (x, y), textcoords="offset points",
                        xytext=(6, 6), fontsize=8)  # fmt: skip
        on = [p for p in timed if p["config"] in front]
        on.sort(key=lambda p: p["ns_per_eval"])
        if on:
            ax.plot([p["ns_per_eval"] for p in on], [p["smape_mean"] for p in on], "--",
                    color="#7570b3", label="Pareto front")  # fmt: skip
            ax.legend(fontsize=8)
        from matplotlib.ticker import FuncFormatter

        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.xaxis.set_minor_formatter(FuncFormatter(_minor_tick))  # 2 and 5 only: no overlap
        ax.set_xlabel("ns_per_eval: fused Dr.Jit kernel execution, ns per evaluation (log)")
        ax.set_ylabel("mean SMAPE over materials (Eq. 6)")
        untimed = [p["config"] for p in points if p.get("ns_per_eval") is None]
        ax.set_title(title + (f"\nnot timed: {', '.join(untimed)}" if untimed else ""), fontsize=10)
        ax.grid(True, which="both", alpha=0.3)

    return figure_png(draw, (7.5, 4.8))


def families_png(doc: dict[str, Any], title: str) -> bytes:
    """Grouped bars: per family (highlighted ones first, starred), each configuration's
    mean SMAPE over seeds, error bars the standard deviation over seeds."""
    fams: list[str] = doc["families"]
    configs: dict[str, dict[str, Any]] = doc["configs"]

    def draw(fig: Any, ax: Any) -> None:
        n = max(1, len(configs))
        width = 0.8 / n
        x = np.arange(len(fams))
        for i, (label, rows) in enumerate(configs.items()):
            ys = [rows[f]["smape_mean"] if f in rows else np.nan for f in fams]
            es = [rows[f]["smape_std"] if f in rows else 0.0 for f in fams]
            model = label.split()[0]
            shade = 0.55 + 0.45 * (i % 2)
            ax.bar(x + (i - (n - 1) / 2) * width, ys, width, yerr=es, capsize=2, label=label,
                   color=COLOURS.get(model, "k"), alpha=shade)  # fmt: skip
        names = [f"*{f}*\n({SHORT.get(f, '')})" if f in doc["highlight"] else f for f in fams]
        ax.set_xticks(x, names)
        ax.set_ylabel("mean SMAPE (Eq. 6), mean over seeds")
        ax.set_title(title + "\n*starred*: the paper's Fig. 12 failure cases", fontsize=10)
        ax.legend(fontsize=7, ncol=2)
        ax.grid(True, axis="y", alpha=0.3)

    return figure_png(draw, (8.5, 4.5))
