"""The ``fabric`` material source: ``{"fabric": {...}}`` renders the aggregated woven fabric.

Chen, Wang & Wang 2024, Sec. 6: the reference renders shade each pixel with the aggregated
BSDF ``f_P`` of its footprint, estimated by Monte Carlo: at 256 spp the paper's ground
truth, at 1 spp its baseline. The value is one material: the fields of
:class:`materials.fabric.params.FabricParams` (the same names and forms as a material's
record in ``generate.fabric``'s ``materials.json``, so a record can be pasted in), all
optional, plus two render settings::

    {"fabric": {"pattern": "twill_3x3", "psi_deg": 25, "u_max_deg": [20, 30],
                "alpha": 0.3, "beta": 0.8, "w": 0.7,
                "kd_warp": [0.6, 0.2, 0.2], "kd_weft": 0.5, "ks_warp": 0.4, "ks_weft": 0.4,
                "gap": 0.2, "t_rho": 2.0, "tiles_per_uv": 16, "visibility": true}}

=================  =========================  ==========  ===================================
key                type                       default     meaning
=================  =========================  ==========  ===================================
``pattern``        built-in pattern name      twill_3x3   ``materials.fabric.patterns``
``psi_deg``        number or [warp, weft]     0           ply twist, degrees, [-80, 80]
``u_max_deg``      number or [warp, weft]     20          yarn inclination, degrees, [0, 75]
``alpha``          number or [warp, weft]     0.3         fibre roughness, [0.02, 1]
``beta``           number or [warp, weft]     1.0         height scaling, [0, 2]
``w``              number                     0.7         Lambertian blend, [0, 1]
``kd_warp`` ...    number or [r, g, b]        0.5         albedos ``kd_warp``, ``kd_weft``,
                                                          ``ks_warp``, ``ks_weft``, [0, 1]
``gap``            number                     0.2         gap fraction, [0, 0.9]
``t_rho``          number                     2.0         SpongeCake optical thickness
``tiles_per_uv``   number                     16          pattern tiles across uv [0, 1]
``visibility``     bool                       true        yarn visibility V (Eq. 3-4)
=================  =========================  ==========  ===================================

Validation happens at spec time, strictly (unknown keys, wrong types), and reuses
``FabricParams``' own checks, so the ranges are those of ``PARAM_RANGES``; an unknown
pattern names the allowed ones. Inside the job the value becomes the ``fabric_aggregate``
BSDF of :mod:`evaluators.render.bsdfs.fabric_aggregate` (one unbiased footprint sample per
evaluation), and
:func:`evaluators.render.integrators.fabric_path.integrator_for` swaps the scene's integrator for
``fabric_path``, which supplies the pixel footprints (ray differentials at pixel centres).

This module registers the source when imported; :mod:`evaluators.render.kind` imports it.
"""

from __future__ import annotations

import types
from collections.abc import Callable
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    Field,
    PlainSerializer,
    PlainValidator,
    WithJsonSchema,
    field_validator,
    model_validator,
)

from evaluators.render.bsdfs.fabric_aggregate import fabric_bsdf
from evaluators.render.sources.common import register_material_source
from jobapi.errors import JobFailed
from jobapi.params import StrictModel
from materials.fabric.params import FabricParams
from materials.fabric.patterns import PATTERNS

if TYPE_CHECKING:
    from jobapi.context import JobContext

Number = Annotated[float, Field(allow_inf_nan=False)]


def _numbers(n: int, what: str) -> Callable[[Any], float | list[float]]:
    """A validator: a number, or a list of ``n`` numbers (``what`` names them in errors);
    kept as given."""

    def check(value: Any) -> float | list[float]:
        def number(x: Any) -> bool:
            return isinstance(x, int | float) and not isinstance(x, bool)

        if number(value):
            return float(value)
        if isinstance(value, list | tuple) and len(value) == n and all(map(number, value)):
            return [float(x) for x in value]
        raise ValueError(f"must be a number or a list of {n} numbers {what}, got {value!r}")

    return check


def _schema(n: int) -> dict[str, Any]:
    return {
        "anyOf": [
            {"type": "number"},
            {"type": "array", "items": {"type": "number"}, "minItems": n, "maxItems": n},
        ]
    }


Pair = Annotated[
    float | list[float], PlainValidator(_numbers(2, "[warp, weft]")), WithJsonSchema(_schema(2))
]
Rgb = Annotated[
    float | list[float], PlainValidator(_numbers(3, "[r, g, b]")), WithJsonSchema(_schema(3))
]


