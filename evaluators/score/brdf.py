"""``score`` in BRDF space: the ``merl`` artifact kind (MERL ``.binary`` tables).

Registered with :func:`evaluators.score.artifacts.register_artifact_kind`; ``score`` imports this
module
from its explicit list :data:`evaluators.score.kind.ARTIFACT_KIND_MODULES`.

The kind ``merl``: MERL tables (``.binary``, ``application/x-merl-binary``), scored with
``smape`` (Eq. 6 of the hybrid-BRDF paper) and ``mae``, both on plain RGB BRDF values
``f(wi, wo)`` in 1/sr at fixed-seed direction pairs.

How a candidate is scored (every choice is written into ``metrics.json`` under ``settings``):

1. the same ``10**6`` pairs for every score: :func:`~evaluators.metrics.brdf.direction_pairs`
   with seed :data:`~evaluators.metrics.brdf.PAIRS_SEED`, ``wi`` and ``wo`` each
   cosine-weighted on the upper hemisphere (the job's own ``seed`` does not enter);
2. reference and candidates are evaluated as :class:`~evaluators.metrics.brdf.BrdfSampler`;
   tables through :class:`~evaluators.metrics.brdf.TableSampler`, multilinear lookup;
3. pairs where the reference has no data (lookup -1) are excluded for every candidate, and
   counted (``excluded_pairs``);
4. where a candidate has no data but the reference does, the candidate counts as 0 (a SMAPE
   term of 1, the worst); counted per candidate in ``candidate_missing_pairs``;
5. ``smape`` is Eq. 6 with ``eps = 0`` and 0/0 = 0, averaged over R, G, B; ``mae`` is the
   mean of ``|f - f^|`` over pairs and channels, in 1/sr.

The model kind ``brdf-model``: a ``train.brdf`` ``model.json`` (any JSON file whose
``format`` is ``matforge.brdf-model/1``), a candidate of ``merl`` references only, given as
``{"model": REF, "material": NAME}``. That material is evaluated at the same pairs, in
float64, by the format's reference evaluator :func:`models.brdf.portable.eval_portable`
(:class:`ModelSampler`), and scored exactly as a table candidate; ``metrics.json`` records
the model and material of each such candidate under ``settings.candidate_models``. Scoring
every material of a model at once is not offered: the reference is one table.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from evaluators.metrics.brdf import (
    DEFAULT_PAIRS,
    DISTRIBUTIONS,
    PAIRS_SEED,
    BrdfSampler,
    Distribution,
    TableSampler,
    brdf_mae,
    direction_pairs,
    sample_brdf,
    smape,
)
from evaluators.score.artifacts import ArtifactKind, Loaded, ScoreResult, register_artifact_kind
from evaluators.score.params import ScoreParams
from jobapi.errors import FormatError, JobFailed
from storage.formats.merl import MEDIA_TYPE, MerlTable, read_merl

if TYPE_CHECKING:
    from jobapi.context import JobContext

#: Metrics of BRDF-space scoring, in the order they are listed.
BRDF_METRICS: tuple[str, ...] = ("smape", "mae")
#: The pair distribution of every BRDF-space score.
DISTRIBUTION: Distribution = "cosine"
#: Whether tables are looked up with multilinear interpolation (reference and candidates).
INTERPOLATE = True
#: SMAPE's denominator floor in ``score``: 0, Eq. 6 exactly.
SMAPE_EPS = 0.0
#: Threads for table lookups (thread-safe numpy); other samplers are evaluated on one.
TABLE_THREADS = min(2, os.cpu_count() or 1)
#: The ``format`` of a ``model.json`` (:data:`models.brdf.portable.FORMAT`, not imported
#: here so that loading ``score`` does not import torch).
MODEL_FORMAT = "matforge.brdf-model/1"
#: Largest ``model.json`` that :func:`detect_model` parses to look at its ``format``.
MODEL_MAX_BYTES = 256 * 1024 * 1024


@dataclass(frozen=True, eq=False)
class PortableModel:
    """A loaded ``model.json``: its ref and its document."""

    ref: str
    doc: dict[str, Any]

    @property
    def material_names(self) -> list[str]:
        return [str(m.get("name")) for m in self.doc.get("materials", [])]


@dataclass(frozen=True, eq=False)
class ModelSampler:
    """One material of a ``model.json`` as a :class:`BrdfSampler`, through
    :func:`models.brdf.portable.eval_portable` (float64, 0 below the horizon)."""

    model: PortableModel
    material: str

    def eval(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """``(N, 3)`` BRDF values in 1/sr of the material at ``(N, 3)`` pairs."""
        from models.brdf.portable import eval_portable

        return eval_portable(self.model.doc, self.material, wi, wo)


def detect_model(path: Path) -> bool:
    """Whether the file at ``path`` is a JSON object whose ``format`` is :data:`MODEL_FORMAT`."""
    try:
        if path.stat().st_size > MODEL_MAX_BYTES:
            return False
        with open(path, "rb") as fh:
            if fh.read(64).lstrip()[:1] != b"{":
                return False
        doc = json.loads(path.read_bytes())
    except (OSError, ValueError):
        return False
    return isinstance(doc, dict) and doc.get("format") == MODEL_FORMAT


def load_model(path: Path, name: str) -> PortableModel:
    """A ``model.json``: parsed and checked for its format and a list of named materials."""
    try:
        doc = json.loads(path.read_bytes())
    except (OSError, ValueError) as exc:
        raise FormatError(name, f"not a JSON document: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != MODEL_FORMAT:
        raise FormatError(name, f"not a {MODEL_FORMAT} model.json")
    materials = doc.get("materials")
    if not isinstance(materials, list) or not all(
        isinstance(m, dict) and isinstance(m.get("name"), str) for m in materials
    ):
        raise FormatError(name, "model.json: 'materials' must be a list of named materials")
    return PortableModel(ref=name, doc=doc)


def bind_material(model: PortableModel, material: str) -> ModelSampler:
    """The :class:`ModelSampler` of ``material``; a ``FormatError`` naming the known ones."""
    names = model.material_names
    if material not in names:
        raise FormatError(
            model.ref, f"no material {material!r} in the model; it has {', '.join(names)}"
        )
    return ModelSampler(model, material)


def as_sampler(role: str, data: Any) -> BrdfSampler:
    """The :class:`BrdfSampler` of a loaded artifact: a table, or anything with ``eval``."""
    if isinstance(data, MerlTable):
        return TableSampler(data, interpolate=INTERPOLATE)
    if isinstance(data, BrdfSampler):
        return data
    raise JobFailed(f"{role}: {type(data).__name__} cannot be evaluated as a BRDF")


def _sample(role: str, sampler: BrdfSampler, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    workers = TABLE_THREADS if isinstance(sampler, TableSampler) else 1
    try:
        return sample_brdf(sampler, wi, wo, workers=workers)
    except ValueError as exc:
        raise JobFailed(f"{role}: {exc}") from None


def score_brdfs(
    reference: Loaded, candidates: dict[str, Loaded], params: ScoreParams, ctx: JobContext
) -> ScoreResult:
    """Score BRDFs (tables, and models' materials) in BRDF space with ``smape`` and ``mae``."""
    if params.exposure is not None:
        raise JobFailed("exposure: applies to HDR-FLIP only, not to BRDF-space scores")
    wanted = list(params.metrics or BRDF_METRICS)
    sampler = as_sampler("reference", reference.data)
    wi, wo, ref_values, excluded = reference_pairs("reference", sampler)
    kept = DEFAULT_PAIRS - excluded
    ctx.progress(0.1 + 0.85 / (len(candidates) + 1), "sampled the reference")

    results: dict[str, dict[str, float | None]] = {}
    missing: dict[str, int] = {}
    models: dict[str, dict[str, Any]] = {
        label: {
            "model": cand.data.model.ref,
            "material": cand.data.material,
            "model_type": cand.data.model.doc.get("model"),
        }
        for label, cand in sorted(candidates.items())
        if isinstance(cand.data, ModelSampler)
    }
    for i, (label, cand) in enumerate(sorted(candidates.items())):
        ctx.check_cancelled()
        role = f"candidate {label!r}"
        results[label], missing[label] = score_candidate(
            role, as_sampler(role, cand.data), wi, wo, ref_values, wanted
        )
        ctx.progress(
            0.1 + 0.85 * (i + 2) / (len(candidates) + 1),
            f"scored {i + 1}/{len(candidates)}: {label}",
        )

    settings: dict[str, Any] = {
        "artifact_kind": reference.kind,
        **brdf_settings(),
        "excluded_pairs": DEFAULT_PAIRS - kept,
        "scored_pairs": kept,
        "candidate_missing_pairs": missing,
    }
    if models:
        settings["candidate_models"] = models
        settings["model_evaluation"] = MODEL_EVALUATION
    external = {
        label: c.ref for label, c in sorted(candidates.items()) if c.kind == "external-brdf"
    }
    if external:
        settings["candidate_external"] = external
        settings["external_evaluation"] = EXTERNAL_EVALUATION
    return ScoreResult(metrics=results, settings=settings)


#: How a model's material is evaluated (``settings.model_evaluation``).
MODEL_EVALUATION = (
    "models.brdf.portable.eval_portable of the named material, float64, at the same pairs "
    "as the reference"
)


#: How a user's model is evaluated (``settings.external_evaluation``).
EXTERNAL_EVALUATION = (
    "the model's own runtime (ExternalModel.eval, float32 inputs), compared in float64 at the "
    "same pairs as the reference"
)


def score_candidate(
    role: str,
    sampler: BrdfSampler,
    wi: np.ndarray,
    wo: np.ndarray,
    ref_values: np.ndarray,
    wanted: list[str],
) -> tuple[dict[str, float | None], int]:
    """``({metric: value}, missing pairs)`` of one candidate at the reference's kept pairs
    (rules 4 and 5 of the module docstring)."""
    values = _sample(role, sampler, wi, wo)
    no_data = np.any(values < 0, axis=1)
    values[no_data] = 0.0
    row: dict[str, float | None] = {}
    try:
        for metric in wanted:
            if metric == "smape":
                row["smape"] = smape(ref_values, values, eps=SMAPE_EPS)
            elif metric == "mae":
                row["mae"] = brdf_mae(ref_values, values)
    except ValueError as exc:
        raise JobFailed(f"{role}: {exc}") from None
    return row, int(np.count_nonzero(no_data))


def reference_pairs(
    role: str, sampler: BrdfSampler
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """``(wi, wo, values, excluded)``: the scoring pairs where the reference has data
    (rules 1-3 of the module docstring). Raises :class:`JobFailed` if it has none."""
    wi, wo = direction_pairs(DEFAULT_PAIRS, seed=PAIRS_SEED, distribution=DISTRIBUTION)
    values = _sample(role, sampler, wi, wo)
    keep = ~np.any(values < 0, axis=1)
    if not keep.any():
        raise JobFailed(f"{role}: the BRDF has no data at any of the scoring pairs")
    return wi[keep], wo[keep], values[keep], DEFAULT_PAIRS - int(np.count_nonzero(keep))


def brdf_settings() -> dict[str, Any]:
    """The settings every BRDF-space ``metrics.json`` records (pairs, rules, formulas)."""
    return {
        "values": "plain RGB BRDF f(wi, wo) in 1/sr, no cosine factor",
        "pairs": DEFAULT_PAIRS,
        "seed": PAIRS_SEED,
        "distribution": DISTRIBUTION,
        "distribution_rule": DISTRIBUTIONS[DISTRIBUTION],
        "interpolation": "multilinear between bin centres" if INTERPOLATE else "nearest bin",
        "excluded_rule": "pairs where the reference has no data (negative) are excluded",
        "candidate_missing_rule": "counted as 0 where the reference has data",
        "smape": {
            "formula": "2/(N C) sum |f - f^| / (|f| + |f^| + eps), Eq. 6 of De Oliveira "
            "et al. (hybrid neural-microfacet BRDF)",
            "eps": SMAPE_EPS,
            "zero_over_zero": 0.0,
            "range": [0.0, 2.0],
            "channels": "mean over R, G, B",
        },
        "mae": {"formula": "1/(N C) sum |f - f^|", "units": "1/sr"},
    }


register_artifact_kind(
    ArtifactKind(
        name="merl",
        description="a MERL BRDF table",
        media_types=(MEDIA_TYPE,),
        extensions=(".binary",),
        magic=b"\x5a\x00\x00\x00\x5a\x00\x00\x00",  # int32 LE (90, 90): both MERL variants
        load=read_merl,
        scorer=score_brdfs,
        metrics=BRDF_METRICS,
        space="brdf",
        candidate_kinds=("brdf-model", "external-brdf"),
    )
)
register_artifact_kind(
    ArtifactKind(
        name="brdf-model",
        description="a trained BRDF model (model.json)",
        media_types=(),
        extensions=(),
        magic=b"",
        load=load_model,
        scorer=score_brdfs,
        metrics=BRDF_METRICS,
        space="brdf",
        detect=detect_model,
        bind=bind_material,
    )
)
