"""Families of synthetic materials and the named presets of ``generate.merl`` collections.

A *family* is a declared parameter distribution plus a sampler that turns one draw into a
material source of known ground truth: a Mitsuba 3 BSDF plugin dict (``{"mitsuba": ...}``)
or an analytic model (``{"analytic": ...}``, :data:`materials.analytic.ANALYTIC_MODELS`).
Each family's distribution is a strict pydantic model whose defaults *are* the documented
distribution, so a job may override any of them (``collection.distributions``) and
``materials.json`` records the one used.

==============  ===========================================================  =============
family          source                                                       look
==============  ===========================================================  =============
``metal``       Mitsuba ``roughconductor``, a named conductor, GGX/Beckmann  metals
``plastic``     Mitsuba ``roughplastic``: rough dielectric over a diffuse    plastics,
                base                                                         phenolics
``paint``       Mitsuba ``principled`` with clearcoat (some metallic)        car/lab paint
``sheen``       Mitsuba ``principled``, rough, with sheen (Disney's cloth    fabrics
                lobe; Mitsuba 3 has no dedicated velvet BSDF)
``blend``       Mitsuba ``blendbsdf`` of two lobes: conductor + diffuse, or  two-layer
                one conductor at two roughnesses                             finishes
``iridescent``  analytic ``thin_film_ggx`` (Belcour & Barla 2017)            films, oils
==============  ===========================================================  =============

Every Mitsuba family draws parameters for which the plugin is isotropic (``anisotropic = 0``
in ``principled``, isotropic ``alpha`` elsewhere) and evaluates deterministically in
``llvm_ad_rgb`` (no textures, no random sampling in ``eval``);
``tests/unit/generators/test_merl_collections.py`` checks both with the tabulation's
anisotropy probe.

Colours are drawn in HSV (hue, saturation, value uniform in their ranges) and converted to
linear RGB reflectance with :func:`colorsys.hsv_to_rgb`, so ``value`` is the largest
channel. "log-uniform" means ``exp(U(log lo, log hi))``. Drawn floats are rounded to four
significant digits (colours to four decimals), so the recorded source dicts reproduce the
tables exactly.

Seeding: :func:`draw_collection` draws each family from its own generator
(``rng_for(family)``), materials in order; the first ``k`` materials of a family are the
same whatever the count and whatever the other families.

:data:`PRESETS`: ``small`` (12 materials, every family; tests and the demo) and
``merl100`` (100 materials, a synthetic counterpart of the MERL database of Matusik et al.
2003, which holds 100 isotropic materials, many of them metals, plastics/phenolics, paints
and fabrics).
"""

from __future__ import annotations

import colorsys
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, Literal, NamedTuple, get_args

import numpy as np
from pydantic import AfterValidator, Field
from pydantic_core import PydanticCustomError

from jobapi.params import StrictModel
from materials.microfacet import NAMED_CONDUCTORS

FamilyName = Literal["metal", "plastic", "paint", "sheen", "blend", "iridescent"]
PresetName = Literal["small", "merl100"]

#: Names usable in material file names (``<name>.binary``): no dots, no slashes.
SAFE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,79}$")

# -- distribution building blocks ----------------------------------------------------------


def _ordered(value: tuple[float, float]) -> tuple[float, float]:
    if value[0] > value[1]:
        # A custom error type keeps pydantic from prefixing "Value error, " to the message.
        raise PydanticCustomError("range", f"a range [lo, hi] needs lo <= hi, got {list(value)}")
    return value


def _known_conductor(name: str) -> str:
    if name not in NAMED_CONDUCTORS or name == "none":
        known = ", ".join(sorted(c for c in NAMED_CONDUCTORS if c != "none"))
        raise PydanticCustomError(
            "conductor", f"unknown conductor {name!r}; Mitsuba's named conductors: {known}"
        )
    return name


