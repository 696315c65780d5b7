"""Parameters of ``evaluate.tss`` (:mod:`evaluators.tss.kind` documents the kind).

Units: metres, degrees, seconds. World frame: z up; the textured plane is the square
``[-0.5, 0.5]^2`` at z = 0 (side :data:`PLANE_SIDE`), its texture's u along +x, v along +y.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

from pydantic import BeforeValidator, Field, field_validator, model_validator

from evaluators.metrics.images import DEFAULT_PPD
from evaluators.render.sources.external import ExternalSpec
from jobapi.params import JobRef, StrictModel
from jobapi.presets import preset_note, resolve_preset

#: Side of the textured plane, metres.
PLANE_SIDE = 1.0


@dataclass(frozen=True)
class TssPreset:
    """Defaults of the tunable fields (``resolutions`` ``None``: texel-matched, see
    :meth:`TssParams.texture_resolutions`)."""

    frames: int
    image: tuple[int, int]
    resolutions: tuple[int, ...] | None


#: ``small``: a 128^2 view, 48 frames (two thirds of a second at 72 FPS), the radiance
#: texture texel-matched to the model: about a minute on 2 cores. ``paper``: Sec. 5.4 --
#: 90 frames (one second at the Quest 3's 90 FPS cap), the texture resolutions of Table 2
#: (800^2 ... 2000^2; 1200^2 is the paper's choice) and a 512^2 view.
PRESETS: dict[str, TssPreset] = {
    "small": TssPreset(frames=48, image=(128, 128), resolutions=None),
    "paper": TssPreset(frames=90, image=(512, 512), resolutions=(800, 1200, 1600, 2000)),
}

#: Three numbers; a JSON array fills it even in strict mode.
Vec3 = Annotated[
    tuple[float, float, float], BeforeValidator(lambda v: tuple(v) if isinstance(v, list) else v)
]
#: Two ints (width, height); a JSON array fills it even in strict mode.
Size = Annotated[tuple[int, int], BeforeValidator(lambda v: tuple(v) if isinstance(v, list) else v)]


class PointLight(StrictModel):
    """A point light: radiance at distance ``r`` is ``BTF * intensity / r^2`` (the BTF holds
    the foreshortening)."""

    position: Vec3 = Field(description="World position [x, y, z], metres; z > 0 (above).")
    intensity: float | Vec3 = Field(
        default=1.0, description="Radiant intensity, one number or [r, g, b], >= 0 (W/sr)."
    )

    @field_validator("position")
    @classmethod
    def _above(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        if not all(abs(c) <= 100.0 for c in v) or v[2] <= 0.0:
            raise ValueError("a light must lie above the plane (z > 0), within 100 m")
        return v

    @field_validator("intensity")
    @classmethod
    def _non_negative(cls, v: float | tuple[float, ...]) -> float | tuple[float, ...]:
        vals = (v,) if isinstance(v, float | int) else v
        if not all(0.0 <= float(c) <= 1e6 for c in vals):
            raise ValueError("intensity must lie in [0, 1e6]")
        return v

    def rgb(self) -> tuple[float, float, float]:
        """The intensity as ``(r, g, b)``."""
        i = self.intensity
        return (float(i), float(i), float(i)) if isinstance(i, float | int) else i


#: Three point lights as in the paper's Table 3: a key light whose highlight the default
#: camera sees near the plane's centre, and two dimmer ones from the sides.
DEFAULT_LIGHTS: tuple[PointLight, ...] = (
    PointLight(position=(0.0, 0.5, 0.6), intensity=1.0),
    PointLight(position=(-0.6, -0.2, 0.7), intensity=(0.5, 0.45, 0.4)),
    PointLight(position=(0.7, 0.1, 0.4), intensity=(0.3, 0.35, 0.45)),
)


class PathSpec(StrictModel):
    """The seeded head motion (:mod:`evaluators.tss.path`): a base pose looking at the
    plane's centre, plus head rotations about a pivot behind the eye and translations, each
    of the six a sum of low-frequency sinusoids with seeded phases."""

    elevation_deg: float = Field(
        default=45.0, ge=5.0, le=90.0,
        description="Elevation of the base eye above the plane, degrees (90: straight down).",
    )  # fmt: skip
    azimuth_deg: float = Field(
        default=-90.0, ge=-360.0, le=360.0,
        description="Azimuth of the base eye from +x towards +y, degrees (-90: on the -y "
        "side, the texture's v pointing up in the image).",
    )  # fmt: skip
    distance_m: float = Field(
        default=1.2, gt=0.05, le=100.0, description="Base eye's distance to the plane's centre."
    )
    fov_deg: float = Field(
        default=50.0, gt=1.0, lt=170.0, description="Horizontal field of view, degrees."
    )
    fps: float = Field(
        default=72.0, gt=1.0, le=1000.0,
        description="Frame rate the frames are spaced at (the paper: >= 72 FPS).",
    )  # fmt: skip
    rotation_deg: float = Field(
        default=10.0, ge=0.0, le=45.0,
        description="Amplitude of each head rotation (yaw, pitch, roll), degrees; 0 and "
        "translation_m 0: a static camera.",
    )  # fmt: skip
    translation_m: float = Field(
        default=0.05, ge=0.0, le=1.0,
        description="Amplitude of each head translation (right, up, forward), metres.",
    )  # fmt: skip
    pivot_m: float = Field(
        default=0.1, ge=0.0, le=1.0,
        description="Distance from the eye back to the head's rotation pivot (the neck), so "
        "that rotations move the eye as a head's do, metres.",
    )  # fmt: skip
    frequencies_hz: list[float] = Field(
        default=[0.5, 1.1, 2.3], min_length=1, max_length=8,
        description="Frequencies of the sinusoids summed per degree of freedom (weights "
        "1/k), Hz.",
    )  # fmt: skip

    @field_validator("frequencies_hz")
    @classmethod
    def _positive(cls, v: list[float]) -> list[float]:
        if not all(0.0 < f <= 100.0 for f in v):
            raise ValueError("frequencies must lie in (0, 100] Hz")
        return v


class ExternalBtfRef(StrictModel):
    """A user's BTF: ``{"external": {"model": REF, "kind": "btf"}}``
    (:mod:`evaluators.tss.external`)."""

    external: ExternalSpec = Field(description="The model, as the 'external' material.")

    @model_validator(mode="after")
    def _btf(self) -> ExternalBtfRef:
        if self.external.kind != "btf":
            raise ValueError("external.kind: evaluate.tss shades a BTF: kind must be 'btf'")
        return self


class TssParams(StrictModel):
    """Parameters of ``evaluate.tss``; a field left out takes the ``preset``'s value.

    ================  =================  ===========  ===========================================
    name              type               default      meaning
    ================  =================  ===========  ===========================================
    ``model``         job ref or         required     a succeeded train.btf job, or
                      ``{external}``                  a user's MLP or ONNX BTF
    ``frames``        int                preset       frames of the camera path
    ``resolutions``   list of int        preset       radiance-texture sides over the plane
    ``intervals``     list of int        0 1 2 4 6    N: reuse the texture N frames more
    ``image``         [w, h]             preset       the view, pixels
    ``lights``        list of lights     three        point lights {position, intensity}
    ``uv_scale``      int                2            repeats of the model's patch per side
    ``path``          PathSpec           see there    seeded head motion, camera
    ``texture_pass``  amortised | ...    amortised    2x2 coarse amortisation (_all: every R)
    ``flip_ppd``      float              67.0         FLIP's pixels per degree
    ``preset``        small | paper      small        defaults of the fields above
    ================  =================  ===========  ===========================================

    Example::

        {"kind": "evaluate.tss", "seed": 0, "params": {"model": "job:<train.btf id>",
         "intervals": [0, 1, 2, 4, 6], "resolutions": [32, 64]}}
    """

    model: JobRef | ExternalBtfRef = Field(
        description="'job:<id>' of a succeeded train.btf job (its model.json and "
        "textures.npz; in a batch file 'step:<name>'), or a user's own BTF, an MLP "
        "(matforge.mlp-btf/1) or an ONNX model: {'external': {'model': REF, 'kind': 'btf'}} "
        "(the 'external' material's value)."
    )
    preset: Literal["small", "paper"] = Field(
        default="small", description="Defaults of the unset fields: 'small' or 'paper'."
    )
    frames: int | None = Field(
        default=None, ge=1, le=10_000,
        description="Frames of the camera path" + preset_note(PRESETS, "frames"),
    )  # fmt: skip
    resolutions: list[int] | None = Field(
        default=None, min_length=1, max_length=8,
        description="Radiance-texture sides R (R x R texels over the whole plane, as the "
        "paper's Table 2 counts them); unset: small: the model's resolution times uv_scale "
        "(one radiance texel per neural texel), paper: 800, 1200, 1600, 2000.",
    )  # fmt: skip
    intervals: list[int] = Field(
        default=[0, 1, 2, 4, 6], min_length=1, max_length=16,
        description="Update intervals N (Table 2's rows): the radiance texture is shaded "
        "every N + 1 frames and reused in between.",
    )  # fmt: skip
    image: Size | None = Field(
        default=None,
        description="[width, height] of the view in pixels, 8..4096"
        + preset_note(PRESETS, "image"),
    )
    lights: list[PointLight] = Field(
        default=list(DEFAULT_LIGHTS), min_length=1, max_length=16,
        description="Point lights [{position: [x, y, z], intensity: I or [r, g, b]}]; "
        "default: three, as the paper's Table 3.",
    )  # fmt: skip
    uv_scale: int = Field(
        default=2,
        ge=1,
        le=64,
        description="Repeats of the model's texture patch along each side of the plane.",
    )
    path: PathSpec = Field(
        default=PathSpec(), description="Camera and seeded head motion (see PathSpec)."
    )
    texture_pass: Literal["amortised", "amortised_all", "per_texel"] = Field(
        default="amortised",
        description="'amortised': the paper's pass (FusedBtf.shade_texture: the student's "
        "coarse MLP once per 2x2 block, at the block centre's directions) where the texture "
        "is texel-matched (R = model resolution x uv_scale), else per texel; "
        "'amortised_all': the student's 2x2 amortisation at every even R (the coarse MLP "
        "once per 2x2 block of the radiance texture); 'per_texel': every texel evaluated "
        "alone (FusedBtf.eval at its centre, exact directions).",
    )
    flip_ppd: float = Field(
        default=DEFAULT_PPD, gt=0.0, le=1000.0,
        description="FLIP's observer pixels per degree (default: FLIP's 67).",
    )  # fmt: skip

    def effective(self) -> TssPreset:
        """The preset with the set fields in its place."""
        return resolve_preset(self, PRESETS)

    def texture_resolutions(self, model_resolution: int) -> list[int]:
        """The radiance-texture sides to simulate for a model of ``model_resolution``^2
        texels: the given list, else the preset's, else texel-matched."""
        res = self.effective().resolutions
        if res is None:
            return [model_resolution * self.uv_scale]
        return [int(r) for r in res]

    @field_validator("resolutions")
    @classmethod
    def _resolutions(cls, v: list[int] | None) -> list[int] | None:
        if v is None:
            return None
        if not all(2 <= r <= 8192 for r in v):
            raise ValueError("each resolution must lie in [2, 8192]")
        if len(set(v)) != len(v):
            raise ValueError("resolutions are listed more than once")
        return v

    @field_validator("intervals")
    @classmethod
    def _intervals(cls, v: list[int]) -> list[int]:
        if not all(0 <= n <= 120 for n in v):
            raise ValueError("each interval N must lie in [0, 120]")
        if len(set(v)) != len(v):
            raise ValueError("intervals are listed more than once")
        return sorted(v)

    @field_validator("image")
    @classmethod
    def _image(cls, v: tuple[int, int] | None) -> tuple[int, int] | None:
        if v is not None and not (8 <= v[0] <= 4096 and 8 <= v[1] <= 4096):
            raise ValueError(f"image must be [width, height] in 8..4096, got {list(v)}")
        return v
