"""The ``report.pareto`` job kind: error against cost over any set of finished jobs.

``runs`` are jobs whose kinds have result rows (:mod:`jobapi.rows`): ``train.brdf`` runs
(SMAPE against ns/eval and bytes per material), ``score`` jobs of renders (FLIP against
render seconds and spp, e.g. the fabric recipe's network against Monte Carlo),
``train.btf`` (L1 against bytes), ``evaluate.tss`` (FLIP against ms per frame). The numbers
are :mod:`evaluators.report.fronts`'s; the claims are the families' own
(:mod:`evaluators.report.claims`) and any given in ``claims``.

Artifacts:

- ``pareto.json``: ``panels`` (one per dataset, scene, error metric and cost column: points
  with their mean error over seeds, std, min, max, per-seed values, cost, ``front`` and
  ``dominated_by``; the front's candidates by cost; the cost's axis label), ``families``
  (per-material rows by family), ``claims`` (each with ``holds`` and ``why``), settings;
- ``pareto.png``: the panels (at most :data:`MAX_DRAWN`), the front joined, dominated points
  hollow, error bars min to max over seeds;
- ``rows.json``: every row the report read.

``ns_per_eval`` is re-measured here: every model charted by it is timed in this job's one
timing pass (:mod:`evaluators.report.timing`), interleaved with the reference kernel
(Mitsuba's ``roughconductor`` on the same batch); the points carry the cost's spread and
its ratio to the reference, ``pareto.json`` the pass (``timing``), and ``pareto.json`` and
``pareto.png`` are then timing artifacts. Costs each job timed itself
(``render_seconds``, ``train_seconds``, ``ms_per_frame``) are charted, not ranked. A point's
place on the front is ``resolved`` only when it holds inside the seed and timing spreads.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Literal

from pydantic import Field, SerializerFunctionWrapHandler, model_serializer

from evaluators.report.fronts import COST_LABELS
from evaluators.report.timing import TimingParams
from jobapi.documents import ParetoDocument, read_typed
from jobapi.errors import JobFailed
from jobapi.kinds import Figure, Kind, register, registered
from jobapi.metric_names import matches
from jobapi.params import JobRef, StrictModel, job_id_of
from jobapi.results import ArtifactReader, ResultTable

if TYPE_CHECKING:
    from jobapi.context import JobContext
    from jobapi.rows import ResultRow

FORMAT = "matforge.pareto/1"
#: Panels drawn in ``pareto.png`` at most (all are in ``pareto.json``).
MAX_DRAWN = 6
CostName = Literal[
    "ns_per_eval",
    "bytes_per_material",
    "bytes_per_network",
    "ms_per_frame",
    "render_seconds",
    "spp",
    "train_seconds",
    "macs_per_eval",
    "bytes_per_eval",
]


class ClaimSpec(StrictModel):
    """A claim to check: candidate ``a``'s mean ``metric`` ``relation`` ``b``'s."""

    a: str = Field(min_length=1, max_length=200, description="the candidate claimed better")
    b: str = Field(min_length=1, max_length=200, description="the candidate it is compared to")
    metric: str = Field(min_length=1, max_length=64, description="an error metric, e.g. flip")
    relation: Literal["<", "<="] = Field(default="<", description="'<' or '<='")
    dataset: str | None = Field(default=None, max_length=200, description="only this dataset")
    claim: str | None = Field(default=None, max_length=300, description="the claim in words")


class ReportParetoParams(StrictModel):
    """Parameters of ``report.pareto``.

    =================  ====================  ========  =====================================
    name               type                  default   meaning
    =================  ====================  ========  =====================================
    ``runs``           list of ``job:<id>``  required  finished jobs with result rows, 1..256
    ``metrics``        list of str           (found)   error metrics to chart; default the
                                                       ones of smape, flip, flip_mean, l1,
                                                       rgb.rel, mae present
    ``costs``          list of cost names    (found)   cost columns to chart against
    ``claims``         list of claims        ``[]``    extra claims to check
    ``family_claims``  bool                  true      check the families' own claims
    ``timing``         timing settings       (below)   the pass that re-times every model
                                                       charted by ns_per_eval beside the
                                                       reference kernel: ``repeats`` (5,
                                                       at least 5), ``warmup`` (2),
                                                       ``batch`` (2^20), ``threads`` (2)
    =================  ====================  ========  =====================================

    Example (in a batch file)::

        {"kind": "report.pareto", "params": {"runs": ["step:seen_scores", "step:unseen_scores"]}}
    """

    runs: list[JobRef] = Field(
        min_length=1,
        max_length=256,
        description="Jobs to compare: 'job:<id>' each ('step:<name>' in a batch file).",
    )
    metrics: list[str] | None = Field(
        default=None, max_length=16, description="Error metrics to chart (default: found)."
    )
    costs: list[CostName] | None = Field(
        default=None, max_length=9, description="Cost columns to chart (default: found)."
    )
    claims: list[ClaimSpec] = Field(
        default_factory=list,
        max_length=64,
        description="Claims to check besides the families' own.",
    )
    family_claims: bool = Field(default=True, description="Check the families' own claims.")
    timing: TimingParams = Field(
        default_factory=TimingParams,
        description="The timing pass that re-times every model charted by ns_per_eval, "
        "beside the reference kernel: repeats (>= 5), warmup, batch, threads.",
    )

    @model_serializer(mode="wrap")
    def _dump(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        # The default timing is left out, so a spec keeps the canonical form (and hash)
        # it had before the setting existed.
        return drop_default_timing(handler(self))


def drop_default_timing(data: dict[str, Any]) -> dict[str, Any]:
    """``data`` without its ``timing`` when that is the default :class:`TimingParams`."""
    if data.get("timing") == TimingParams().model_dump():
        del data["timing"]
    return data


def timed_pass(
    rows: list[ResultRow],
    metrics: list[str],
    costs: list[str],
    timing: TimingParams,
    ctx: JobContext,
) -> dict[str, Any] | None:
    """The comparison's timing pass (:mod:`evaluators.report.timing`) when ``costs`` has a
    cost it re-measures and some charted row has one; else ``None``."""
    from evaluators.report.fronts import whole_set
    from evaluators.report.timing import PASS_COSTS, comparison_pass, pass_targets

    cost = next((c for c in costs if c in PASS_COSTS), None)
    if cost is None:
        return None
    charted = [r for r in rows if matches(r.metric, metrics) and whole_set(r)]
    targets = pass_targets(charted, cost)
    if not targets:
        return None
    ctx.progress(0.65, f"timing {len(targets)} models and the reference kernel in one pass")
    record = comparison_pass(targets, timing, ctx)
    ctx.measure("timing", record)
    return record


def gather_rows(params: ReportParetoParams, ctx: JobContext) -> list[ResultRow]:
    """Every row of every run, in the order of ``runs``."""
    from jobapi.row_sources import StoreSource

    if len(set(params.runs)) != len(params.runs):
        raise JobFailed("runs: a job is listed twice")
    rows: list[ResultRow] = []
    for i, ref in enumerate(params.runs):
        job = ctx.input_job(job_id_of(ref), f"runs.{i}")
        kind = registered().get(job.kind)
        if kind is None or kind.rows is None:
            raise JobFailed(f"runs.{i}: job {job.id} is a {job.kind} job, which has no result rows")
        rows += kind.rows(StoreSource(job, ctx.jobs, ctx.store))
        ctx.progress(0.6 * (i + 1) / len(params.runs), f"read {i + 1}/{len(params.runs)} runs")
    return rows


def run_report_pareto(params: ReportParetoParams, ctx: JobContext) -> None:
    """Gather the rows, compute the panels, families and claims, and write the artifacts."""
    from evaluators.report import claims, fronts
    from evaluators.report.plots import pareto_png
    from evaluators.report.timing import timing_summary

    rows = gather_rows(params, ctx)
    metrics = fronts.error_metrics(rows, params.metrics)
    costs = fronts.cost_columns(rows, params.costs)
    timing = timed_pass(rows, metrics, costs, params.timing, ctx)
    panels = fronts.panels(rows, metrics, costs, timing)
    if not panels:
        found = sorted({r.metric for r in rows})
        raise JobFailed(
            f"no error metric with a cost to chart: metrics {metrics or 'none'} against "
            f"{costs or 'no cost'}; the runs measured {', '.join(found) or 'nothing'}"
        )
    checked = claims.family_claims(rows) if params.family_claims else []
    checked += [fronts.check_claim(rows, c.model_dump()) for c in params.claims]
    ctx.put_json(
        "pareto.json",
        {
            "format": FORMAT,
            "runs": list(params.runs),
            "metrics": metrics,
            "costs": costs,
            "panels": panels,
            "families": fronts.families(rows, metrics),
            "claims": checked,
            **({"timing": timing_summary(timing)} if timing is not None else {}),
            "settings": {
                "point": "a candidate's whole-set rows (material empty or 'mean') in the panel; "
                "error: mean over jobs (seeds) of each job's value, std ddof 1, min, max; "
                "cost: median over the rows; ns_per_eval: the median of this job's timing "
                "pass (every model and the reference kernel interleaved), with min, max, "
                "IQR and the ratio to the reference",
                "front": "not beaten on both cost and mean error by another point; "
                "resolved when that holds anywhere inside the spreads (seed min..max, "
                "timing min..max), else the ties are named",
                "costs": {c: COST_LABELS.get(c, c) for c in costs},
            },
        },
    )
    ctx.put_json("rows.json", [r.document() for r in rows])
    ctx.progress(0.9, "drawing")
    title = f"report.pareto: {len(params.runs)} runs, {len(rows)} rows"
    ctx.put_bytes("pareto.png", pareto_png(panels[:MAX_DRAWN], title), "image/png")
    held = [c["claim"] for c in checked if c.get("holds") is False]
    ctx.progress(1.0, f"{len(panels)} panels; claims not holding: {'; '.join(held) or 'none'}")


#: Columns of the result table: one row per panel and point (``x_reference``: the cost
#: over the reference kernel's, from the timing pass).
COLUMNS = (
    "mean", "std", "min", "max", "n", "cost", "cost_min", "cost_max", "x_reference", "front",
    "resolved",
)  # fmt: skip


def summarize(read: ArtifactReader) -> ResultTable | None:
    """One row per panel and point (``"<metric> vs <cost> / <candidate>"``, with the
    dataset when there are several), and the claims."""
    doc = read_typed(read("pareto.json"), ParetoDocument)
    if doc is None:
        return None
    panels = doc["panels"]
    several = len({(p.get("dataset"), p.get("scene")) for p in panels}) > 1
    rows = {}
    for p in panels:
        scene = p.get("scene")
        where = f" [{p.get('dataset')}{' ' + scene if scene else ''}]" if several else ""
        for pt in p["points"]:
            label = f"{p['metric']} vs {p['cost']}{where} / {pt['candidate']}"
            rel = pt.get("relative")
            x_ref = rel.get("median") if isinstance(rel, dict) else None
            rows[label] = {c: pt.get(c) for c in COLUMNS} | {"x_reference": x_ref}
    return ResultTable.from_report(
        dict(doc),
        rows,
        title="Error against cost",
        label_header="Panel / candidate",
        columns=COLUMNS,
    )


def timed_artifacts(params: ReportParetoParams) -> tuple[str, ...]:
    """The artifacts that hold the job's own timing pass: ``pareto.json`` and ``pareto.png``
    when ``ns_per_eval`` may be charted (asked, or ``costs`` left to what is found)."""
    from evaluators.report.timing import PASS_COSTS

    if params.costs is not None and not set(params.costs) & set(PASS_COSTS):
        return ()
    return ("pareto.json", "pareto.png")


register(
    Kind(
        name="report.pareto",
        params=ReportParetoParams,
        runner=run_report_pareto,
        description="Error against cost over any finished jobs with result rows (train.*, "
        "score, evaluate.tss): Pareto fronts per dataset and scene with dominated points, "
        "seed spread, per-family errors and the families' claims checked.",
        artifacts=("pareto.json", "pareto.png", "rows.json"),
        timing_artifacts=timed_artifacts,
        smoke={"runs": ["step:train.brdf"], "timing": {"batch": 4096, "min_sample_ms": 0}},
        figures=(
            Figure(
                "pareto.png",
                caption=(
                    "Error against cost: the Pareto front of each dataset, scene, metric and cost."
                ),
                lead=True,
            ),
        ),
        documents={"pareto.json": ParetoDocument},
        summary=summarize,
    )
)