Unit = Annotated[float, Field(ge=0.0, le=1.0)]
UnitRange = Annotated[tuple[Unit, Unit], AfterValidator(_ordered), Field(strict=False)]
Alpha = Annotated[float, Field(ge=0.005, le=1.0)]
AlphaRange = Annotated[tuple[Alpha, Alpha], AfterValidator(_ordered), Field(strict=False)]
Ior = Annotated[float, Field(ge=1.05, le=3.0)]
IorRange = Annotated[tuple[Ior, Ior], AfterValidator(_ordered), Field(strict=False)]
Thickness = Annotated[float, Field(ge=0.0, le=5000.0)]
ThicknessRange = Annotated[
    tuple[Thickness, Thickness], AfterValidator(_ordered), Field(strict=False)
]
Conductor = Annotated[str, AfterValidator(_known_conductor)]
Conductors = Annotated[list[Conductor], Field(min_length=1, max_length=64)]
Microfacet = Literal["ggx", "beckmann"]
Microfacets = Annotated[list[Microfacet], Field(min_length=1, max_length=2)]

#: Mitsuba's named conductors, without ``"none"`` (a perfect mirror, not a material).
ALL_CONDUCTORS: tuple[str, ...] = tuple(c for c in NAMED_CONDUCTORS if c != "none")
#: Common base metals of films and blends.
COMMON_METALS = ("Al", "Ag", "Au", "Cu", "Cr", "Ni_palik", "Rh", "W")
BlendPair = Literal["conductor_diffuse", "two_roughness"]
BLEND_PAIRS: tuple[str, ...] = get_args(BlendPair)


def _span(lo: float, hi: float, text: str) -> Any:
    """A ``[lo, hi]`` range field with default ``(lo, hi)``."""
    return Field(default=(lo, hi), description=text)


def _options(values: tuple[str, ...], text: str) -> Any:
    """A list-of-choices field (drawn uniformly) with default ``values``."""
    return Field(default_factory=lambda: list(values), description=text)


_HUE = "Hue range, fractions of the colour circle, uniform."
_SAT = "HSV saturation range, [0, 1], uniform."
_VAL = "HSV value range (the largest linear RGB channel), [0, 1], uniform."
_LOG = "log-uniform"

# -- the families' distributions -----------------------------------------------------------


class MetalDistribution(StrictModel):
    """``metal``: Mitsuba ``roughconductor`` with a named conductor's spectral IOR."""

    conductors: Conductors = _options(
        ALL_CONDUCTORS, "Mitsuba named conductors, uniformly (default: all but 'none')."
    )
    alpha: AlphaRange = _span(0.02, 0.6, f"Microfacet roughness alpha, {_LOG}.")
    distributions: Microfacets = _options(("ggx", "beckmann"), "Microfacet NDFs, uniformly.")


class PlasticDistribution(StrictModel):
    """``plastic``: Mitsuba ``roughplastic``, a rough dielectric coat over a diffuse base."""

    alpha: AlphaRange = _span(0.02, 0.5, f"Coat roughness alpha, {_LOG}.")
    ior: IorRange = _span(1.4, 1.6, "Coat index of refraction (over air), uniform.")
    distributions: Microfacets = _options(("ggx", "beckmann"), "Microfacet NDFs, uniformly.")
    hue: UnitRange = _span(0.0, 1.0, _HUE)
    saturation: UnitRange = _span(0.0, 0.9, _SAT)
    value: UnitRange = _span(0.03, 0.85, _VAL)


class PaintDistribution(StrictModel):
    """``paint``: Mitsuba ``principled`` with a clearcoat; a share of metallic paints."""

    hue: UnitRange = _span(0.0, 1.0, _HUE)
    saturation: UnitRange = _span(0.2, 1.0, _SAT)
    value: UnitRange = _span(0.02, 0.8, _VAL)
    roughness: UnitRange = _span(0.3, 0.8, "Principled roughness (alpha = r^2), uniform.")
    metallic_probability: Unit = Field(
        default=0.3, description="Probability that a paint is metallic (else metallic = 0)."
    )
    metallic: UnitRange = _span(0.3, 0.9, "Principled metallic of metallic paints, uniform.")
    specular: UnitRange = _span(0.3, 0.7, "Principled specular (base Fresnel), uniform.")
    clearcoat: UnitRange = _span(0.3, 1.0, "Principled clearcoat weight, uniform.")
    clearcoat_gloss: UnitRange = _span(
        0.5, 0.95, "Principled clearcoat gloss (coat alpha 0.1 lerp 0.001), uniform."
    )


