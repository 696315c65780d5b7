"""Result rows of ``score`` (:mod:`jobapi.rows`): one row per candidate and metric (and per
material, for a whole model scored against a set of tables).

A candidate that is a render's image (``job:<render>/image.exr``) carries that render's
scene, spp, time, seed and settings (:func:`evaluators.render.rows.render_facts`), so a
score's rows chart error against samples and seconds directly. A model candidate
(``{"model": REF, "material": NAME}``) names its material and the model it came from in
``config`` (its row is about the whole reference, one table, like a table candidate's). The
row's ``dataset`` is the reference ref (a ``generate.merl`` job for a whole model, or the
reference image).

Costs, measured the same way for every model and named with their ``runtime``: an
external candidate's (``{"external": {...}}``) from the job's measurement ``cost`` (manifest)
(:mod:`models.external.cost`: ``ns_per_eval`` on the fixed batch, ``bytes_per_network`` its
parameter bytes); a trained model's (``{"model": "job:<train>/model.json", ...}``) from its
training job's rows (``speed.json``'s fused kernel time on the same kind of batch, bytes per
material and network); a MERL table candidate (``...binary``) has 0 multiply-adds and
reads eight RGB float32 bins per evaluation (:func:`models.counts.merl_table_counts`). A
BTF score (external BTFs against a BTF job's slices) gives ``l1``
and ``relative_l1`` per candidate and per failure case (``material`` and ``family`` the
case's name), as ``train.btf``'s rows do, so both land in the same ``report.pareto`` and
``report.stability`` panels.

Metric names say their space (:mod:`jobapi.metric_names`): an image score's rows are
``image.flip``, ``image.psnr``, ``image.ssim``, ``image.mae``, ``image.mse``; a BRDF
score's (tables, models, sets of tables) ``brdf.smape`` and ``brdf.mae``, so that an image
MAE and a BRDF-space MAE never share a column. ``metrics.json`` keeps the names of the
score's ``metrics`` param. The space comes from the reference's artifact kind
(``settings.artifact_kind``, :attr:`evaluators.score.artifacts.ArtifactKind.space`).
"""

from __future__ import annotations

import statistics
from collections.abc import Mapping
from typing import Any

from evaluators.render.rows import render_facts
from evaluators.score.artifacts import ARTIFACT_KINDS
from jobapi.kinds import registered
from jobapi.metric_names import ALIASES, qualified
from jobapi.rows import ResultRow, RowSource, base_row, number

#: The cost columns a candidate's rows carry.
CANDIDATE_COSTS = (
    "ns_per_eval", "runtime", "bytes_per_material", "bytes_per_network", "macs_per_eval",
    "bytes_per_eval",
)  # fmt: skip


#: The space of the settings-only artifact kinds of ``metrics.json`` (a set of MERL
#: tables; BTF slices have metrics of one space only).
SETTINGS_SPACES = {"merl-set": "brdf", "btf-slices": None}
#: Every metric name a score's rows may have (:attr:`jobapi.kinds.Kind.metrics`).
METRICS = (
    *(qualified("image", m) for m in ("flip", "psnr", "ssim", "mae", "mse")),
    *(qualified("brdf", m) for m in ("smape", "mae")),
    "l1",
    "relative_l1",
)


def metric_space(doc: Mapping[str, Any]) -> str | None:
    """The space of a ``metrics.json``'s metrics (``"image"``, ``"brdf"``; ``None``: one
    space only): from its ``settings.artifact_kind``, or for a document without one from
    its metric names (``smape`` is BRDF-space only, ``flip``, ``psnr``, ``ssim``, ``mse``
    image-space only)."""
    settings = doc.get("settings")
    kind = settings.get("artifact_kind") if isinstance(settings, Mapping) else None
    if isinstance(kind, str) and kind in ARTIFACT_KINDS:
        return ARTIFACT_KINDS[kind].space
    if isinstance(kind, str) and kind in SETTINGS_SPACES:
        return SETTINGS_SPACES[kind]
    names = {str(m) for v in doc["metrics"].values() if isinstance(v, Mapping) for m in v}
    for space in ("brdf", "image"):
        if any(ALIASES.get(n) == (qualified(space, n),) for n in names):
            return space
    return None


