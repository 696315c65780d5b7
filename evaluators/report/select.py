"""The ``select`` job kind: the cheapest candidate that meets a quality target.

Model no more than a scene needs. ``runs`` hold the measured ladder: e.g. the fabric
recipe's score jobs (Monte Carlo at 1 and 6 spp, the network at 1 and 16 spp, each FLIP
against the 256-spp reference) or ``train.brdf`` runs (analytic, hybrid 16x3, 32x3). Per
dataset and scene (one reference), the rungs are the candidates ordered by ``cost``, each at
its mean ``metric`` over seeds (:func:`evaluators.report.fronts.panels`); the chosen rung is
the cheapest whose value meets ``target`` (``<=`` for an error, ``>=`` for a metric where
higher is better, e.g. PSNR), or none, with the reason.

This kind chooses among rungs that were already rendered and scored (a batch file makes
them); it does not render.

Artifacts: ``select.json`` (``ladders``: rungs with value, cost, ``meets``; ``chosen`` and
``why``), ``select.png`` (per ladder, the rungs' values as bars by increasing cost, the
target as a line, the chosen rung highlighted).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from pydantic import Field

from evaluators.report.kind import CostName, gather_rows
from jobapi.errors import JobFailed
from jobapi.kinds import Kind, register
from jobapi.params import JobRef, StrictModel
from jobapi.results import ArtifactReader, ResultTable
from jobapi.rows import lower_is_better

if TYPE_CHECKING:
    from jobapi.context import JobContext

FORMAT = "matforge.select/1"


class SelectParams(StrictModel):
    """Parameters of ``select``.

    ==========  ====================  ==================  ===================================
    name        type                  default             meaning
    ==========  ====================  ==================  ===================================
    ``runs``    list of ``job:<id>``  required            jobs with result rows: the ladder
    ``metric``  str                   ``flip``            the quality metric
    ``target``  float                 required            the value a rung must reach
    ``cost``    cost name             ``render_seconds``  what "cheapest" is measured in
    ==========  ====================  ==================  ===================================

    Example: ``{"kind": "select", "params": {"runs": ["step:seen_scores"], "metric":
    "flip", "target": 0.05}}``.
    """

    runs: list[JobRef] = Field(
        min_length=1, max_length=256, description="Jobs with result rows: 'job:<id>' each."
    )
    metric: str = Field(
        default="flip", min_length=1, max_length=64, description="The quality metric of the target."
    )
    target: float = Field(
        allow_inf_nan=False,
        description="The value a rung must reach "
        "(at most, for an error; at least, where higher is better).",
    )
    cost: CostName = Field(default="render_seconds", description="What cheapest is measured in.")


def ladders(panels: list[dict[str, Any]], target: float, lower: bool) -> list[dict[str, Any]]:
    """Per panel, the rungs by increasing cost with ``meets``, and the chosen rung."""
    out = []
    for panel in panels:
        rungs = sorted(panel["points"], key=lambda p: (p["cost"], p["candidate"]))
        rungs = [
            {
                "candidate": p["candidate"],
                "value": p["mean"],
                "n": p["n"],
                "min": p["min"],
                "max": p["max"],
                "cost": p["cost"],
                "meets": p["mean"] <= target if lower else p["mean"] >= target,
            }
            for p in rungs
        ]
        chosen = next((r for r in rungs if r["meets"]), None)
        rel = "<=" if lower else ">="
        if chosen is not None:
            why = (
                f"{chosen['candidate']}: {panel['metric']} {chosen['value']:.4g} {rel} "
                f"{target:g} at {panel['cost']} {chosen['cost']:.4g}, the cheapest of "
                f"{sum(r['meets'] for r in rungs)} that meet it"
            )
        else:
            best = min(rungs, key=lambda r: r["value"] if lower else -r["value"])
            why = (
                f"no rung has {panel['metric']} {rel} {target:g}; the best is "
                f"{best['candidate']} at {best['value']:.4g}"
            )
        out.append(
            {
                "dataset": panel["dataset"],
                "scene": panel["scene"],
                "metric": panel["metric"],
                "cost": panel["cost"],
                "cost_label": panel["cost_label"],
                "rungs": rungs,
                "chosen": chosen["candidate"] if chosen else None,
                "why": why,
            }
        )
    return out


def run_select(params: SelectParams, ctx: JobContext) -> None:
    """Gather the rows, build the ladders and write the artifacts."""
    from evaluators.report.fronts import panels
    from evaluators.report.kind import ReportParetoParams
    from evaluators.report.plots import select_png

    rows = gather_rows(ReportParetoParams(runs=params.runs), ctx)
    found = panels(rows, [params.metric], [params.cost])
    if not found:
        metrics = sorted({r.metric for r in rows})
        raise JobFailed(
            f"no {params.metric} rows with a {params.cost}; the runs measured "
            f"{', '.join(metrics) or 'nothing'}"
        )
    lower = lower_is_better(params.metric) is not False
    result = ladders(found, params.target, lower)
    ctx.put_json(
        "select.json",
        {
            "format": FORMAT,
            "runs": list(params.runs),
            "metric": params.metric,
            "target": params.target,
            "lower_is_better": lower,
            "cost": params.cost,
            "ladders": result,
        },
    )
    ctx.put_bytes("select.png", select_png(result, params.target), "image/png")
    picks = "; ".join(f"{lad['chosen'] or 'none'}" for lad in result)
    ctx.progress(1.0, f"{len(result)} ladders; chosen: {picks}")


COLUMNS = ("value", "cost", "meets", "chosen")


def summarize(read: ArtifactReader) -> ResultTable | None:
    """One row per ladder and rung (``"<dataset> / <candidate>"`` when several ladders)."""
    doc = read("select.json")
    if not isinstance(doc, dict) or not isinstance(doc.get("ladders"), list):
        return None
    several = len(doc["ladders"]) > 1
    rows = {}
    for lad in doc["ladders"]:
        for r in lad.get("rungs") or []:
            label = f"{lad.get('dataset')} / {r['candidate']}" if several else str(r["candidate"])
            rows[label] = {
                "value": r.get("value"),
                "cost": r.get("cost"),
                "meets": r.get("meets"),
                "chosen": r["candidate"] == lad.get("chosen"),
            }
    claims = [
        {
            "claim": f"cheapest rung meeting {doc.get('metric')} target {doc.get('target')}",
            "holds": lad.get("chosen") is not None,
            "why": lad.get("why"),
        }
        for lad in doc["ladders"]
    ]
    return ResultTable(
        title="Cheapest rung meeting the target",
        label_header="Rung",
        columns=list(COLUMNS),
        rows=rows,
        claims=claims,
        settings={k: doc.get(k) for k in ("metric", "target", "cost")},
    )


register(
    Kind(
        name="select",
        params=SelectParams,
        runner=run_select,
        description="The cheapest candidate that meets a quality target (e.g. FLIP <= 0.05), "
        "from scored runs: per reference, the ladder of rungs by cost, which meet the "
        "target, and the one chosen.",
        artifacts=("select.json", "select.png"),
        smoke={
            "runs": ["step:train.brdf"],
            "metric": "smape",
            "target": 2.0,
            "cost": "ns_per_eval",
        },
        summary=summarize,
    )
)