class SheenDistribution(StrictModel):
    """``sheen``: cloth-like Mitsuba ``principled``, rough, with Disney's sheen lobe."""

    hue: UnitRange = _span(0.0, 1.0, _HUE)
    saturation: UnitRange = _span(0.1, 0.9, _SAT)
    value: UnitRange = _span(0.02, 0.6, _VAL)
    roughness: UnitRange = _span(0.7, 1.0, "Principled roughness, uniform (high: fabric).")
    sheen: UnitRange = _span(0.5, 1.0, "Principled sheen weight, uniform.")
    sheen_tint: UnitRange = _span(0.0, 1.0, "Principled sheen tint to the base colour, uniform.")
    specular: UnitRange = _span(0.1, 0.4, "Principled specular (base Fresnel), uniform.")


class BlendDistribution(StrictModel):
    """``blend``: Mitsuba ``blendbsdf`` of two lobes, ``(1 - w) bsdf_0 + w bsdf_1``."""

    pairs: Annotated[list[BlendPair], Field(min_length=1, max_length=2)] = _options(
        BLEND_PAIRS,
        "Lobe pairs, uniformly: 'conductor_diffuse' (bsdf_0 diffuse, bsdf_1 rough "
        "conductor) or 'two_roughness' (one conductor: bsdf_0 rough, bsdf_1 sharp).",
    )
    weight: UnitRange = _span(0.2, 0.8, "blendbsdf weight w of bsdf_1, uniform.")
    conductors: Conductors = _options(COMMON_METALS, "Conductors of the lobes, uniformly.")
    alpha: AlphaRange = _span(0.05, 0.5, f"Conductor alpha of 'conductor_diffuse', {_LOG}.")
    alpha_sharp: AlphaRange = _span(0.02, 0.1, f"Sharp lobe alpha of 'two_roughness', {_LOG}.")
    alpha_rough: AlphaRange = _span(0.15, 0.6, f"Rough lobe alpha of 'two_roughness', {_LOG}.")
    hue: UnitRange = _span(0.0, 1.0, _HUE)
    saturation: UnitRange = _span(0.0, 0.8, _SAT)
    value: UnitRange = _span(0.05, 0.8, _VAL)


class IridescentDistribution(StrictModel):
    """``iridescent``: analytic ``thin_film_ggx``, a dielectric film on a GGX conductor."""

    conductors: Conductors = _options(COMMON_METALS, "Named base conductors, uniformly.")
    alpha: AlphaRange = _span(0.05, 0.4, f"GGX alpha, {_LOG}.")
    thickness_nm: ThicknessRange = _span(200.0, 800.0, "Film thickness in nm, uniform.")
    film_ior: IorRange = _span(1.3, 1.6, "Film IOR (real), uniform.")


# -- sampling ------------------------------------------------------------------------------


class Draw(NamedTuple):
    """One drawn material: its source (as in a job spec), the drawn parameters, and an
    optional label for its name (e.g. the conductor, ``"Au"``)."""

    source: dict[str, Any]
    params: dict[str, Any]
    label: str | None = None


def _sig(x: float) -> float:
    return float(f"{float(x):.4g}")


def _uniform(rng: np.random.Generator, r: tuple[float, float]) -> float:
    return _sig(rng.uniform(r[0], r[1]))


def _log_uniform(rng: np.random.Generator, r: tuple[float, float]) -> float:
    return _sig(np.exp(rng.uniform(np.log(r[0]), np.log(r[1]))))


def _choice(rng: np.random.Generator, options: Sequence[str]) -> str:
    return options[int(rng.integers(len(options)))]