def _model_costs(src: RowSource, ref: Any, material: Any) -> dict[str, Any]:
    """The costs of a trained model's material, from its training job's rows."""
    made_by = src.source(ref) if isinstance(ref, str) else None
    kind = registered().get(made_by.job.kind) if made_by is not None else None
    if made_by is None or kind is None or kind.rows is None:
        return {}
    rows = [r for r in kind.rows(made_by) if r.material in (material, "mean", None)]
    out: dict[str, Any] = {}
    for col in CANDIDATE_COSTS:
        found = [getattr(r, col) for r in rows if getattr(r, col) is not None]
        if found:
            out[col] = found[0] if col == "runtime" else float(statistics.median(found))
    return out


def _external_costs(cost: Any, label: str) -> dict[str, Any]:
    found = (cost.get("candidates") or {}).get(label) if isinstance(cost, Mapping) else None
    if not isinstance(found, Mapping):
        return {}
    runtime = found.get("runtime")
    return {
        "ns_per_eval": number(found.get("ns_per_eval")),
        "bytes_per_material": number(found.get("bytes_per_material")),
        "bytes_per_network": number(found.get("bytes_per_network")),
        "macs_per_eval": number(found.get("macs_per_eval")),
        "bytes_per_eval": number(found.get("bytes_per_eval")),
        "runtime": str(runtime) if isinstance(runtime, str) else None,
    }


def _candidate_facts(src: RowSource, spec: Any, label: str, cost: Any) -> dict[str, Any]:
    """Row fields of one candidate of the score's params."""
    if isinstance(spec, Mapping) and isinstance(spec.get("external"), Mapping):
        value = spec["external"]
        return {
            "config": {"external": {k: v for k, v in value.items() if v is not None}},
            **_external_costs(cost, label),
        }
    if isinstance(spec, Mapping):  # a model candidate
        # One material against one table is the whole of what was scored (a row beside
        # the table's and a user's model's in report.pareto): the material goes in config.
        facts: dict[str, Any] = {"config": {"model": spec.get("model")}}
        if isinstance(spec.get("material"), str):
            facts["config"]["material"] = spec["material"]
        facts.update(_model_costs(src, spec.get("model"), spec.get("material")))
        # measured in this job (a BTF score times its built-in models too): that wins
        facts.update({k: v for k, v in _external_costs(cost, label).items() if v is not None})
        return facts
    if isinstance(spec, str):
        made_by = src.source(spec)
        facts = render_facts(made_by) if made_by is not None else {}
        if spec.endswith(".binary"):  # a MERL table: what its lookup reads
            from models.counts import merl_table_counts

            facts = {**merl_table_counts(), **facts}
        return facts
    return {}


def score_rows(src: RowSource) -> list[ResultRow]:
    """Every candidate's metrics from ``metrics.json``, with each candidate's facts."""
    doc = src.read("metrics.json")
    if not isinstance(doc, Mapping) or not isinstance(doc.get("metrics"), Mapping):
        return []
    params = src.job.params
    candidates = params.get("candidates")
    candidates = candidates if isinstance(candidates, Mapping) else {}
    reference = params.get("reference")
    # What was scored against: a set of tables (its generate job) or a reference image;
    # the fronts of report.pareto are drawn per dataset, so each reference is its own.
    dataset = reference if isinstance(reference, str) else None
    ref_src = src.source(reference) if isinstance(reference, str) else None
    ref_scene = render_facts(ref_src).get("scene") if ref_src is not None else None
    per = doc.get("per_material")
    per = per if isinstance(per, Mapping) else {}
    space = metric_space(doc)

    def named(metric: Any) -> str:
        return qualified(space, str(metric)) if space is not None else str(metric)

    rows: list[ResultRow] = []
    cost = src.job.measured.get("cost")
    cases = doc.get("cases")
    cases = cases if isinstance(cases, Mapping) else {}
    for label, values in doc["metrics"].items():
        facts = _candidate_facts(src, candidates.get(label), str(label), cost)
        facts.setdefault("scene", ref_scene)
        common = {"candidate": str(label), "dataset": dataset, **facts}
        materials = per.get(label) or {}
        overall = "mean" if materials else None  # the mean over the materials that follow
        for material, vals in [(overall, values), *materials.items()]:
            if not isinstance(vals, Mapping):
                continue
            fields = dict(common)
            if material is not None:
                fields["material"] = str(material)
            for metric, raw in vals.items():
                value = number(raw)
                if value is not None:
                    rows.append(base_row(src, named(metric), value, **fields))
        for case in cases.get(label) or []:  # a BTF score's failure cases
            if not isinstance(case, Mapping) or not case.get("case"):
                continue
            name = str(case["case"])
            for metric in ("l1", "relative_l1"):
                if (value := number(case.get(metric))) is not None:
                    rows.append(
                        base_row(src, metric, value, **{**common, "material": name, "family": name})
                    )
    return rows
