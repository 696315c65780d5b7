"""The ``external`` material source: a user's own BRDF or BTF model, from a data file.

::

    {"external": {"model": "sha256:...", "kind": "brdf"}}
    {"external": {"model": "job:<id>/my-btf.json", "kind": "btf", "uv_scale": 4}}

``model`` is an artifact reference to an uploaded (``matforge import``, ``POST
/api/artifacts``) or produced file; its content decides the runtime:

- a ``matforge.mlp-brdf/1`` / ``matforge.mlp-btf/1`` JSON document (``docs/formats.md``)
  renders through the fused Dr.Jit kernel: the ``external_mlp`` BSDF
  (:mod:`evaluators.render.bsdfs.external_mlp`, GGX/cosine MIS when the model has an
  analytic part) or ``external_mlp_btf`` (:mod:`evaluators.render.bsdfs.external_mlp_btf`);
- an ONNX file renders through :mod:`evaluators.render.bsdfs.external_onnx`: in the fused
  Dr.Jit kernel when its graph is an MLP (:mod:`models.external.onnx_mlp`), else through
  onnxruntime; ``runtime: "onnxruntime"`` asks for onnxruntime whatever the graph.

``kind`` must match the file (a BRDF file refuses ``"btf"``); ``uv_scale`` (BTF only) is
the patch repetition of the other BTF materials (:mod:`evaluators.render.sources.btf`).
"""

from __future__ import annotations

import types
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import AfterValidator, Field, PlainSerializer, WithJsonSchema, model_validator

from evaluators.render.sources.btf import UV_SCALE_DESCRIPTION, UvScale, uv_scale_pair
from evaluators.render.sources.common import inline_schema, register_material_source
from jobapi.errors import JobFailed
from jobapi.params import Ref, StrictModel

if TYPE_CHECKING:
    from jobapi.context import JobContext

FIELD = "material.external"


class GgxSampling(StrictModel):
    """Importance sampling of an ONNX BRDF: a GGX lobe mixed with the cosine lobe."""

    alpha: float = Field(gt=0.0, le=1.0, description="GGX roughness of the sampled lobe.")
    specular_weight: float = Field(
        ge=0.0, lt=1.0, description="Probability of sampling the GGX lobe (else cosine)."
    )


class ExternalSpec(StrictModel):
    """The value of an ``external`` material."""

    model: Ref = Field(
        description="The model file: 'sha256:<digest>' of an upload or 'job:<id>/<name>'; a "
        "matforge.mlp-brdf/1 or matforge.mlp-btf/1 JSON document, or an ONNX model."
    )
    kind: Literal["brdf", "btf"] = Field(
        description="'brdf' (evaluated at (wi, wo)) or 'btf' (at (uv, wi, wo)); must match "
        "the file."
    )
    uv_scale: UvScale | None = Field(default=None, description="BTF only: " + UV_SCALE_DESCRIPTION)
    sampling: GgxSampling | None = Field(
        default=None,
        description="ONNX BRDF only: {alpha, specular_weight}, a GGX lobe sampled with that "
        "probability beside the cosine lobe (MIS); default cosine only. An MLP file samples "
        "its own analytic part's lobe.",
    )
    runtime: Literal["auto", "onnxruntime"] | None = Field(
        default=None,
        description="ONNX only: 'auto' (default: the fused Dr.Jit kernel when the graph is an "
        "MLP, else onnxruntime) or 'onnxruntime' (always; to compare the two runtimes).",
    )

    @model_validator(mode="after")
    def _btf_only(self) -> ExternalSpec:
        if self.uv_scale is not None and self.kind != "btf":
            raise ValueError("uv_scale: applies to kind 'btf' only")
        if self.sampling is not None and self.kind != "brdf":
            raise ValueError("sampling: applies to kind 'brdf' only")
        return self


def _as_dict(spec: ExternalSpec) -> dict[str, Any]:
    return spec.model_dump(exclude_none=True)


#: The ``external`` value as validated at spec time: a plain dict (canonical in the spec).
ExternalValue = Annotated[
    ExternalSpec,
    AfterValidator(_as_dict),
    PlainSerializer(dict, return_type=dict[str, Any]),
    WithJsonSchema(inline_schema(ExternalSpec)),
]


def resolve_external(raw: dict[str, Any], ctx: JobContext, mi: types.ModuleType) -> Any:
    """The BSDF of an ``external`` material; :class:`JobFailed` naming the field, the
    reference and the problem when the file is malformed, of the other kind, or needs a
    runtime this build lacks."""
    from models.external import model_format
    from models.external.mlp import read_mlp

    value = ExternalSpec.model_validate(raw, strict=False)
    path = ctx.resolve(value.model)
    try:
        fmt = model_format(path)
    except ValueError as exc:
        raise JobFailed(f"{FIELD}.model: {value.model}: {exc}") from None
    if fmt == "onnx":
        from evaluators.render.bsdfs.external_onnx import external_onnx_plugin

        try:
            return external_onnx_plugin(path, dict(raw), ctx, mi)
        except ValueError as exc:  # a wrong signature or kind, named by the plugin
            raise JobFailed(f"{FIELD}.model: {exc}") from None
    if value.sampling is not None:
        raise JobFailed(
            f"{FIELD}.sampling: {value.model} is an MLP file, which samples its own analytic "
            "part's lobe; sampling applies to ONNX BRDFs"
        )
    if value.runtime is not None:
        raise JobFailed(
            f"{FIELD}.runtime: {value.model} is an MLP file, which runs in the fused Dr.Jit "
            "kernel; runtime applies to ONNX models"
        )
    try:
        material = read_mlp(path)
    except ValueError as exc:
        raise JobFailed(f"{FIELD}.model: {value.model}: {exc}") from None
    if material.kind != value.kind:
        raise JobFailed(
            f"{FIELD}.kind: {value.model} is a {material.kind} model, but kind is {value.kind!r}"
        )
    try:
        if value.kind == "brdf":
            from evaluators.render.bsdfs.external_mlp import (
                EXTERNAL_MLP_NAME,
                register_external_mlp_bsdf,
            )

            register_external_mlp_bsdf(mi)
            return {"type": EXTERNAL_MLP_NAME, "filename": str(path)}
        from evaluators.render.bsdfs.external_mlp_btf import (
            EXTERNAL_MLP_BTF_NAME,
            register_external_mlp_btf_bsdf,
        )

        register_external_mlp_btf_bsdf(mi)
    except RuntimeError as exc:
        raise JobFailed(f"{FIELD}: {exc}") from None
    su, sv = uv_scale_pair(raw)
    return {
        "type": EXTERNAL_MLP_BTF_NAME,
        "filename": str(path),
        "uv_scale_u": su,
        "uv_scale_v": sv,
    }


register_material_source(
    "external",
    resolve_external,
    value_type=ExternalValue,
    summary="A user's own model from a file: {'model': REF, 'kind': 'brdf' | 'btf', optional "
    "'uv_scale' (btf)}; a matforge.mlp-brdf/1 or matforge.mlp-btf/1 document, or an ONNX "
    "graph that is an MLP, renders through the fused Dr.Jit kernel, any other ONNX model "
    "through onnxruntime.",
)
