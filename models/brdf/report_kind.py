"""The ``report.brdf`` job kind: accuracy against cost over finished ``train.brdf`` runs.

For the hybrid-BRDF paper's summary figures (De Oliveira et al.: Fig. 4 accuracy, Table 4
cost, Fig. 12 failure families): ``runs`` are ``train.brdf`` jobs, typically every model
type and size over several seeds on one ``generate.merl`` collection. Runs of the same model
type and size are one *configuration* (:mod:`models.brdf.study`).

Artifacts:

- ``pareto.json``: per configuration its mean SMAPE over seeds (with std, min, max), its
  fused-kernel ns per evaluation, bytes per network and per material, ``pareto: true`` on
  the front; ``front`` (the front's configurations by cost) and ``claims``: "hybrid <
  analytic" for each hybrid size and "hybrid <= neural at equal per-material parameters" at
  16x3, 32x3 and every other size with both, each with its numbers and ``holds``
  true / false (``null`` with ``why`` where a configuration is missing), and one claim
  that does not hold per material whose SMAPE is within 10 % of its maximum 2 in any
  configuration (:func:`models.brdf.study.near_maximum`: there the score cannot rank);
  ``panels``: the same configurations as ``report.pareto``'s panels (mean SMAPE against
  ns per evaluation, and against bytes per material), the one ``pareto.json`` schema of
  ``docs/artifacts.md`` that the dashboard draws;
- ``pareto.png``: the same as a picture;
- ``spread.json``: per configuration the per-seed mean SMAPE (job, seed, value) and
  mean / std / min / max over seeds;
- ``families.json``, ``families.png``: per configuration and material family the mean
  SMAPE over seeds and its spread; ``iridescent`` (thin film) and ``blend`` (multi-lobe)
  singled out, as in the paper's Fig. 12.

Cost: from each run's speed timings (``train.brdf``'s ``speed: trained`` or ``full``, in its
manifest's ``timings.measured.speed``; a ``speed.json`` artifact for runs made before
timings moved there), its trained-size row; a configuration none of whose runs has one is
timed here, once, with the first run's model (:func:`models.speed.model_row`,
``speed_batch`` pairs, median of 5, 2 threads), and its ``ns_source`` says so.
Same runs, same bytes, unless a configuration had to be timed here (then the ns figures
vary between runs, as the runs' timings do).
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any, TypeVar, cast

from pydantic import Field

from jobapi.documents import DocumentError, ParetoDocument, check_typed
from jobapi.errors import JobFailed
from jobapi.kinds import Figure, Kind, register
from jobapi.metric_names import qualified
from jobapi.params import JobRef, StrictModel
from jobapi.results import ArtifactReader, ResultTable
from jobapi.row_sources import measured_timings
from models.brdf.document import BrdfFamilies, BrdfModelDocument, BrdfSpread, TrainBrdfMetrics

if TYPE_CHECKING:
    from jobapi.context import JobContext
    from models.brdf.study import Run

REPORT_FORMAT = "matforge.brdf-report/1"
T = TypeVar("T")


class ReportBrdfParams(StrictModel):
    """Parameters of ``report.brdf``.

    ===============  =======================  ========  ===================================
    name             type                     default   meaning
    ===============  =======================  ========  ===================================
    ``runs``         list of ``job:<id>``     required  finished train.brdf jobs, 1..64
    ``speed_batch``  int                      2^18      pairs per ns/eval measurement of a
                                                        configuration without speed timings
    ===============  =======================  ========  ===================================

    Example (in a batch file, ``step:<name>`` is the whole job)::

        {"kind": "report.brdf", "params": {"runs": ["step:hybrid_s0", "step:neural_s0"]}}
    """

    runs: list[JobRef] = Field(
        min_length=1,
        max_length=64,
        description="train.brdf jobs to compare: 'job:<id>' each ('step:<name>' in a batch "
        "file); all fitted to the same materials.",
    )
    speed_batch: int = Field(
        default=1 << 18,
        ge=1024,
        le=1 << 22,
        description="Pairs per ns/eval measurement, for configurations whose runs have no "
        "speed timings (they are timed here, median of 5).",
    )


def load_run(ref: str, ctx: JobContext) -> tuple[Run, dict[str, Any]]:
    """The :class:`~models.brdf.study.Run` of a ``train.brdf`` job and its ``model.json``."""
    from models.brdf.study import Run

    job_id = ref.removeprefix("job:")
    job = ctx.input_job(job_id, "runs", "train.brdf")
    names = {a.name for a in job.artifacts}

    def read(name: str) -> Any:
        return json.loads(ctx.read_ref(f"job:{job_id}/{name}"))

    metrics = _document(read("metrics.json"), TrainBrdfMetrics, f"{ref}/metrics.json")
    doc = _document(read("model.json"), BrdfModelDocument, f"{ref}/model.json")
    arch = doc["architecture"]
    speed, source = None, "none"
    # The speed document: the manifest's timings.measured.speed, or the speed.json artifact
    # of a run made before timings moved to the manifest.
    timed = measured_timings(job, ctx.store).get("speed")
    if timed is None and "speed.json" in names:
        timed = read("speed.json")
    if isinstance(timed, dict):
        rows = [r for r in timed.get("rows", []) if r.get("trained")]
        if rows:
            speed, source = rows[0], "speed timings of the runs"
    run = Run(
        job_id=job_id,
        seed=job.seed,
        model=doc["model"],
        width=arch["width"],
        depth=arch["depth"],
        latent_dim=arch["latent_dim"],
        per_material_params=arch["per_material_params"],
        materials=tuple(dict(m) for m in metrics["materials"]),
        speed=speed,
        speed_source=source,
        stored_mean=metrics["mean"]["smape"],
    )
    return run, dict(doc)


def _document(doc: Any, typed: type[T], name: str) -> T:
    """``doc`` as a ``typed`` document of a run; :class:`JobFailed` naming the run's file
    and the field if it is not one."""
    try:
        check_typed(name, doc, typed)
    except DocumentError as exc:
        raise JobFailed(f"runs: {exc}") from None
    return cast(T, doc)


def _time_config(doc: dict[str, Any], batch: int) -> dict[str, Any] | None:
    """The trained-size speed row of ``doc``'s first material, or ``None`` without a
    vectorised variant (LLVM or CUDA)."""
    from materials.backend import load_mitsuba
    from models.brdf.kind import SPEED_REPEATS
    from models.speed import speed_report

    mi = load_mitsuba()
    if not mi.variant().startswith(("llvm_", "cuda_")):
        return None
    rows = speed_report(mi, doc, sizes=(), batch=batch, repeats=SPEED_REPEATS)["rows"]
    return next(r for r in rows if r.get("trained"))


def run_report_brdf(params: ReportBrdfParams, ctx: JobContext) -> None:
    """Gather the runs, time what is untimed, and write the report artifacts."""
    from dataclasses import replace

    from models.brdf import study
    from models.brdf.report_plots import families_png, pareto_png

    if len(set(params.runs)) != len(params.runs):
        raise JobFailed("runs: a job is listed twice")
    runs, docs = [], {}
    for i, ref in enumerate(params.runs):
        run, doc = load_run(ref, ctx)
        runs.append(run)
        docs[run.job_id] = doc
        ctx.progress(0.3 * (i + 1) / len(params.runs), f"read {i + 1}/{len(params.runs)} runs")
    sets = {tuple(sorted(r["name"] for r in run.materials)) for run in runs}
    if len(sets) > 1:
        raise JobFailed(
            "runs: fitted to different sets of materials; a report compares models on one "
            "dataset (the same generate.merl job)"
        )
    configs = study.group(runs)
    for i, c in enumerate(configs.values()):
        if all(r.speed is None for r in c.runs):
            ctx.progress(0.3 + 0.6 * i / len(configs), f"timing {c.label}")
            row = _time_config(docs[c.runs[0].job_id], params.speed_batch)
            if row is not None:
                c.runs[:] = [
                    replace(r, speed=row, speed_source="timed by this job") for r in c.runs
                ]
    points = [c.summary() for c in configs.values()]
    front = study.pareto_front(points)
    for p in points:
        p["pareto"] = p["config"] in front
    # A material whose SMAPE is near its maximum in any configuration is a claim that does
    # not hold ("the score ranks the models there"), so that the report never stays silent.
    claims = study.claims(configs) + [
        {"claim": f"{d['material']}: SMAPE below 90 % of its maximum 2 (it can rank the models)",
         "holds": False, "why": d["warning"]}
        for d in study.near_maximum(configs)
    ]  # fmt: skip
    n_mat = len(runs[0].materials)
    common = {"format": REPORT_FORMAT, "materials": n_mat, "runs": list(params.runs)}
    ctx.put_json("pareto.json", {
        **common, "points": points, "front": front, "claims": claims,
        "panels": panels(points),
        "settings": {
            "accuracy": "mean SMAPE (Eq. 6) over materials per run (metrics.json), then mean "
            "over seeds; std is the sample std (ddof 1)",
            "cost": "ns_per_eval: fused Dr.Jit kernel execution ns per evaluation "
            "(the runs' speed timings, fused_kernel_ns), median over runs; the x axis of "
            "pareto.png; "
            "bytes per material = 4 x per-material floats",
            "front": "not beaten on both mean SMAPE and ns_per_eval by another configuration",
        },
    })  # fmt: skip
    spread = {
        c.label: {
            **study.spread([r.mean_smape for r in c.runs]),
            "per_seed": [
                {"seed": r.seed, "run": f"job:{r.job_id}", "smape": r.mean_smape} for r in c.runs
            ],  # fmt: skip
        }
        for c in configs.values()
    }
    ctx.put_json("spread.json", {**common, "configs": spread})
    fams = {**common, **study.families(configs)}
    ctx.put_json("families.json", fams)
    title = f"report.brdf: {len(configs)} configurations, {len(runs)} runs, {n_mat} materials"
    ctx.progress(0.95, "drawing")
    ctx.put_bytes("pareto.png", pareto_png(points, front, title), "image/png")
    ctx.put_bytes("families.png", families_png(fams, title), "image/png")
    held = [c["claim"] for c in claims if c.get("holds") is False]
    ctx.progress(1.0, f"front: {', '.join(front) or 'none timed'}; claims not holding: "
                 f"{'; '.join(held) or 'none'}")  # fmt: skip


#: The costs of ``pareto.json``'s panels, and their axis labels.
PANEL_COSTS = {
    "ns_per_eval": "ns_per_eval: fused Dr.Jit kernel execution, ns per evaluation",
    "bytes_per_material": "bytes_per_material: float32 parameters per material",
    "macs_per_eval": "macs_per_eval: multiply-adds per evaluation (any machine)",
    "bytes_per_eval": "bytes_per_eval: bytes read per evaluation (any machine)",
}


def panels(points: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The configurations as ``report.pareto``'s panels (the one ``pareto.json`` schema,
    ``docs/artifacts.md``): mean SMAPE over seeds against each cost that some configuration
    has, each panel with its own front."""
    from evaluators.metrics.pareto import front_indices

    out = []
    for cost, label in PANEL_COSTS.items():
        have = [p for p in points if p.get(cost) is not None]
        if not have:
            continue
        on = front_indices([float(p[cost]) for p in have], [p["smape_mean"] for p in have])
        pts = [
            {
                "candidate": p["config"],
                "mean": p["smape_mean"],
                "std": p["smape_std"],
                "min": p["smape_min"],
                "max": p["smape_max"],
                "n": p["n"],
                "cost": float(p[cost]),
                "front": i in on,
                "jobs": p["runs"],
                "seeds": p["seeds"],
                "kind": "train.brdf",
            }
            for i, p in enumerate(have)
        ]
        out.append({
            "dataset": None, "scene": None, "metric": qualified("brdf", "smape"), "cost": cost,
            "cost_label": label, "points": pts, "front": [pts[i]["candidate"] for i in on],
        })  # fmt: skip
    return out


