"""Parameters of ``generate.btf``: the surface, the directions, the slices, presets."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import AfterValidator, BeforeValidator, Field, model_validator

from evaluators.render.sources.common import material_sources
from jobapi.params import StrictModel
from jobapi.presets import preset_note, resolve_preset
from materials.btf.directions import check_pairs, preset_pairs, to_vector
from materials.btf.surfaces import KINDS


@dataclass(frozen=True)
class BtfPreset:
    """Defaults of the tunable fields."""

    directions: str
    resolution: int
    spp: int
    max_depth: int
    shard_slices: int


#: ``small``: the 36 pairs of the ``small`` directions at 32^2 texels, seconds on 2 cores.
#: ``paper``: UBO2014's 151 x 151 pairs at 400^2 texels (Xu et al. Sec. 5), one shard per
#: light direction.
PRESETS: dict[str, BtfPreset] = {
    "small": BtfPreset(directions="small", resolution=32, spp=16, max_depth=4, shard_slices=12),
    "paper": BtfPreset(directions="ubo2014", resolution=400, spp=4, max_depth=4, shard_slices=151),
}


def _check_bsdf(value: dict[str, Any]) -> dict[str, Any]:
    # The render kind's check of Mitsuba plugin dicts: a 'type', no 'filename' anywhere.
    return dict(material_sources()["mitsuba"].adapter.validate_python(value, strict=True))


class FlatSurface(StrictModel):
    """``{"bsdf": {<Mitsuba BSDF dict>}}``: a flat plane of any Mitsuba 3 BSDF."""

    bsdf: Annotated[dict[str, Any], AfterValidator(_check_bsdf)] = Field(
        description='A Mitsuba 3 BSDF plugin dict, e.g. {"type": "roughconductor", "alpha": '
        "0.2}; no 'filename' keys. The plane's z axis is the BTF's normal, x its columns."
    )


class ProceduralSurface(StrictModel):
    """``{"procedural": NAME, ...}``: a seeded height field with albedo and roughness maps,
    rendered as a displaced mesh (:mod:`materials.btf.surfaces`)."""

    procedural: Literal["leather", "fabric", "wood", "stone"] = Field(
        description="Surface kind: " + ", ".join(KINDS) + "."
    )
    size: int | None = Field(
        default=None,
        ge=8,
        le=1024,
        description="Texels per side of the maps and vertices per side of one mesh tile "
        "(default: the slice resolution).",
    )
    relief: float = Field(
        default=0.02,
        ge=0.0,
        le=0.2,
        description="Standard deviation of the height, in units of the patch's side.",
    )


assert set(ProceduralSurface.model_fields["procedural"].annotation.__args__) == set(KINDS)  # type: ignore[union-attr]


class DirectionPreset(StrictModel):
    """``{"preset": "small" | "ubo2014"}``: every light x view pair of a direction set."""

    preset: Literal["small", "ubo2014"] = Field(
        description="'small': 6 directions, 36 pairs; 'ubo2014': UBO2014's dome, 151 "
        "directions on 10 rings up to 75 degrees, 22801 pairs."
    )


#: ``[theta_i, phi_i, theta_o, phi_o]`` in degrees; a JSON array fills it in strict mode.
AnglePair = Annotated[
    tuple[float, float, float, float],
    BeforeValidator(lambda v: tuple(v) if isinstance(v, list) else v),
]


def _check_angle_list(value: list[tuple[float, float, float, float]]) -> list[Any]:
    if not value:
        raise ValueError("the direction list is empty")
    arr = np.asarray(value, dtype=np.float64)
    wi, wo = to_vector(arr[:, 0], arr[:, 1]), to_vector(arr[:, 2], arr[:, 3])
    for k, (ti, _, to, _) in enumerate(value):
        if not (0.0 <= ti <= 85.0 and 0.0 <= to <= 85.0):
            raise ValueError(f"pair {k}: theta_i and theta_o must lie in [0, 85] degrees")
    check_pairs(wi, wo)
    return value


#: Largest number of slices one job may render.
MAX_SLICES = 151 * 151


class BtfGenParams(StrictModel):
    """Parameters of ``generate.btf``.

    ================  =========================  ========  =====================================
    name              type                       default   meaning
    ================  =========================  ========  =====================================
    ``surface``       bsdf or procedural         required  the material
    ``directions``    preset or list             preset    light x view pairs
    ``resolution``    int                        preset    texels per side of a slice
    ``spp``           int                        preset    rays per texel
    ``max_depth``     int                        preset    Mitsuba path depth (2: direct only)
    ``shard_slices``  int                        preset    slices per ``slices-XXXX.npz``
    ``dtype``         float32 | float16          float32   of the stored slices
    ``jitter``        stratified | independent   strat.    ray positions within a texel
    ``preset``        small | paper              small     defaults of the fields above
    ================  =========================  ========  =====================================

    Example::

        {"kind": "generate.btf", "seed": 1, "params": {"surface": {"bsdf": {"type":
         "diffuse", "reflectance": {"type": "rgb", "value": [0.2, 0.5, 0.8]}}},
         "directions": {"preset": "small"}, "resolution": 32, "spp": 16}}
    """

    surface: FlatSurface | ProceduralSurface = Field(
        description='The material: {"bsdf": {<Mitsuba BSDF dict>}} (a flat plane) or '
        '{"procedural": "leather" | "fabric" | "wood" | "stone", "size": n, "relief": r}.'
    )
    directions: (
        DirectionPreset | Annotated[list[AnglePair], AfterValidator(_check_angle_list)] | None
    ) = Field(
        default=None,
        description='{"preset": "small" | "ubo2014"}, or a list of [theta_i, phi_i, theta_o, '
        "phi_o] in degrees (theta at most 85, phi from +x towards +y)"
        + preset_note(PRESETS, "directions"),
    )
    preset: Literal["small", "paper"] = Field(
        default="small", description="Defaults of the unset fields: 'small' or 'paper'."
    )
    resolution: int | None = Field(
        default=None, ge=4, le=1024,
        description="Texels per side of a slice" + preset_note(PRESETS, "resolution"),
    )  # fmt: skip
    spp: int | None = Field(
        default=None, ge=2, le=4096,
        description="Rays per texel (at least 2, for the error estimate)"
        + preset_note(PRESETS, "spp"),
    )  # fmt: skip
    max_depth: int | None = Field(
        default=None, ge=2, le=64,
        description="Mitsuba's path depth: 2 is direct light only, each step above adds a "
        "bounce of interreflection" + preset_note(PRESETS, "max_depth"),
    )  # fmt: skip
    shard_slices: int | None = Field(
        default=None, ge=1, le=MAX_SLICES,
        description="Slices per shard file" + preset_note(PRESETS, "shard_slices"),
    )  # fmt: skip
    dtype: Literal["float32", "float16"] = Field(
        default="float32",
        description="Stored type of the slices ('float16' halves the paper scale's ~44 GB).",
    )
    jitter: Literal["stratified", "independent"] = Field(
        default="stratified",
        description="Ray positions within a texel: 'stratified' (a Latin hypercube; the "
        "stated error is then an upper bound) or 'independent' uniform.",
    )

    def effective(self) -> BtfPreset:
        """The preset with the set fields in its place (``directions`` stays the preset's
        name: :meth:`pairs` applies the field)."""
        return resolve_preset(self, PRESETS, keep=("directions",))

    def pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """``(wi, wo)`` unit vectors ``(N, 3)``, float64, in the order of the slices."""
        d = self.directions
        if d is None:
            return preset_pairs(PRESETS[self.preset].directions)
        if isinstance(d, DirectionPreset):
            return preset_pairs(d.preset)
        arr = np.asarray(d, dtype=np.float64)
        return to_vector(arr[:, 0], arr[:, 1]), to_vector(arr[:, 2], arr[:, 3])

    @model_validator(mode="after")
    def _check_size(self) -> BtfGenParams:
        n = len(self.pairs()[0])
        if n > MAX_SLICES:
            raise ValueError(f"at most {MAX_SLICES} slices per job, got {n}")
        return self
