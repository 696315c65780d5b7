"""The ``report.stability`` job kind: where trained models fail, run by run.

``runs`` are finished training jobs (``train.brdf``, ``train.fabric``, ``train.btf``: every
kind that declares :attr:`jobapi.kinds.Kind.report`, whose
:class:`~jobapi.reports.ReportFacts` say which rows are its error, which metric compares its
failure cases, where its loss is and what checks its model needs; this module names none of
them). For each run, from its own artifacts:

- its error (``train.brdf``: mean SMAPE; ``train.fabric``: the network's mean RGB relative
  error; ``train.btf``: L1), from its result rows (:mod:`jobapi.rows`);
- *convergence*: whether its training loss had flattened by the last step, judged over the
  second half of training (:func:`evaluators.metrics.convergence.convergence` on
  ``curves.json``): a run whose loss was still falling there is under-trained even if the
  annealed learning rate flattened its last tenth, and claims about it are premature;
- for ``train.brdf``, per material (:mod:`models.brdf.stability`): NaN/Inf counts at extreme
  inputs (grazing, tangent, ``wi = wo``, below the horizon), the largest directional albedo
  over incident angles (above 1: energy gain) and the reciprocity error.

Per configuration (candidate and kind) over its runs: the seed spread of the error (mean,
std, worst seed) and how many runs had not converged. Per configuration and material family
(``train.brdf``, ``train.fabric``): the mean error and the worst family.

Per family or failure case (``train.brdf``: MERL family, e.g. iridescent, blend (multi-lobe),
metal; ``train.fabric``: weave pattern and footprint size, the tiny footprints below a tenth
of a tile; ``train.btf``: strongly shadowed and near-specular slices,
:mod:`models.btf.cases`): the mean error and its ratio to the model's whole-set error.

``score`` runs (renders scored against a reference) add render-level failure families: each
is a family of its own, labelled by ``labels`` (default: the job's name), and each of its
candidates' ``render_metric`` (FLIP by default) is ratioed to that candidate's mean over the
score runs listed. So the fabric recipe's seen and unseen scores give "unseen patterns" per
method, and the glint recipe's per-type scores the tiny model's error per example type.
They have no training curve and no model checks.

Artifacts: ``stability.json`` (``runs``, ``configs``, ``families``, settings) and
``stability.png``, the heat table of those ratios: models x families, one panel per kind.
Deterministic per spec (no timings).
"""

from __future__ import annotations

import dataclasses
import statistics
from collections.abc import Sequence
from typing import TYPE_CHECKING, Annotated, Any

from pydantic import Field, StringConstraints, model_validator

from evaluators.report.stability_document import StabilityDocument
from jobapi.documents import read_typed
from jobapi.errors import JobFailed
from jobapi.kinds import Figure, Kind, register, registered, report_facts
from jobapi.metric_names import matches
from jobapi.params import JobRef, StrictModel, job_id_of
from jobapi.reports import ReportFacts, phase_loss
from jobapi.results import ArtifactReader, ResultTable
from jobapi.rows import headline_rows, whole_set

if TYPE_CHECKING:
    from jobapi.context import JobContext
    from jobapi.rows import ResultRow

FORMAT = "matforge.stability/1"
#: The kind whose jobs add render-level families (renders scored against a reference):
#: its rows are read as families of their own, not as a training run's.
SCORE_KIND = "score"


def trained_kinds() -> dict[str, ReportFacts]:
    """The registered kinds that declare what a report reads of their runs
    (:attr:`jobapi.kinds.Kind.report`), in the registry's order: the training kinds."""
    return {n: k.report for n, k in registered().items() if k.report is not None}


def _facts(kind: str) -> ReportFacts:
    facts = report_facts(kind)
    if facts is None:
        raise KeyError(f"kind {kind!r} declares no report facts")
    return facts