def _colour(rng: np.random.Generator, d: Any) -> list[float]:
    h, s, v = (float(rng.uniform(*r)) for r in (d.hue, d.saturation, d.value))
    return [round(c, 4) for c in colorsys.hsv_to_rgb(h % 1.0, s, v)]


def _rgb(value: list[float]) -> dict[str, Any]:
    return {"type": "rgb", "value": value}


def _conductor(material: str, alpha: float, distribution: str = "ggx") -> dict[str, Any]:
    return {
        "type": "roughconductor",
        "distribution": distribution,
        "alpha": alpha,
        "material": material,
    }


def sample_metal(rng: np.random.Generator, d: MetalDistribution) -> Draw:
    conductor, alpha = _choice(rng, d.conductors), _log_uniform(rng, d.alpha)
    ndf = _choice(rng, d.distributions)
    p = {"conductor": conductor, "alpha": alpha, "distribution": ndf}
    return Draw({"mitsuba": _conductor(conductor, alpha, ndf)}, p, conductor)


def sample_plastic(rng: np.random.Generator, d: PlasticDistribution) -> Draw:
    alpha, ior = _log_uniform(rng, d.alpha), _uniform(rng, d.ior)
    ndf, diffuse = _choice(rng, d.distributions), _colour(rng, d)
    p = {"alpha": alpha, "ior": ior, "distribution": ndf, "diffuse": diffuse}
    plugin = {
        "type": "roughplastic",
        "distribution": ndf,
        "alpha": alpha,
        "int_ior": ior,
        "ext_ior": 1.0,
        "diffuse_reflectance": _rgb(diffuse),
    }
    return Draw({"mitsuba": plugin}, p)


def sample_paint(rng: np.random.Generator, d: PaintDistribution) -> Draw:
    base, roughness = _colour(rng, d), _uniform(rng, d.roughness)
    is_metallic = bool(rng.random() < d.metallic_probability)
    metallic = _uniform(rng, d.metallic)  # drawn either way: the stream does not branch
    p: dict[str, Any] = {
        "base_color": base,
        "roughness": roughness,
        "metallic": metallic if is_metallic else 0.0,
        "specular": _uniform(rng, d.specular),
        "clearcoat": _uniform(rng, d.clearcoat),
        "clearcoat_gloss": _uniform(rng, d.clearcoat_gloss),
    }
    return Draw({"mitsuba": {"type": "principled", **p, "base_color": _rgb(base)}}, p)


def sample_sheen(rng: np.random.Generator, d: SheenDistribution) -> Draw:
    base = _colour(rng, d)
    p: dict[str, Any] = {
        "base_color": base,
        "roughness": _uniform(rng, d.roughness),
        "sheen": _uniform(rng, d.sheen),
        "sheen_tint": _uniform(rng, d.sheen_tint),
        "specular": _uniform(rng, d.specular),
    }
    return Draw({"mitsuba": {"type": "principled", **p, "base_color": _rgb(base)}}, p)


def sample_blend(rng: np.random.Generator, d: BlendDistribution) -> Draw:
    pair, weight = _choice(rng, d.pairs), _uniform(rng, d.weight)
    conductor = _choice(rng, d.conductors)
    # Every variable is drawn whatever the pair, so the stream does not branch.
    alpha, sharp, rough = (_log_uniform(rng, r) for r in (d.alpha, d.alpha_sharp, d.alpha_rough))
    colour = _colour(rng, d)
    p: dict[str, Any] = {"pair": pair, "weight": weight, "conductor": conductor}
    if pair == "conductor_diffuse":
        p.update(alpha=alpha, diffuse=colour)
        lobes = ({"type": "diffuse", "reflectance": _rgb(colour)}, _conductor(conductor, alpha))
    else:
        p.update(alpha_rough=rough, alpha_sharp=sharp)
        lobes = (_conductor(conductor, rough), _conductor(conductor, sharp))
    plugin = {"type": "blendbsdf", "weight": weight, "bsdf_0": lobes[0], "bsdf_1": lobes[1]}
    return Draw({"mitsuba": plugin}, p, conductor)


