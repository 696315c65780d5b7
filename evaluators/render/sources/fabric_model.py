"""``{"model": REF, "fabric": {...}}``: a ``train.fabric`` network renders a woven fabric.

Chen, Wang & Wang 2024, Sec. 4.3: the encoder runs once per material, and the decoder
replaces the Monte Carlo aggregate per shading query. The ``fabric_model`` BSDF here
derives from the same footprint base as the Monte Carlo ``fabric_aggregate``
(:mod:`evaluators.render.bsdfs.fabric_footprint`: uv partials, sides, cosine sampling, Eq. 8), and
its ``estimate`` is the fused decoder of :mod:`models.fabric.fused`
(``decoder_drjit``) traced into the render kernel: deterministic per footprint, so one
sample per pixel is already noise-free in the footprint (the light integral still needs
samples).

Footprint: the network takes an isotropic square ``(cx, cy, size)``; the pixel's uv
parallelogram (``si.duv_dx``, ``si.duv_dy``, in tile units) becomes the square of the same
area around the hit point's uv, ``size = sqrt(|det|)``; the decoder clamps sizes beyond 5
tiles. Secondary vertices get the one-tile fallback footprint, as in the Monte Carlo BSDF.

The latent (in order):

1. a ``model.pt`` reference carries the encoder: the material's normal and orientation maps
   are rasterised from the ``fabric`` fields (``models.fabric.fused.material_maps``) at the
   side of the training data's maps (recorded in the ``model.pt``; 256 for older models), so
   exactly as training made them, and encoded once;
2. a ``model.json`` carries no encoder but the training materials' latents: the one whose
   parameters (pattern and yarn geometry, roughness, ``w``; the albedos only enter Eq. 8)
   equal the ``fabric`` fields is used;
3. otherwise the job fails and says to use the job's ``model.pt``.

The albedos, ``tiles_per_uv`` come from the ``fabric`` value; ``visibility`` is ignored
(the network learned the aggregate with visibility).

Latent interpolation (Sec. 6.3, Fig. 8): an optional ``interpolate`` sibling renders the
latent ``(1 - t) z(A) + t z(B)`` between the ``fabric`` material A and a second material B,
both encoded as above (steps 1-3; with a ``model.json`` both must be training materials)::

    {"model": "job:<id>/model.pt", "fabric": {"pattern": "twill_3x3", "beta": 0.2},
     "interpolate": {"fabric": {"pattern": "twill_3x3", "beta": 0.8}, "t": 0.5}}

``t`` lies in [0, 1]; B must have A's ``pattern`` and ``tiles_per_uv`` (the latent space is
continuous in the parameters, not across patterns). Every numeric ``FabricParams`` field of
the BSDF (albedos for Eq. 8, ``gap`` for the tile geometry) is interpolated with the same
weights, so ``t = 0`` renders exactly A and ``t = 1`` exactly B (bit for bit: ``1 x + 0 y``
is ``x``); in Fig. 8 A and B differ only in roughness or height scaling, which only the
latent carries, so the interpolated latent is the only thing compared against the directly
encoded one.
"""

from __future__ import annotations

import json
import types
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import numpy as np
from pydantic import Field, WithJsonSchema

from evaluators.render.bsdfs.fabric_model import (
    FABRIC_MODEL_BSDF_NAME,
    register_fabric_model_bsdf,
)
from evaluators.render.sources.fabric import FabricSpec, FabricValue
from jobapi.errors import JobFailed
from jobapi.params import StrictModel
from materials.fabric.params import FabricParams, params_json

if TYPE_CHECKING:
    from jobapi.context import JobContext
    from models.fabric.fused import FabricModel

#: Map side handed to the encoder for models that do not record their training data's
#: (it resamples to its own); a model that does gets its maps rasterised at that side, as
#: the training maps were (``FabricModel.data_map_resolution``).
_MAP_RESOLUTION = 256
#: Parameters that must match for a training latent to stand for the material.
_GEOMETRY = ("psi_deg", "u_max_deg", "alpha", "beta", "w", "gap", "t_rho")


class FabricInterpolation(StrictModel):
    """The ``interpolate`` sibling: render the latent ``(1 - t) z(fabric) + t z(B)``."""

    fabric: FabricValue = Field(
        description="Material B (the 'fabric' material's fields): same pattern and "
        "tiles_per_uv as the 'fabric' sibling."
    )
    t: float = Field(
        ge=0.0,
        le=1.0,
        allow_inf_nan=False,
        description="Weight of B, [0, 1]: 0 renders the 'fabric' material, 1 renders B.",
    )


#: The ``interpolate`` sibling's type, its JSON schema inlined (the material schema embeds
#: sibling properties without ``$defs``).
InterpolationValue = Annotated[
    FabricInterpolation, WithJsonSchema(FabricInterpolation.model_json_schema())
]