class FabricSpec(StrictModel):
    """One woven-fabric material for a render (see the module docstring)."""

    pattern: str = Field(default="twill_3x3", description="Built-in weave pattern name.")
    psi_deg: Pair = Field(default=0.0, description="Ply twist psi, degrees, [warp, weft].")
    u_max_deg: Pair = Field(default=20.0, description="Yarn inclination u, degrees.")
    alpha: Pair = Field(default=0.3, description="Fibre microflake roughness, [0.02, 1].")
    beta: Pair = Field(default=1.0, description="Height-field scaling, [0, 2].")
    w: Number = Field(default=0.7, description="Lambertian blend weight, [0, 1].")
    kd_warp: Rgb = Field(default=0.5, description="Diffuse albedo of warp yarns (RGB).")
    kd_weft: Rgb = Field(default=0.5, description="Diffuse albedo of weft yarns (RGB).")
    ks_warp: Rgb = Field(default=0.5, description="Specular albedo of warp yarns (RGB).")
    ks_weft: Rgb = Field(default=0.5, description="Specular albedo of weft yarns (RGB).")
    gap: Number = Field(default=0.2, description="Gap fraction beside each yarn, [0, 0.9].")
    t_rho: Number = Field(default=2.0, description="SpongeCake optical thickness T rho.")
    yarn_profile: Literal["smooth", "jin"] = Field(
        default="smooth",
        description="Yarn height profile: 'smooth' (default; tapers each float's height over "
        "its outer half, a different yarn from Jin et al. 2022's) or 'jin' (Jin's slopes on "
        "90 % of each float, closed to zero in a thin band at its boundary).",
    )
    tiles_per_uv: Number = Field(
        default=16.0, gt=0.0, le=4096.0, description="Pattern tiles across the uv range [0, 1]."
    )
    visibility: bool = Field(default=True, description="Yarn-to-yarn visibility V (Eq. 3-4).")

    @field_validator("pattern")
    @classmethod
    def _known_pattern(cls, value: str) -> str:
        if value not in PATTERNS:
            raise ValueError(f"unknown pattern {value!r}; allowed: {', '.join(sorted(PATTERNS))}")
        return value

    @model_validator(mode="after")
    def _check_params(self) -> FabricSpec:
        self.to_params()  # FabricParams' own range checks, messages naming the field
        return self

    def to_params(self) -> FabricParams:
        """The :class:`FabricParams` of this material (raises ``ValueError`` when invalid)."""
        fields = self.model_dump(exclude={"tiles_per_uv", "visibility"})
        return FabricParams(**fields)


def _as_dict(spec: FabricSpec) -> dict[str, Any]:
    # The validated params stay plain JSON (canonical spec hashing, render.json);
    # yarn_profile only when not the default, so older specs keep their bytes.
    doc = spec.model_dump(mode="json")
    if doc["yarn_profile"] == "smooth":
        del doc["yarn_profile"]
    return doc


#: The pydantic type of the ``fabric`` value: validated as :class:`FabricSpec`, kept as JSON.
#: (Its JSON schema is inlined: the material schema embeds sibling properties without $defs.)
FabricValue = Annotated[
    FabricSpec,
    AfterValidator(_as_dict),
    PlainSerializer(dict, return_type=dict[str, Any]),
    WithJsonSchema(FabricSpec.model_json_schema()),
]


def resolve_fabric(value: dict[str, Any], ctx: JobContext, mi: types.ModuleType) -> Any:
    """Resolve ``{"fabric": value}`` to an instantiated ``fabric_aggregate`` BSDF."""
    spec = FabricSpec.model_validate(value, strict=False)
    try:
        return fabric_bsdf(
            mi, spec.to_params(), tiles_per_uv=spec.tiles_per_uv, visibility=spec.visibility
        )
    except RuntimeError as exc:
        raise JobFailed(f"material.fabric: {exc}") from None


register_material_source(
    "fabric",
    resolve_fabric,
    value_type=FabricValue,
    summary="A woven fabric (Chen et al. 2024): FabricParams fields (pattern, psi_deg, "
    "u_max_deg, alpha, beta, w, kd_*/ks_* albedos, gap, t_rho) plus tiles_per_uv and "
    "visibility; rendered with the Monte Carlo aggregated BSDF of each pixel footprint.",
)