class ReportStabilityParams(StrictModel):
    """Parameters of ``report.stability``.

    =================  ====================  ========  =====================================
    name               type                  default   meaning
    =================  ====================  ========  =====================================
    ``runs``           list of ``job:<id>``  required  train.brdf / train.fabric / train.btf,
                                                       and score jobs (render families)
    ``tolerance``      float                 0.1       the loss changing by less than this
                                                       fraction over the second half of
                                                       training: flattened
    ``model_checks``   bool                  true      NaN/Inf, energy, reciprocity of
                                                       train.brdf models
    ``labels``         list of str           names     per run, its family label (score
                                                       runs); as many as ``runs``
    ``render_metric``  str                   flip      the error of score runs
    =================  ====================  ========  =====================================
    """

    runs: list[JobRef] = Field(
        min_length=1, max_length=128, description="Training jobs: 'job:<id>' each."
    )
    tolerance: float = Field(
        default=0.1,
        ge=0.0,
        le=1.0,
        description="Relative change over the second half under which a loss is flat.",
    )
    model_checks: bool = Field(
        default=True, description="Check train.brdf models at extreme inputs."
    )
    labels: list[Annotated[str, StringConstraints(min_length=1, max_length=64)]] | None = Field(
        default=None,
        description="Per run, a short label: a score run's family in the heat table "
        "(default: the job's name).",
    )
    render_metric: str = Field(
        default="flip", min_length=1, max_length=64, description="The error of score runs."
    )

    @model_validator(mode="after")
    def _labels_match(self) -> ReportStabilityParams:
        if self.labels is not None and len(self.labels) != len(self.runs):
            raise ValueError(
                f"labels: {len(self.labels)} labels for {len(self.runs)} runs; give one per run"
            )
        return self


def loss_curve(kind: str, curves: Any) -> list[float | None]:
    """The training loss of a ``curves.json``: as its kind reads it
    (:meth:`~jobapi.reports.ReportFacts.training_loss`: its loss key, the ``train`` phase),
    or the ``loss`` series of the one schema for a kind that declares nothing."""
    facts = report_facts(kind)
    return facts.training_loss(curves) if facts is not None else phase_loss(curves)


def headline(kind: str, rows: Sequence[ResultRow]) -> tuple[str, float | None, str | None]:
    """``(metric, the run's whole-set error, candidate)`` from its rows (the metric and
    candidate its kind declares, :class:`~jobapi.reports.ReportFacts`)."""
    facts = _facts(kind)
    metric, cand = facts.metric, facts.candidate
    for r in headline_rows(rows):
        if matches(r.metric, metric) and cand in (None, r.candidate):
            return r.metric, r.value, r.candidate
    return metric, None, cand


