"""Parameters of ``generate.glint``: the example, the NDF maps, the preview surface, presets."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

from pydantic import BeforeValidator, Field, model_validator

from jobapi.params import Ref, StrictModel
from jobapi.presets import preset_note, resolve_preset
from materials.glints.examples import SIZES, TYPES
from materials.glints.surface import Distribution, Transform

ExampleType = Literal[
    "scratches", "isotropic_noise", "anisotropic_noise", "brushed_metal", "leather", "structured"
]
assert set(ExampleType.__args__) == set(TYPES)  # type: ignore[attr-defined]


@dataclass(frozen=True)
class GlintPreset:
    """Defaults of the tunable fields."""

    ndf_resolution: int
    lobe_rate: int
    reference_resolution: int


#: ``small``: seconds on 2 cores. ``paper``: Sec. 7.3 -- NDF images of 128 x 128 (the
#: memory of Table 3: 5.32 MB for a 16 x 16 example is 85 tiles of 128^2 float32), lobes at
#: 4 x 4 seeds per texel, and the reference normal maps of Table 3 (4k x 4k).
PRESETS: dict[str, GlintPreset] = {
    "small": GlintPreset(ndf_resolution=32, lobe_rate=2, reference_resolution=512),
    "paper": GlintPreset(ndf_resolution=128, lobe_rate=4, reference_resolution=4096),
}


#: Two numbers; a JSON array fills it even in strict mode.
Pair = Annotated[
    tuple[float, float], BeforeValidator(lambda v: tuple(v) if isinstance(v, list) else v)
]


class ProceduralExample(StrictModel):
    """``{"procedural": TYPE, "size": n}``: a seeded procedural tiny example."""

    procedural: ExampleType = Field(description="Example type: " + ", ".join(TYPES) + ".")
    size: int = Field(default=16, description=f"Texels per side, one of {list(SIZES)}.")
    slope: float | None = Field(
        default=None,
        ge=0.0,
        le=2.0,
        description="RMS slope of the example's height field (default: the type's).",
    )

    @model_validator(mode="after")
    def _check_size(self) -> ProceduralExample:
        if self.size not in SIZES:
            raise ValueError(f"size must be one of {list(SIZES)}, got {self.size}")
        return self


class MapExample(StrictModel):
    """``{"normal_map": REF}``: a user's normal map (``.normal.exr`` / ``.normal.png``)."""

    normal_map: Ref = Field(
        description="An uploaded normal map: square, power-of-two side, unit normals z > 0 "
        "(EXR floats, or PNG storing (n + 1) / 2); import it as '<name>.normal.exr' or "
        "'<name>.normal.png' to have it checked on upload."
    )


class SurfaceSpec(StrictModel):
    """How the example covers the preview surface (Sec. 6.1-6.2)."""

    distribution: Literal["tiled", "stochastic"] = Field(
        default="tiled", description="'tiled' (one transform) or 'stochastic' (noise map)."
    )
    rotation_deg: float = Field(default=0.0, ge=-360, le=360, description="Tiled: rotation.")
    scale: Pair = Field(default=(1.0, 1.0), description="Tiled: (s_x, s_y).")
    shear: Pair = Field(default=(0.0, 0.0), description="Tiled: (h_x, h_y).")
    mirror: bool = Field(default=False, description="Tiled: mirror x.")
    offset: Pair = Field(default=(0.0, 0.0), description="Tilt offset of the normals (t_x, t_y).")
    scale_range: Pair = Field(
        default=(0.8, 1.25), description="Stochastic: range of the random isotropic scale."
    )
    spacing: float | None = Field(
        default=None,
        gt=0.0,
        le=4096.0,
        description="Stochastic: grid spacing of example centres, texels (default 0.75 n "
        "times the smallest scale, so examples overlap).",
    )

    def distribution_for(self, seed: int) -> Distribution:
        """The :class:`~materials.glints.surface.Distribution` this spec describes."""
        if self.distribution == "tiled":
            t = Transform.compose(
                scale=self.scale,
                shear=self.shear,
                rotation_deg=self.rotation_deg,
                mirror=self.mirror,
                offset=self.offset,
            )
            return Distribution(kind="tiled", transform=t)
        return Distribution(
            kind="stochastic",
            spacing=self.spacing or 0.0,
            scale_range=self.scale_range,
            seed=seed,
        )


class GlintGenParams(StrictModel):
    """Parameters of ``generate.glint``.

    ========================  ===================  =========  =================================
    name                      type                 default    meaning
    ========================  ===================  =========  =================================
    ``example``               procedural or map    required   the tiny example
    ``crop``                  int                  none       keep the example's top-left
                                                              crop x crop texels
    ``sigma_r``               float                0.02       intrinsic roughness
    ``ndf_resolution``        int                  preset     R, cells per side of each image
    ``lobe_rate``             int                  preset     seeds per texel per axis
    ``extent``                float                auto       e: images cover [-e, e]^2
    ``surface``               surface spec         tiled      the preview surface
    ``reference_resolution``  int                  preset     texels of the explicit reference
                                                              the memory is compared with
    ``preset``                small | paper        small      defaults of the fields above
    ========================  ===================  =========  =================================

    Example::

        {"kind": "generate.glint", "seed": 3, "params": {"example": {"procedural":
         "isotropic_noise", "size": 16}, "sigma_r": 0.02, "ndf_resolution": 32}}
    """

    example: ProceduralExample | MapExample = Field(
        description='The tiny example: {"procedural": TYPE, "size": n} or {"normal_map": REF}.'
    )
    crop: int | None = Field(
        default=None,
        description=f"Keep only the example's top-left crop x crop texels, one of {list(SIZES)} "
        "and at most its size: a smaller example of the same microstructure (Fig. 13's "
        "protocol; the crop tiles with seams where the full example has none).",
    )
    sigma_r: float = Field(
        default=0.02, gt=0.0, le=0.5, description="Intrinsic roughness sigma_r of the lobes."
    )
    preset: Literal["small", "paper"] = Field(
        default="small", description="Defaults of the unset fields: 'small' or 'paper'."
    )
    ndf_resolution: int | None = Field(
        default=None,
        ge=4,
        le=512,
        description="R: cells per side of each tile's NDF image"
        + preset_note(PRESETS, "ndf_resolution"),
    )
    lobe_rate: int | None = Field(
        default=None,
        ge=1,
        le=8,
        description="Lobe seeds per texel per axis" + preset_note(PRESETS, "lobe_rate"),
    )
    extent: float | None = Field(
        default=None,
        gt=0.0,
        le=1.0,
        description="e: NDF images cover projected normals in [-e, e]^2 (default: the lobes' "
        "reach with 3 standard deviations, rounded up to 0.05).",
    )
    surface: SurfaceSpec = Field(
        default_factory=SurfaceSpec, description="Transform and distribution of the preview."
    )
    reference_resolution: int | None = Field(
        default=None,
        ge=16,
        le=16384,
        description="Side in texels of the explicit normal map of the Yan et al. reference "
        "that stats.json compares memory with" + preset_note(PRESETS, "reference_resolution"),
    )

    @model_validator(mode="after")
    def _check_crop(self) -> GlintGenParams:
        if self.crop is not None:
            if self.crop not in SIZES:
                raise ValueError(f"crop must be one of {list(SIZES)}, got {self.crop}")
            ex = self.example
            if isinstance(ex, ProceduralExample) and self.crop > ex.size:
                raise ValueError(f"crop {self.crop} is larger than the example ({ex.size})")
        return self

    def effective(self) -> GlintPreset:
        """The preset with the set fields in its place."""
        return resolve_preset(self, PRESETS)
