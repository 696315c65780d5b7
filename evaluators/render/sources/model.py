"""The ``model`` material source: ``{"model": REF, "material": NAME}`` renders a trained model.

``REF`` is an artifact reference (``"job:<id>/model.json"`` of a ``train.brdf`` job, or a
``"sha256:<digest>"`` of an imported ``model.json``) to a ``matforge.brdf-model/1``
document (:mod:`models.brdf.portable`); ``NAME`` is one of its materials. Inside the job the
document is read, the material is looked up, and it becomes the ``brdf_model`` BSDF of
:mod:`evaluators.render.bsdfs.brdf_model`: the network fused into the render kernel, sampled by MIS
between cosine and the material's fitted GGX lobe (Sec. 5.2 of the hybrid-BRDF paper).

``neural_max_depth`` (optional, int >= 0) asks for selective neural evaluation (Sec. 5.3):
the network only at path vertices of depth ``< neural_max_depth`` (0 = the camera ray's
hit), the analytic part ``f_a`` beyond. Only the ``neural_depth`` integrator of
:mod:`evaluators.render.integrators.neural_depth` knows the depth: the resolved BSDF carries
``neural_max_depth`` as an attribute, and the renderer must swap its integrator with
:func:`evaluators.render.integrators.neural_depth.integrator_for`. So that the setting is never
silently ignored, the resolver refuses it (the job fails with a message) unless
:mod:`evaluators.render.kind` calls ``integrator_for``. Only hybrid models have an ``f_a`` to fall
back on.

``material`` and ``neural_max_depth`` are *sibling* keys of ``model`` in the material
object (see :mod:`evaluators.render.sources.common`)::

    {"model": "job:<id>/model.json", "material": "gold-metallic-paint", "neural_max_depth": 1}

A ``train.fabric`` model takes a ``fabric`` sibling instead of ``material`` (the value of a
``{"fabric": ...}`` material): ``{"model": "job:<id>/model.pt", "fabric": {...}}`` renders
the woven fabric through the network's fused decoder, with the same pixel footprints as the
Monte Carlo reference (:mod:`evaluators.render.sources.fabric_model`). With it, an optional
``interpolate`` sibling ``{"fabric": {...}, "t": 0.5}`` renders the latent interpolated
between the two materials (Sec. 6.3 of the woven-fabric paper).

A trained **BTF** model (``train.btf``, Xu et al. 2025) is two files, ``model.json`` and
``textures.npz``, so it is named by its whole job: ``{"model": "job:<train.btf id>"}``, with
an optional ``uv_scale`` sibling (see :mod:`evaluators.render.sources.btf`) and none of the
keys above; it renders through the ``btf_model`` BSDF
(:mod:`evaluators.render.bsdfs.btf_model`). Whether the reference is a whole job decides
which siblings are allowed, at spec time (the siblings see it as their validation context).

This module registers the source when imported; :mod:`evaluators.render.kind` must import it so
that the source exists wherever the ``render`` kind does.
"""

from __future__ import annotations

import json
import types
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

from pydantic import AfterValidator, Field, ValidationInfo, model_validator

from evaluators.render.bsdfs.brdf_model import MODEL_BSDF_NAME, register_model_bsdf
from evaluators.render.sources.btf import (
    BTF_MODEL_FORMAT,
    UV_SCALE_DESCRIPTION,
    UvScale,
    resolve_btf_model,
)
from evaluators.render.sources.common import register_material_source
from evaluators.render.sources.fabric import FabricValue
from evaluators.render.sources.fabric_model import (
    InterpolationValue,
    check_interpolation,
    resolve_model_fabric,
)
from jobapi.errors import JobFailed
from jobapi.params import JOB_ID_REF, StrictModel, is_ref
from models.brdf.fused import bake_material, read_model

if TYPE_CHECKING:
    from jobapi.context import JobContext


def _check_model_ref(value: str) -> str:
    if not (is_ref(value) or JOB_ID_REF.match(value)):
        raise ValueError(
            "must be an artifact reference 'job:<job-id>/<artifact-name>' or "
            "'sha256:<64 lowercase hex>', or for a BTF model the whole train.btf job "
            "'job:<job-id>'"
        )
    return value


#: The ``model`` value: an artifact reference, or a whole ``train.btf`` job.
ModelRef = Annotated[str, AfterValidator(_check_model_ref)]


def is_btf_model_ref(ref: str) -> bool:
    """Whether a ``model`` value names a whole job (a BTF model)."""
    return bool(JOB_ID_REF.match(ref))


