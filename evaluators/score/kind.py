"""The ``score`` job kind: score candidate artifacts against a reference.

The reference's *artifact kind* picks the scorer, through :data:`ARTIFACT_KINDS`:

=============  ===================  ====================================  =================
kind           files                metrics                               values compared
=============  ===================  ====================================  =================
``image-hdr``  OpenEXR (``.exr``)   ``flip`` (HDR-FLIP), ``psnr``,         linear RGB
                                    ``ssim``, ``mae``, ``mse``
``image-ldr``  PNG (``.png``)       ``flip`` (LDR-FLIP), ``psnr``,         sRGB-encoded
                                    ``ssim``, ``mae``, ``mse``             values in [0, 1]
``merl``       MERL table            ``smape`` (Eq. 6 of the hybrid-BRDF   plain RGB BRDF in
               (``.binary``)         paper), ``mae``                       1/sr at 10^6 pairs
=============  ===================  ====================================  =================

Other artifact kinds plug in with :func:`register_artifact_kind` (a loader, a scorer, the
metrics it supports) from modules in :data:`ARTIFACT_KIND_MODULES`: images in
:mod:`evaluators.score.images`, ``merl`` and ``brdf-model`` in :mod:`evaluators.score.brdf`.
``metrics`` left out means all that the reference's kind supports; one it does not support
fails the job, listing those it does.

Candidates are of the reference's kind, or of a kind it lists in ``candidate_kinds``. A
*model* kind (one with ``bind``) is a file holding several materials, scored one material
at a time: such a candidate is given as ``{"model": REF, "material": NAME}``. The model kind
``brdf-model`` (a ``train.brdf`` ``model.json``, recognised by its ``format`` field) is
scored against ``merl`` references, evaluated for that material with the portable
evaluator at the same pairs as tables; a model cannot be the reference. A whole model,
``{"model": REF}``, is scored against a *set* of tables given as the reference
(``job:<generate.merl id>`` or ``{material name: table ref}``), each material against the
table of the same name (:mod:`evaluators.score.sets`); the two forms are checked against
the reference's form at spec time.

A user's model, ``{"external": {"model": REF, "kind": "brdf" | "btf"}}``
(:mod:`evaluators.score.external`): an external BRDF is a candidate of ``merl`` references,
scored as a ``brdf-model`` is; external BTFs are scored against the slices of a BTF job
(reference ``job:<generate.btf id>``) with ``train.btf``'s L1, per failure case too. Each
external candidate's cost, measured as the built-in models' (``ns_per_eval`` on a fixed
batch in its runtime, parameter bytes), goes to the job's manifest as the measurement
``cost`` (``timings.measured.cost``), not to an artifact: timings vary between runs, and the
artifacts of a spec are the same bytes every time.

Choices for images, recorded in ``metrics.json`` under ``settings``:

- ``data_range`` of PSNR and SSIM: 1 for PNG; for EXR the reference's largest pixel value
  (over all channels), so that PSNR is the error relative to the brightest reference value;
- HDR-FLIP's exposure range is computed once from the reference (unless given in
  ``exposure``) and used for every candidate, so their FLIP values are comparable;
- PSNR of an identical candidate is infinite and is written as ``null``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from evaluators.score import brdf, external, images
from evaluators.score.artifacts import ARTIFACT_KINDS, Loaded, load_input
from evaluators.score.document import ScoreMetrics
from evaluators.score.params import ExternalCandidate, ModelCandidate, ScoreParams
from evaluators.score.rows import METRICS as ROW_METRICS
from evaluators.score.rows import score_rows
from jobapi.documents import read_typed
from jobapi.errors import JobFailed
from jobapi.kinds import Kind, register
from jobapi.results import ArtifactReader, ResultTable

if TYPE_CHECKING:
    from jobapi.context import JobContext

#: The modules that register the artifact kinds ``score`` knows (explicit, in order).
ARTIFACT_KIND_MODULES = (images, brdf, external)


# -- the runner ------------------------------------------------------------------------------


def run_score(params: ScoreParams, ctx: JobContext) -> None:
    """Load the reference and candidates, score them, and store ``metrics.json``."""
    ctx.progress(0.0, "loading inputs")
    if params.btf_set:
        external.score_btf_slices(params, ctx)
        return
    if params.table_set:
        from evaluators.score.sets import score_table_set

        score_table_set(params, ctx)
        return
    assert isinstance(params.reference, str)
    reference = load_input(params.reference, "reference", ctx)
    kind = ARTIFACT_KINDS[reference.kind]
    metrics = list(params.metrics or kind.metrics)
    unsupported = [m for m in metrics if m not in kind.metrics]
    if unsupported:
        names = ", ".join(repr(m) for m in unsupported)
        verb = "metric " + names + " does" if len(unsupported) == 1 else f"metrics {names} do"
        raise JobFailed(
            f"metrics: {verb} not apply to {kind.description}; use {', '.join(kind.metrics)}"
        )
    params = params.model_copy(update={"metrics": metrics})  # scorers see the concrete list
    candidates: dict[str, Loaded] = {}
    for label, spec in params.candidates.items():
        role = f"candidate {label!r}"
        if isinstance(spec, ExternalCandidate):
            cand = external.external_brdf_input(label, spec, ctx)
        elif isinstance(spec, ModelCandidate):
            assert spec.material is not None  # whole models only with table sets
            cand = load_input(spec.model, role, ctx, material=spec.material)
        else:
            cand = load_input(spec, role, ctx)
        if cand.kind != reference.kind and cand.kind not in kind.candidate_kinds:
            raise JobFailed(
                f"candidate {label!r} is {ARTIFACT_KINDS[cand.kind].description} "
                f"but the reference is {kind.description}; score artifacts of "
                f"one kind against each other"
            )
        candidates[label] = cand
    ctx.progress(0.1, f"scoring {len(candidates)} candidates")
    result = kind.scorer(reference, candidates, params, ctx)
    ctx.put_json(
        "metrics.json",
        {"reference": params.reference, "metrics": result.metrics, "settings": result.settings},
    )
    users = {k: c.data.model for k, c in candidates.items() if c.kind == external.EXTERNAL_BRDF}
    if users:
        ctx.progress(0.95, f"timing {len(users)} external model(s)")
        ctx.measure("cost", external.external_costs(users, ctx))
    ctx.progress(1.0, f"scored {len(candidates)} candidates with {', '.join(metrics)}")


def summarize(read: ArtifactReader) -> ResultTable | None:
    """The result table of a ``score`` job: ``metrics.json``, one row per candidate (and,
    for whole models against a set of tables, one ``"<label> / <material>"`` row per
    material after its candidate's row), one column per metric."""
    doc = read_typed(read("metrics.json"), ScoreMetrics)
    if doc is None:
        return None
    rows: dict[str, dict[str, Any]] = {}
    per = doc.get("per_material", {})
    for label, values in doc["metrics"].items():
        rows[label] = dict(values)
        for name, vals in per.get(label, {}).items():
            rows[f"{label} / {name}"] = dict(vals)
    names: list[str] = []
    for values in rows.values():
        names.extend(str(m) for m in values if m not in names)
    reference = doc.get("reference")
    return ResultTable(
        title="Metrics",
        label_header="Candidate",
        columns=names,
        rows=rows,
        reference=reference if isinstance(reference, str) else None,
        settings=doc.get("settings"),
    )


register(
    Kind(
        name="score",
        params=ScoreParams,
        runner=run_score,
        description="Scores candidate artifacts against a reference (images: FLIP, PSNR, "
        "SSIM, MAE, MSE; MERL BRDF tables, and trained models' materials against them: "
        "SMAPE, MAE in BRDF space).",
        artifacts=("metrics.json", "flip_<label>.png"),
        smoke={
            "reference": "step:render/image.exr",
            "candidates": {"same": "step:render/image.exr"},
        },
        documents={"metrics.json": ScoreMetrics},
        summary=summarize,
        rows=score_rows,
        metrics=ROW_METRICS,
    )
)