def run_stability(params: ReportStabilityParams, ctx: JobContext) -> None:
    """Check every run and write ``stability.json``."""
    from evaluators.metrics.convergence import convergence
    from jobapi.row_sources import StoreSource

    if len(set(params.runs)) != len(params.runs):
        raise JobFailed("runs: a job is listed twice")
    runs: list[dict[str, Any]] = []
    all_rows: list[ResultRow] = []
    score_rows: list[ResultRow] = []
    for i, ref in enumerate(params.runs):
        job = ctx.input_job(job_id_of(ref), f"runs.{i}")
        kind = registered().get(job.kind)
        trained = trained_kinds()
        known = job.kind in trained or job.kind == SCORE_KIND
        if not known or kind is None or kind.rows is None:
            raise JobFailed(
                f"runs.{i}: job {job.id} is a {job.kind} job; report.stability "
                f"checks {', '.join(trained)} and {SCORE_KIND}"
            )
        src = StoreSource(job, ctx.jobs, ctx.store)
        rows = kind.rows(src)
        label = params.labels[i] if params.labels else (job.name or job.id)
        if job.kind == SCORE_KIND:
            scored = render_rows(rows, params.render_metric, label)
            if not scored:
                raise JobFailed(
                    f"runs.{i}: score job {job.id} has no {params.render_metric} of a "
                    "candidate's whole image"
                )
            score_rows += scored
            runs.append(
                {
                    "run": ref,
                    "kind": SCORE_KIND,
                    "label": label,
                    "candidate": None,
                    "seed": job.seed,
                    "metric": params.render_metric,
                    "error": None,
                    "candidates": {r.candidate: r.value for r in scored},
                    "convergence": {"flattened": None, "why": "a score job has no training"},
                }
            )
            ctx.progress(0.9 * (i + 1) / len(params.runs), f"checked {i + 1}/{len(params.runs)}")
            continue
        all_rows += rows
        metric, error, cand = headline(job.kind, rows)
        run: dict[str, Any] = {
            "run": ref,
            "kind": job.kind,
            "candidate": cand,
            "seed": job.seed,
            "metric": metric,
            "error": error,
            "convergence": convergence(
                loss_curve(job.kind, src.read("curves.json")), tolerance=params.tolerance
            ),
        }
        checks = trained[job.kind].checks
        if checks is not None and params.model_checks:
            try:
                run.update(checks(ctx, job.id))
            except JobFailed as exc:
                raise JobFailed(f"runs: {exc}") from None
        runs.append(run)
        ctx.progress(0.9 * (i + 1) / len(params.runs), f"checked {i + 1}/{len(params.runs)}")
    from evaluators.report.plots import stability_png

    found = configs([r for r in runs if r["kind"] != SCORE_KIND])
    fams = families(all_rows) + render_families(score_rows)
    ctx.put_json(
        "stability.json",
        {
            "format": FORMAT,
            "runs": runs,
            "configs": found,
            "families": fams,
            "settings": {
                "convergence": f"flattened: the loss's last tenth within {params.tolerance:g} "
                "of its tenth around the middle of training (curves.json); the last tenth "
                "alone is flat under an annealed learning rate",
                "albedo": "pi x mean f over 4096 stratified cosine-weighted wo, max over "
                "channels and incident angles; > 1.01 is an energy gain",
                "reciprocity": "mean |f(wi,wo) - f(wo,wi)| / (|f(wi,wo)| + |f(wo,wi)|)",
                "families": "per material family or failure case (train.brdf: MERL "
                "family; train.fabric: weave pattern and footprint size; train.btf: "
                "shadowing / specular / rest slices, relative L1): mean error, and its ratio "
                "to the model's whole-set error",
            },
        },
    )
    ctx.put_bytes("stability.png", stability_png(fams, found), "image/png")
    flat = sum(1 for r in runs if r["convergence"]["flattened"] is False)
    ctx.progress(1.0, f"{len(runs)} runs; {flat} still falling at the last step")