class ModelSiblings(StrictModel):
    """The keys next to ``"model"`` in a ``{"model": REF, ...}`` material: exactly one of
    ``material`` (a BRDF model's material) and ``fabric`` (a fabric model's material); for
    a BTF model (``REF`` a whole job), at most ``uv_scale``."""

    material: str | None = Field(
        default=None,
        min_length=1,
        max_length=200,
        description="Name of the material in the model (its materials.json / model.json).",
    )
    fabric: FabricValue | None = Field(
        default=None,
        description="For a train.fabric model: the woven-fabric material (the 'fabric' "
        "material's fields); rendered by the network through the fused decoder.",
    )
    interpolate: InterpolationValue | None = Field(
        default=None,
        description="With 'fabric': render the latent (1 - t) z(fabric) + t z(B) of a "
        "second material B {'fabric': {...}, 't': 0..1} of the same pattern (Sec. 6.3 of the "
        "woven-fabric paper); the shading fields are interpolated alike.",
    )
    neural_max_depth: int | None = Field(
        default=None,
        ge=0,
        le=64,
        description="Evaluate the network only at path vertices of depth < this (0: the "
        "analytic part everywhere; 1: first hits only); default: at every vertex. Hybrid "
        "models only (Sec. 5.3 of the hybrid-BRDF paper).",
    )

    uv_scale: UvScale | None = Field(
        default=None, description="For a train.btf model: " + UV_SCALE_DESCRIPTION
    )

    @model_validator(mode="after")
    def _one_material(self, info: ValidationInfo) -> ModelSiblings:
        ref = (info.context or {}).get("model")
        if isinstance(ref, str) and is_btf_model_ref(ref):
            given = [k for k in ("material", "fabric", "interpolate", "neural_max_depth")
                     if getattr(self, k) is not None]  # fmt: skip
            if given:
                raise ValueError(
                    f"{given[0]}: a whole-job reference names a BTF model (train.btf), which "
                    f"takes only 'uv_scale'; a BRDF or fabric model takes its artifact "
                    f"reference, e.g. 'job:<id>/model.json'"
                )
            return self
        if self.uv_scale is not None:
            raise ValueError(
                "uv_scale: applies to BTF models, named by their whole train.btf job 'job:<id>'"
            )
        if (self.material is None) == (self.fabric is None):
            raise ValueError(
                "material: this key is required"
                if self.material is None
                else "give either 'material' or 'fabric', not both"
            )
        if self.fabric is not None and self.neural_max_depth is not None:
            raise ValueError("neural_max_depth applies to BRDF models, not to 'fabric'")
        if self.interpolate is not None:
            if self.fabric is None:
                raise ValueError("interpolate applies to fabric models: give 'fabric' too")
            check_interpolation(self.fabric, self.interpolate.fabric)  # type: ignore[arg-type]
        return self


def resolve_model(value: dict[str, Any], ctx: JobContext, mi: types.ModuleType) -> Any:
    """Resolve ``{"model": REF, "material": NAME, ...}`` to a ``brdf_model`` BSDF.

    Raises :class:`JobFailed` naming the reference when it does not resolve, the file is not
    a model document, the material is not in it, ``neural_max_depth`` is given for a model
    without an analytic part, or Mitsuba runs a variant the BSDF cannot use.
    """
    if is_btf_model_ref(value["model"]):
        return resolve_btf_model(value, ctx, mi)
    if "fabric" in value:
        return resolve_model_fabric(value, ctx, mi)
    ref, name = value["model"], value["material"]
    depth = value.get("neural_max_depth")
    path = ctx.resolve(ref)
    try:
        baked = bake_material(read_model(path), name)
    except ValueError as exc:
        if _format_of(path) == BTF_MODEL_FORMAT:
            raise JobFailed(
                f"material.model: {ref} is a BTF model: name its whole train.btf job "
                f"{{'model': 'job:<id>'}}, without 'material'"
            ) from None
        raise JobFailed(f"material.model: {ref}: {exc}") from None
    if depth is not None and not baked.has_analytic:
        raise JobFailed(
            f"material.model: {ref}: neural_max_depth needs a hybrid model (this one is "
            f"{baked.model}: it has no analytic part to fall back on)"
        )
    try:
        register_model_bsdf(mi)
    except RuntimeError as exc:
        raise JobFailed(f"material.model: {exc}") from None
    plugin: dict[str, Any] = {"type": MODEL_BSDF_NAME, "filename": str(path), "material": name}
    if depth is not None:
        plugin["neural_max_depth"] = int(depth)
    return plugin


def _format_of(path: Path) -> Any:
    """The ``format`` of a JSON document at ``path`` (``None`` if unreadable)."""
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    return doc.get("format") if isinstance(doc, dict) else None


register_material_source(
    "model",
    resolve_model,
    value_type=ModelRef,
    siblings=ModelSiblings,
    summary="One material of a trained BRDF model: {'model': REF to a model.json, "
    "'material': NAME, optional 'neural_max_depth': int}; or of a train.fabric model: "
    "{'model': REF to its model.json or model.pt, 'fabric': {...}, optional 'interpolate': "
    "{'fabric': {...}, 't': 0..1}}; or a train.btf model: {'model': 'job:<train.btf id>', "
    "optional 'uv_scale': s or [s_u, s_v]}; rendered with the fused-network BSDF.",
)