#: Columns of ``pareto.json``'s points, in the result table.
PARETO_COLUMNS = (
    "per_material_params",
    "n",
    "smape_mean",
    "smape_std",
    "smape_min",
    "smape_max",
    "ns_per_eval",
    "torch_ns",
    "bytes_per_material",
    "macs_per_eval",
    "bytes_per_eval",
    "pareto",
)


def summarize(read: ArtifactReader) -> ResultTable | None:
    """The result table: ``pareto.json``, one row per configuration, and its claims."""
    doc = read("pareto.json")
    # Its own key ``points`` (per configuration, beside the typed panels), not the type's
    # (:class:`~jobapi.documents.ParetoDocument`): documents written before the panels
    # existed have only these, and still get their table.
    if not isinstance(doc, dict):
        return None
    points = [p for p in doc.get("points", []) if isinstance(p, dict) and "config" in p]
    if not points:
        return None
    rows = {str(p["config"]): {k: p.get(k) for k in PARETO_COLUMNS} for p in points}
    return ResultTable.from_report(
        doc,
        rows,
        title="Accuracy against cost",
        label_header="Configuration",
        columns=PARETO_COLUMNS,
    )


register(
    Kind(
        name="report.brdf",
        params=ReportBrdfParams,
        runner=run_report_brdf,
        description="Accuracy (mean SMAPE) against cost (fused ns/eval) over train.brdf runs: "
        "Pareto front, seed spread, per-family errors and the paper's claims checked.",
        artifacts=("pareto.json", "pareto.png", "spread.json", "families.json", "families.png"),
        smoke={"runs": ["step:train.brdf"], "speed_batch": 1024},
        figures=(
            Figure(
                "pareto.png",
                caption="Mean SMAPE against fused ns/eval: the Pareto front with seed spread.",
                lead=True,
            ),
        ),
        documents={
            "pareto.json": ParetoDocument,
            "spread.json": BrdfSpread,
            "families.json": BrdfFamilies,
        },
        summary=summarize,
    )
)
