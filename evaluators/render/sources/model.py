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

This module registers the source when imported; :mod:`evaluators.render.kind` must import it so
that the source exists wherever the ``render`` kind does.
"""

from __future__ import annotations

import types
from typing import TYPE_CHECKING, Any

from pydantic import Field, model_validator

from evaluators.render.bsdfs.brdf_model import MODEL_BSDF_NAME, register_model_bsdf
from evaluators.render.sources.common import register_material_source
from evaluators.render.sources.fabric import FabricValue
from evaluators.render.sources.fabric_model import (
    InterpolationValue,
    check_interpolation,
    resolve_model_fabric,
)
from jobapi.errors import JobFailed
from jobapi.params import Ref, StrictModel
from models.brdf.fused import bake_material, read_model

if TYPE_CHECKING:
    from jobapi.context import JobContext


class ModelSiblings(StrictModel):
    """The keys next to ``"model"`` in a ``{"model": REF, ...}`` material: exactly one of
    ``material`` (a BRDF model's material) and ``fabric`` (a fabric model's material)."""

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

    @model_validator(mode="after")
    def _one_material(self) -> ModelSiblings:
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
    if "fabric" in value:
        return resolve_model_fabric(value, ctx, mi)
    ref, name = value["model"], value["material"]
    depth = value.get("neural_max_depth")
    path = ctx.resolve(ref)
    try:
        baked = bake_material(read_model(path), name)
    except ValueError as exc:
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


register_material_source(
    "model",
    resolve_model,
    value_type=Ref,
    siblings=ModelSiblings,
    summary="One material of a trained BRDF model: {'model': REF to a model.json, "
    "'material': NAME, optional 'neural_max_depth': int}; or of a train.fabric model: "
    "{'model': REF to its model.json or model.pt, 'fabric': {...}, optional 'interpolate': "
    "{'fabric': {...}, 't': 0..1}}; rendered with the "
    "fused-network BSDF.",
)