def check_interpolation(a: Mapping[str, Any], b: Mapping[str, Any]) -> None:
    """Spec-time check of B (``b``) against A (``a``), both validated ``fabric`` values.

    Raises ``ValueError`` naming the field when the patterns or ``tiles_per_uv`` differ.
    """
    for key in ("pattern", "tiles_per_uv"):
        if a.get(key) != b.get(key):
            raise ValueError(
                f"interpolate.fabric.{key} must equal fabric.{key} ({a.get(key)!r}), got "
                f"{b.get(key)!r}: latents interpolate between parameters of one pattern"
            )


def lerp_params(a: FabricParams, b: FabricParams, t: float) -> FabricParams:
    """Every numeric field ``(1 - t) a + t b`` (exactly ``a`` at 0 and ``b`` at 1)."""
    if a.pattern.name != b.pattern.name:
        raise ValueError(f"patterns differ: {a.pattern.name} and {b.pattern.name}")
    ra, rb = json.loads(params_json(a)), json.loads(params_json(b))

    def mix(x: Any, y: Any) -> Any:
        if isinstance(x, list):
            return [mix(u, v) for u, v in zip(x, y, strict=True)]
        return (1.0 - t) * float(x) + t * float(y)

    if a.yarn_profile != b.yarn_profile:
        raise ValueError(f"yarn profiles differ: {a.yarn_profile} and {b.yarn_profile}")
    keep = ("pattern", "yarn_profile")
    return FabricParams(**{k: v if k in keep else mix(v, rb[k]) for k, v in ra.items()})


def lerp_latent(za: np.ndarray, zb: np.ndarray, t: float) -> np.ndarray:
    """``(1 - t) za + t zb`` as float32 (exactly ``za`` at 0 and ``zb`` at 1)."""
    za64, zb64 = np.asarray(za, np.float64), np.asarray(zb, np.float64)
    return ((1.0 - t) * za64 + t * zb64).astype(np.float32)


def _same_material(record: Mapping[str, Any], pattern: str | None, params: FabricParams) -> bool:
    """Whether a training record describes ``params`` (albedos aside)."""
    if pattern is not None and pattern != params.pattern.name:
        return False
    try:
        known = {k: record[k] for k in _GEOMETRY if k in record}
        theirs = params.replace(pattern=record.get("pattern", params.pattern), **known)
    except (ValueError, KeyError):
        return False
    if theirs.pattern.name != params.pattern.name:
        return False
    if record.get("yarn_profile", "smooth") != params.yarn_profile:
        return False
    return all(
        np.allclose(np.asarray(getattr(theirs, k)), np.asarray(getattr(params, k)), atol=1e-6)
        for k in _GEOMETRY
    )


def latent_for(model: FabricModel, params: FabricParams, ref: str) -> np.ndarray:
    """The ``(latent_dim,)`` float32 latent of ``params`` (module docstring, steps 1-3)."""
    from models.fabric.fused import encode_material, material_maps

    if model.encoder is not None:
        side = model.data_map_resolution or _MAP_RESOLUTION
        normal, orientation = material_maps(params, side)
        return encode_material(model, params, normal, orientation)
    for name, record in model.params.items():
        if _same_material(record, record.get("pattern"), params):
            return model.latents[name]
    known = ", ".join(sorted(model.latents)) or "none"
    raise JobFailed(
        f"material.model: {ref}: this model.json carries no encoder and none of its training "
        f"materials ({known}) has these fabric parameters; use the job's model.pt to encode "
        f"a new material"
    )


def resolve_model_fabric(value: Mapping[str, Any], ctx: JobContext, mi: types.ModuleType) -> Any:
    """Resolve ``{"model": REF, "fabric": {...}}`` to an instantiated ``fabric_model`` BSDF."""
    from models.fabric.fused import load_fabric_model

    ref = value["model"]
    spec = FabricSpec.model_validate(value["fabric"], strict=False)
    params = spec.to_params()
    path = ctx.resolve(ref)
    try:
        model = load_fabric_model(Path(path).read_bytes())
    except ValueError as exc:
        raise JobFailed(f"material.model: {ref}: {exc}") from None
    latent = latent_for(model, params, ref)
    if value.get("interpolate") is not None:
        # Sec. 6.3: the latent (and with it the shading fields) between A and B.
        interp = FabricInterpolation.model_validate(value["interpolate"], strict=False)
        other = FabricSpec.model_validate(interp.fabric, strict=False)
        check_interpolation(spec.model_dump(mode="json"), other.model_dump(mode="json"))
        b = other.to_params()
        latent = lerp_latent(latent, latent_for(model, b, ref), interp.t)
        params = lerp_params(params, b, interp.t)
    try:
        register_fabric_model_bsdf(mi)
    except RuntimeError as exc:
        raise JobFailed(f"material.model: {exc}") from None
    return mi.load_dict(
        {
            "type": FABRIC_MODEL_BSDF_NAME,
            "filename": str(path),
            "latent": mi.TensorXf(np.asarray(latent, np.float32)),
            "params": params_json(params),
            "tiles_per_uv": float(spec.tiles_per_uv),
        }
    )


__all__ = [
    "FabricInterpolation",
    "InterpolationValue",
    "check_interpolation",
    "lerp_latent",
    "lerp_params",
    "latent_for",
    "resolve_model_fabric",
]