def configs(runs: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (kind, candidate): seed spread of the error, the worst seed, unconverged runs."""
    groups: dict[tuple[str, Any], list[dict[str, Any]]] = {}
    for r in runs:
        groups.setdefault((r["kind"], r["candidate"]), []).append(r)
    out = []
    for (kind, cand), rs in groups.items():
        scored = [r for r in rs if r["error"] is not None]
        vals = [r["error"] for r in scored]
        worst = max(scored, key=lambda r: r["error"]) if scored else None
        out.append(
            {
                "kind": kind,
                "candidate": cand,
                "n": len(rs),
                "mean": statistics.fmean(vals) if vals else None,
                "std": statistics.stdev(vals) if len(vals) > 1 else 0.0 if vals else None,
                "worst_seed": worst["seed"] if worst else None,
                "worst": worst["error"] if worst else None,
                "not_converged": sum(1 for r in rs if r["convergence"]["flattened"] is False),
            }
        )
    return out


def family_metric(kind: str) -> str:
    """The metric families are compared by: the headline one, except where the kind
    declares a relative figure to compare cases whose scales differ (BTF highlights and
    shadows: :attr:`~jobapi.reports.ReportFacts.family_metric`)."""
    return _facts(kind).families_by


def families(rows: Sequence[ResultRow]) -> list[dict[str, Any]]:
    """Per (kind, candidate, family): mean error over materials and runs of
    :func:`family_metric`, its worst, and ``ratio``: that mean over the candidate's
    whole-set error (its rows without a material or with ``"mean"``, averaged over runs;
    ``None`` without one). A ratio above 1 is a family the model does worse on than on
    average: the cells of ``stability.png``."""
    acc: dict[tuple[str, Any, str], list[float]] = {}
    whole: dict[tuple[str, Any], list[float]] = {}
    trained = trained_kinds()
    headline = {id(r) for r in headline_rows(rows)}  # rows are unhashable (config)
    for r in rows:
        facts = trained.get(r.kind)
        if facts is None:
            continue
        metric, cand = facts.families_by, facts.candidate
        if not matches(r.metric, metric) or cand not in (None, r.candidate):
            continue
        if r.family:
            acc.setdefault((r.kind, r.candidate, r.family), []).append(r.value)
        elif id(r) in headline:
            whole.setdefault((r.kind, r.candidate), []).append(r.value)
    return [
        _cell(k, c, f, family_metric(k), v, whole.get((k, c)) or None)
        for (k, c, f), v in acc.items()
    ]


def _cell(
    kind: str, cand: Any, family: str, metric: str, values: list[float], base: list[float] | None
) -> dict[str, Any]:
    """One heat-table cell: the family's mean and worst ``values``, and ``ratio``, that mean
    over the mean of ``base`` (the model's whole-set values; ``None``: no ratio)."""
    mean = statistics.fmean(values)
    whole = statistics.fmean(base) if base else None
    return {
        "kind": kind,
        "candidate": cand,
        "family": family,
        "metric": metric,
        "mean": mean,
        "worst": max(values),
        "n": len(values),
        "whole": whole,
        "ratio": mean / whole if whole else None,
    }


def render_rows(rows: Sequence[ResultRow], metric: str, label: str) -> list[ResultRow]:
    """A score job's whole-image ``metric`` rows, one per candidate, as family ``label``."""
    out = []
    for r in rows:
        if matches(r.metric, metric) and whole_set(r) and r.candidate is not None:
            out.append(dataclasses.replace(r, family=label))
    return out


def render_families(rows: Sequence[ResultRow]) -> list[dict[str, Any]]:
    """Per (candidate, score run's label): the candidate's metric there and its ratio to the
    candidate's mean over all the score runs (``whole``); the cells of the score panel."""
    by_cand: dict[Any, list[float]] = {}
    for r in rows:
        by_cand.setdefault(r.candidate, []).append(r.value)
    acc: dict[tuple[Any, str], list[float]] = {}
    for r in rows:
        acc.setdefault((r.candidate, str(r.family)), []).append(r.value)
    return [_cell(SCORE_KIND, c, f, rows[0].metric, v, by_cand[c]) for (c, f), v in acc.items()]


#: Columns of the result table, one row per run.
COLUMNS = (
    "seed",
    "metric",
    "error",
    "flattened",
    "second_half_drop",
    "nonfinite_total",
    "albedo_max",
    "reciprocity_error",
)


def summarize(read: ArtifactReader) -> ResultTable | None:
    """One row per run (``"<candidate> / seed <s>"``)."""
    doc = read_typed(read("stability.json"), StabilityDocument)
    if doc is None:
        return None
    rows = {}
    for r in doc["runs"]:
        conv = r["convergence"]
        row = {c: r.get(c) for c in COLUMNS}
        row.update(flattened=conv["flattened"], second_half_drop=conv.get("second_half_drop"))
        who = r.get("label") if r["kind"] == SCORE_KIND else r["candidate"]
        rows[f"{who} / seed {r['seed']} ({r['run']})"] = row
    return ResultTable(
        title="Stability",
        label_header="Run",
        columns=list(COLUMNS),
        rows=rows,
        settings=doc["settings"],
    )


register(
    Kind(
        name="report.stability",
        params=ReportStabilityParams,
        runner=run_stability,
        description="Where trained models fail: seed spread and worst seed, errors per "
        "family and failure case (BRDF families; fabric patterns and tiny footprints; BTF "
        "shadowing and specular slices; and, from score jobs, each method's image error per "
        "scene, e.g. unseen patterns or glint example types) against each model's average, "
        "drawn as a heat table, whether each training loss had flattened, and for BRDF "
        "models NaN/Inf at extreme inputs, directional albedo above 1 and reciprocity error.",
        artifacts=("stability.json", "stability.png"),
        documents={"stability.json": StabilityDocument},
        smoke={"runs": ["step:train.brdf"]},
        figures=(
            Figure(
                "stability.png",
                caption=(
                    "Error per family and failure case against each model's average (the heat "
                    "table)."
                ),
                lead=True,
            ),
        ),
        summary=summarize,
    )
)
