"""Result rows of ``score`` (:mod:`jobapi.rows`): one row per candidate and metric (and per
material, for a whole model scored against a set of tables).

A candidate that is a render's image (``job:<render>/image.exr``) carries that render's
scene, spp, time, seed and settings (:func:`evaluators.render.rows.render_facts`), so a
score's rows chart error against samples and seconds directly. A model candidate
(``{"model": REF, "material": NAME}``) names its material and the model it came from. The
row's ``dataset`` is the reference ref (a ``generate.merl`` job for a whole model, or the
reference image).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from evaluators.render.rows import render_facts
from jobapi.rows import ResultRow, RowSource, base_row, number


def _candidate_facts(src: RowSource, spec: Any) -> dict[str, Any]:
    """Row fields of one candidate of the score's params."""
    if isinstance(spec, Mapping):  # a model candidate
        facts: dict[str, Any] = {"config": {"model": spec.get("model")}}
        if isinstance(spec.get("material"), str):
            facts["material"] = spec["material"]
        return facts
    if isinstance(spec, str):
        made_by = src.source(spec)
        if made_by is not None:
            return render_facts(made_by)
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
    rows: list[ResultRow] = []
    for label, values in doc["metrics"].items():
        facts = _candidate_facts(src, candidates.get(label))
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
                    rows.append(base_row(src, str(metric), value, **fields))
    return rows