def sample_iridescent(rng: np.random.Generator, d: IridescentDistribution) -> Draw:
    material, alpha = _choice(rng, d.conductors), _log_uniform(rng, d.alpha)
    p = {
        "material": material,
        "alpha": alpha,
        "thickness_nm": _uniform(rng, d.thickness_nm),
        "film_ior": _uniform(rng, d.film_ior),
    }
    return Draw({"analytic": {"model": "thin_film_ggx", **p}}, p, material)


@dataclass(frozen=True)
class Family:
    """A family: its documented distribution (a strict model whose defaults are the
    distribution) and its sampler ``sample(rng, distribution) -> Draw``."""

    summary: str
    distribution: type[StrictModel]
    sample: Callable[[np.random.Generator, Any], Draw]


#: The families, in the order collections list them.
FAMILIES: dict[str, Family] = {
    "metal": Family("rough conductors (Mitsuba roughconductor)", MetalDistribution, sample_metal),
    "plastic": Family("rough plastics (Mitsuba roughplastic)", PlasticDistribution, sample_plastic),
    "paint": Family("clear-coated paints (Mitsuba principled)", PaintDistribution, sample_paint),
    "sheen": Family("cloth-like sheen (Mitsuba principled)", SheenDistribution, sample_sheen),
    "blend": Family("two-lobe blends (Mitsuba blendbsdf)", BlendDistribution, sample_blend),
    "iridescent": Family(
        "thin-film iridescence (analytic thin_film_ggx)", IridescentDistribution, sample_iridescent
    ),
}
assert tuple(FAMILIES) == get_args(FamilyName)


@dataclass(frozen=True)
class Preset:
    """A named collection: how many materials of each family."""

    summary: str
    counts: Mapping[str, int]


#: The named collections (``collection: {"preset": name}``).
PRESETS: dict[str, Preset] = {
    "small": Preset(
        "12 materials covering every family, for tests and the demo",
        {"metal": 3, "plastic": 2, "paint": 2, "sheen": 2, "blend": 2, "iridescent": 1},
    ),
    "merl100": Preset(
        "100 materials with the MERL database's size and spread: many metals, plastics, "
        "paints and fabrics, some two-layer finishes and films",
        {"metal": 28, "plastic": 24, "paint": 20, "sheen": 12, "blend": 10, "iridescent": 6},
    ),
}
assert tuple(PRESETS) == get_args(PresetName)


@dataclass(frozen=True)
class PlannedMaterial:
    """A material of a collection, before tabulation."""

    name: str
    family: str
    source: dict[str, Any]
    params: dict[str, Any]


def material_name(family: str, index: int, label: str | None) -> str:
    """``<family>-<index:03d>[-<label>]``, e.g. ``metal-003-Au``; file-system safe."""
    name = f"{family}-{index:03d}"
    if label:
        name += "-" + re.sub(r"[^A-Za-z0-9_-]", "_", label)
    if not SAFE_NAME.fullmatch(name):
        raise ValueError(f"material name {name!r} is not file-system safe")
    return name


def draw_collection(
    counts: Mapping[str, int],
    distributions: Mapping[str, StrictModel],
    rng_for: Callable[[str], np.random.Generator],
) -> list[PlannedMaterial]:
    """Draw ``counts[family]`` materials of each family, in :data:`FAMILIES` order.

    ``distributions`` overrides a family's default distribution; ``rng_for(family)`` gives
    that family's generator (e.g. ``lambda f: ctx.rng(f"generate.merl/{f}")``).
    """
    unknown = sorted(set(counts) - set(FAMILIES))
    if unknown:
        raise ValueError(f"unknown families {unknown}; known: {', '.join(FAMILIES)}")
    out: list[PlannedMaterial] = []
    for family, spec in FAMILIES.items():
        n = counts.get(family, 0)
        if n <= 0:
            continue
        dist = distributions.get(family) or spec.distribution()
        rng = rng_for(family)
        for k in range(n):
            draw = spec.sample(rng, dist)
            out.append(
                PlannedMaterial(
                    material_name(family, k, draw.label), family, draw.source, draw.params
                )
            )
    return out
