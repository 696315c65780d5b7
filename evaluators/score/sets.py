"""``score`` of whole trained models against a set of MERL tables, material by material.

The form (validated at spec time by :class:`evaluators.score.kind.ScoreParams`)::

    {"reference": "job:<generate.merl job id>" | {"<material>": "<table ref>", ...},
     "candidates": {"<label>": {"model": "<model.json ref>"}, ...}}

The reference set names the materials to score: ``job:<id>`` is every table of that job's
``materials.json`` (a ``generate.merl`` job), in its order; a mapping is those tables under
those names. Every candidate is a ``train.brdf`` ``model.json``; each material of the set is
scored against the model's material of the same name, exactly as one ``{model, material}``
candidate against one table is (:mod:`evaluators.score.brdf`: the same 10^6 fixed-seed
cosine-weighted pairs, pairs without table data excluded, ``smape`` Eq. 6 and ``mae``). A
model lacking one of the set's materials fails the job, naming it; a model's materials that
the set does not name are not scored (listed under ``settings.candidate_models``).

``metrics.json``::

    {"reference": <as given>,
     "metrics": {label: {"smape": mean, "mae": mean}},          # plain means over materials
     "per_material": {label: {material: {"smape", "mae"}}},
     "settings": {... the BRDF-space settings ..., "reference_tables": {material: ref},
                  "excluded_pairs": {material: n}, "candidate_missing_pairs": {label: n},
                  "candidate_models": {label: {"model", "model_type", "not_scored"}}}}
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from evaluators.score.brdf import (
    BRDF_METRICS,
    MODEL_EVALUATION,
    ModelSampler,
    PortableModel,
    as_sampler,
    brdf_settings,
    detect_model,
    load_model,
    reference_pairs,
    score_candidate,
)
from jobapi.documents import DocumentError, check_typed
from jobapi.errors import FormatError, JobFailed
from storage.formats.merl import read_merl
from storage.formats.merl_materials import MerlMaterials

if TYPE_CHECKING:
    from evaluators.score.params import ScoreParams
    from jobapi.context import JobContext


def reference_tables(reference: str | dict[str, str], ctx: JobContext) -> dict[str, str]:
    """``{material name: table ref}`` of a set reference, in the set's order."""
    if isinstance(reference, dict):
        return dict(reference)
    job_id = reference.removeprefix("job:")
    job = ctx.input_job(job_id, "reference")
    names = {a.name for a in job.artifacts}
    if "materials.json" not in names:
        raise JobFailed(
            f"reference: job {job_id} ({job.kind}) has no materials.json; give a generate.merl "
            "job or a mapping {material name: table ref}"
        )
    name = f"job:{job_id}/materials.json"
    doc = json.loads(ctx.read_ref(name))
    try:
        check_typed(name, doc, MerlMaterials)
    except DocumentError as exc:  # e.g. a train.brdf job's materials.json
        raise JobFailed(f"reference: job {job_id} lists no MERL tables in its materials.json "
                        f"({exc})") from None  # fmt: skip
    records = cast(MerlMaterials, doc)["materials"]
    tables = {r["name"]: f"job:{job_id}/{r['artifacts']['table']}" for r in records}
    if not tables:
        raise JobFailed(f"reference: job {job_id} lists no MERL tables in its materials.json")
    return tables


def _load_model(label: str, ref: str, ctx: JobContext) -> PortableModel:
    role = f"candidate {label!r}"
    path = ctx.resolve(ref)
    if not detect_model(path):
        raise JobFailed(f"{role}: {ref} is not a trained BRDF model (a train.brdf model.json)")
    try:
        return load_model(path, ref)
    except FormatError as exc:
        raise JobFailed(f"{role}: {exc}") from None


def score_table_set(params: ScoreParams, ctx: JobContext) -> None:
    """Score every candidate model on every material of the set; store ``metrics.json``."""
    wanted = list(params.metrics or BRDF_METRICS)
    bad = [m for m in wanted if m not in BRDF_METRICS]
    if bad:
        raise JobFailed(
            f"metrics: {', '.join(repr(m) for m in bad)} do not apply to BRDF tables; use "
            f"{', '.join(BRDF_METRICS)}"
        )
    if params.exposure is not None:
        raise JobFailed("exposure: applies to HDR-FLIP only, not to BRDF-space scores")
    assert not isinstance(params.reference, str) or params.reference.startswith("job:")
    tables = reference_tables(params.reference, ctx)
    models: dict[str, PortableModel] = {}
    for label, cand in sorted(params.candidates.items()):
        model = _load_model(label, str(getattr(cand, "model", cand)), ctx)
        missing = [n for n in tables if n not in model.material_names]
        if missing:
            raise JobFailed(
                f"candidate {label!r}: the model has no material {', '.join(map(repr, missing))} "
                f"of the reference; it has {', '.join(model.material_names)}"
            )
        models[label] = model
    per: dict[str, dict[str, dict[str, float | None]]] = {label: {} for label in models}
    absent: dict[str, int] = dict.fromkeys(models, 0)
    excluded: dict[str, int] = {}
    for i, (name, ref) in enumerate(tables.items()):
        ctx.check_cancelled()
        try:
            table = read_merl(ctx.resolve(ref), ref)
        except FormatError as exc:
            raise JobFailed(f"reference table {name!r}: {exc}") from None
        wi, wo, values, excluded[name] = reference_pairs(
            f"reference table {name!r}", as_sampler(name, table)
        )
        for label, model in models.items():
            row, n_missing = score_candidate(
                f"candidate {label!r}, material {name!r}",
                ModelSampler(model, name),
                wi,
                wo,
                values,
                wanted,
            )
            per[label][name] = row
            absent[label] += n_missing
        ctx.progress(0.05 + 0.9 * (i + 1) / len(tables), f"scored {i + 1}/{len(tables)}: {name}")
    means = {
        label: {m: float(np.mean([r[m] for r in rows.values()])) for m in wanted}
        for label, rows in per.items()
    }
    settings: dict[str, Any] = {
        "artifact_kind": "merl-set",
        **brdf_settings(),
        "reference_tables": tables,
        "excluded_pairs": excluded,
        "candidate_missing_pairs": absent,
        "mean": "plain mean over the reference's materials",
        "model_evaluation": MODEL_EVALUATION,
        "candidate_models": {
            label: {
                "model": m.ref,
                "model_type": m.doc.get("model"),
                "not_scored": [n for n in m.material_names if n not in tables],
            }
            for label, m in models.items()
        },
    }
    ctx.put_json(
        "metrics.json",
        {
            "reference": params.reference,
            "metrics": means,
            "per_material": per,
            "settings": settings,
        },
    )
    ctx.progress(1.0, f"scored {len(models)} model(s) on {len(tables)} materials")
