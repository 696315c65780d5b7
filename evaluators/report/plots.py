"""Pictures of the report kinds: ``pareto.png`` (``report.pareto``), ``select.png``
(``select``) and ``stability.png`` (``report.stability``).

``pareto.png``: one panel per dataset, scene, metric and cost.

Each panel: every candidate at its median cost and mean error over seeds, labelled with its
runtime (``drjit-fused``, ``onnxruntime``, ``mitsuba``) where its rows name one and its cost
relative to the reference kernel where a timing pass measured it, error bars from the minimum
to the maximum over seeds (y) and over the timing pass's repeats (x), ``~`` after a point
whose place on or off the front is not resolved within those spreads; points on the front
filled and joined by a dashed line, dominated points hollow and grey. The x axis is
logarithmic and labelled with the cost column's name and meaning
(:data:`evaluators.report.fronts.COST_LABELS`).
Deterministic bytes for the same numbers (:func:`evaluators.metrics.figures.figure_png`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from evaluators.metrics.figures import figure_png

FRONT, DOMINATED, LINE = "#d95f02", "#999999", "#7570b3"


def _short(ref: Any) -> str:
    """A dataset ref shortened for a title: ``job:0123abcd…/image.exr``,
    ``sha256:0123abcd…``."""
    text = str(ref)
    if text.startswith("job:") and len(text) > 16:
        return f"{text[:12]}…{text[36:]}"
    if text.startswith("sha256:") and len(text) > 20:
        return f"{text[:15]}…"
    return text


def _panel(ax: Any, panel: dict[str, Any]) -> None:
    for p in panel["points"]:
        x, y = p["cost"], p["mean"]
        err = [[y - p["min"]], [p["max"] - y]]
        xerr = [[x - p.get("cost_min", x)], [p.get("cost_max", x) - x]]
        on = p["front"]
        ax.errorbar([x], [y], yerr=err, xerr=xerr, fmt="o", ms=6, capsize=3,
                    color=FRONT if on else DOMINATED,
                    markerfacecolor=FRONT if on else "white")  # fmt: skip
        runtime = f", {p['runtime']}" if p.get("runtime") else ""
        rel = p.get("relative")
        ratio = f", {rel['median']:.3g}x ref" if isinstance(rel, Mapping) else ""
        tie = " ~" if p.get("resolved") is False else ""
        split = f", {p['split']}" if p.get("split") else ""  # train or test error
        ax.annotate(f"{p['candidate']} (n={p['n']}{split}{runtime}{ratio}){tie}", (x, y),
                    textcoords="offset points", xytext=(5, 5), fontsize=7)  # fmt: skip
    front = sorted((p for p in panel["points"] if p["front"]), key=lambda p: p["cost"])
    if len(front) > 1:
        ax.plot([p["cost"] for p in front], [p["mean"] for p in front], "--", color=LINE)
    if all(p["cost"] > 0 for p in panel["points"]):
        ax.set_xscale("log")
    ax.set_xlabel(panel["cost_label"], fontsize=8)
    ax.set_ylabel(f"{panel['metric']} (mean over seeds)", fontsize=8)
    where = _short(panel["dataset"]) if panel.get("dataset") else "-"
    scene = f", {panel['scene']}" if panel.get("scene") else ""
    undecided = "; front not resolved (~)" if panel.get("resolved") is False else ""
    ax.set_title(f"{panel['metric']} vs {panel['cost']}: {where}{scene}{undecided}", fontsize=8)
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


def select_png(ladders: Sequence[Mapping[str, Any]], target: float) -> bytes:
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
            vals = [r["value"] for r in rungs]
            spread = [[v - r.get("min", v) for v, r in zip(vals, rungs, strict=True)],
                      [r.get("max", v) - v for v, r in zip(vals, rungs, strict=True)]]  # fmt: skip
            a.bar(xs, vals, color=colours, yerr=spread, capsize=3)
            a.axhline(target, ls="--", color=LINE, label=f"target {target:g}")
            names = [
                f"{r['candidate']}\n{r['cost']:.3g}"
                + (
                    f" ({r['cost_min']:.3g}..{r['cost_max']:.3g})"
                    if r.get("cost_min") is not None and r.get("cost_max") is not None
                    else ""
                )
                + (f"\n{r['runtime']}" if r.get("runtime") else "")
                for r in rungs
            ]
            a.set_xticks(list(xs), names, fontsize=7)
            a.set_xlabel(f"rungs by {lad['cost_label']}", fontsize=8)
            a.set_ylabel(lad["metric"], fontsize=8)
            undecided = "; not resolved" if lad.get("resolved") is False else ""
            a.set_title(f"{_short(lad['dataset'])}: {lad['chosen'] or 'none'} chosen{undecided}",
                        fontsize=8)  # fmt: skip
            a.legend(fontsize=7)

    return figure_png(draw, (6.0 * cols, 3.6 * rows + 0.3))


def heat_cells(cells: list[dict[str, Any]]) -> list[tuple[float | None, str]]:
    """Per heat-table cell of one panel: the ratio its colour shows (``None``: none) and
    its text. A model with a single family in the panel has that family as its whole set:
    its ratio is 1 by construction, so it is neither coloured nor printed (a panel of such
    models read "1.00x" in every cell), only its error, marked as its whole set."""
    count: dict[str, int] = {}
    for f in cells:
        count[str(f["candidate"])] = count.get(str(f["candidate"]), 0) + 1
    out: list[tuple[float | None, str]] = []
    for f in cells:
        alone = count[str(f["candidate"])] == 1
        ratio = None if alone else f["ratio"]
        text = f"{f['mean']:.3g}"
        if ratio:
            text += f"\n{ratio:.2f}x"
        elif alone:
            text += "\n(its whole set)"
        out.append((ratio, text))
    return out


def stability_png(families: list[dict[str, Any]], configs: list[dict[str, Any]]) -> bytes:
    """The heat table of ``report.stability``: per kind one panel, models (rows) x families
    (columns); a cell's colour is the family's error over the model's whole-set error on a
    log scale centred on 1 (red: worse than its average, green: better), its text the error
    and that ratio (:func:`heat_cells`). Row labels carry the seed count and how many runs
    had not converged."""
    import numpy as np

    from evaluators.report.stability import SCORE_KIND

    kinds = list(dict.fromkeys(f["kind"] for f in families))
    conf = {(c["kind"], c["candidate"]): c for c in configs}
    if not kinds:

        def empty(fig: Any, ax: Any) -> None:
            ax.axis("off")
            ax.text(0.5, 0.5, "no per-family rows in these runs", ha="center", va="center")

        return figure_png(empty, (6.0, 1.5))
    shapes = []
    for kind in kinds:
        mine = [f for f in families if f["kind"] == kind]
        shapes.append((kind, mine, list(dict.fromkeys(str(f["candidate"]) for f in mine)),
                       list(dict.fromkeys(f["family"] for f in mine))))  # fmt: skip
    width = max(6.0, 2.2 + 1.25 * max(len(s[3]) for s in shapes))
    heights = [0.9 + 0.42 * len(s[2]) for s in shapes]

    def draw(fig: Any, ax: Any) -> None:
        fig.delaxes(ax)
        grid = fig.add_gridspec(len(shapes), 1, height_ratios=heights)
        for i, (kind, mine, cands, fams) in enumerate(shapes):
            a = fig.add_subplot(grid[i])
            ratio = np.full((len(cands), len(fams)), np.nan)
            cells = heat_cells(mine)
            for f, (shown, _) in zip(mine, cells, strict=True):
                if shown is not None:
                    ratio[cands.index(str(f["candidate"])), fams.index(f["family"])] = shown
            logr = np.clip(np.log2(np.where(np.isfinite(ratio), ratio, 1.0)), -2.0, 2.0)
            a.imshow(np.ma.masked_where(~np.isfinite(ratio), logr), cmap="RdYlGn_r",
                     vmin=-2.0, vmax=2.0, aspect="auto")  # fmt: skip
            for f, (_, text) in zip(mine, cells, strict=True):
                r, c = cands.index(str(f["candidate"])), fams.index(f["family"])
                a.text(c, r, text, ha="center", va="center", fontsize=7)
            labels = []
            for cand in cands:
                cfg = next((v for (k, c), v in conf.items() if k == kind and str(c) == cand), None)
                note = f" (n={cfg['n']}, {cfg['not_converged']} not conv.)" if cfg else ""
                labels.append(f"{cand}{note}")
            a.set_yticks(range(len(cands)), labels, fontsize=7)
            a.set_xticks(range(len(fams)), fams, fontsize=7, rotation=20, ha="right")
            metric = mine[0]["metric"]
            title = (
                f"renders (score runs): {metric} per run / the method's mean over them"
                if kind == SCORE_KIND
                else f"{kind}: {metric} per family / whole-set {metric}"
            )
            a.set_title(title, fontsize=8)

    return figure_png(draw, (width, sum(heights) + 0.6))
