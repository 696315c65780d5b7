"""Material families and presets of ``generate.merl`` collections.

Oracles: the declared distributions (every drawn value inside its range, every choice in
its list); seeded generators (same seed, same draws; a family's first draws do not depend
on counts or other families); Mitsuba itself (every family builds in ``llvm_ad_rgb``, is
isotropic under the tabulation's probe and gives finite values); the spec validator (every
drawn source is a valid ``generate.merl`` source).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from generators.merl.collections import (
    ALL_CONDUCTORS,
    FAMILIES,
    PRESETS,
    SAFE_NAME,
    BlendDistribution,
    MetalDistribution,
    PaintDistribution,
    PlannedMaterial,
    draw_collection,
)
from materials.tabulate import ANISOTROPY_TOL

EVERY_FAMILY = {family: 40 for family in FAMILIES}


def rngs(seed: int):
    """Per-family generators, as a job derives them from its seed."""
    return lambda family: np.random.default_rng([seed, sum(map(ord, family))])


def by_family(materials: list[PlannedMaterial]) -> dict[str, list[PlannedMaterial]]:
    out: dict[str, list[PlannedMaterial]] = {}
    for m in materials:
        out.setdefault(m.family, []).append(m)
    return out


def within(value: float, bounds: tuple[float, float]) -> bool:
    """Inside ``[lo, hi]`` up to the rounding of drawn values (4 digits, colours 4 decimals)."""
    lo, hi = bounds
    tol = 5e-4 * max(abs(lo), abs(hi)) + 5e-5
    return lo - tol <= value <= hi + tol


def test01_every_family_documents_its_distribution() -> None:
    for name, family in FAMILIES.items():
        assert family.summary, name
        schema = family.distribution.model_json_schema()
        assert schema.get("additionalProperties") is False, name
        for field, prop in schema["properties"].items():
            assert prop.get("description"), f"{name}.{field} has no description"


def test02_seeded_draws_are_reproducible() -> None:
    a = draw_collection(EVERY_FAMILY, {}, rngs(1))
    b = draw_collection(EVERY_FAMILY, {}, rngs(1))
    c = draw_collection(EVERY_FAMILY, {}, rngs(2))
    assert a == b
    assert [m.source for m in a] != [m.source for m in c]
    # A family's first draws do not depend on its count or on the other families.
    few = draw_collection({"paint": 3}, {}, rngs(1))
    assert few == by_family(a)["paint"][:3]


def test03_names_are_unique_and_file_system_safe() -> None:
    materials = draw_collection(EVERY_FAMILY, {}, rngs(3))
    names = [m.name for m in materials]
    assert len(set(names)) == len(names) == sum(EVERY_FAMILY.values())
    assert all(SAFE_NAME.match(n) for n in names)
    metal = by_family(materials)["metal"][5]
    assert metal.name == f"metal-005-{metal.params['conductor']}"
    assert [m.family for m in materials] == sorted(
        (m.family for m in materials), key=list(FAMILIES).index
    )


def test04_drawn_parameters_respect_the_distributions() -> None:
    groups = by_family(draw_collection(EVERY_FAMILY, {}, rngs(4)))
    dist: dict[str, Any] = {name: fam.distribution() for name, fam in FAMILIES.items()}
    for m in groups["metal"]:
        d = dist["metal"]
        assert m.params["conductor"] in d.conductors and m.params["conductor"] != "none"
        assert within(m.params["alpha"], d.alpha)
        assert m.source["mitsuba"]["type"] == "roughconductor"
        assert m.source["mitsuba"]["material"] == m.params["conductor"]
    for m in groups["plastic"]:
        d = dist["plastic"]
        assert within(m.params["alpha"], d.alpha) and within(m.params["ior"], d.ior)
        assert within(max(m.params["diffuse"]), d.value)  # HSV value = largest channel
    for m in groups["paint"]:
        d = dist["paint"]
        plugin = m.source["mitsuba"]
        assert plugin["type"] == "principled" and "anisotropic" not in plugin
        assert within(m.params["clearcoat"], d.clearcoat)
        assert within(m.params["clearcoat_gloss"], d.clearcoat_gloss)
        assert m.params["metallic"] == 0.0 or within(m.params["metallic"], d.metallic)
    assert any(m.params["metallic"] > 0 for m in groups["paint"])
    assert any(m.params["metallic"] == 0 for m in groups["paint"])
    for m in groups["sheen"]:
        d = dist["sheen"]
        assert within(m.params["sheen"], d.sheen) and within(m.params["roughness"], d.roughness)
    for m in groups["blend"]:
        plugin = m.source["mitsuba"]
        assert plugin["type"] == "blendbsdf" and within(plugin["weight"], dist["blend"].weight)
        assert m.params["pair"] in ("conductor_diffuse", "two_roughness")
    assert {m.params["pair"] for m in groups["blend"]} == {"conductor_diffuse", "two_roughness"}
    for m in groups["iridescent"]:
        d = dist["iridescent"]
        assert m.source["analytic"]["model"] == "thin_film_ggx"
        assert within(m.params["thickness_nm"], d.thickness_nm)
        assert within(m.params["film_ior"], d.film_ior)
    # Log-uniform alpha: about half the metals below the geometric mean of the range.
    alphas = np.array([m.params["alpha"] for m in groups["metal"]])
    lo, hi = dist["metal"].alpha
    assert 0.2 < np.mean(alphas < math.sqrt(lo * hi)) < 0.8
    # Colours are reflectances.
    for m in groups["plastic"] + groups["paint"] + groups["sheen"]:
        colour = m.params.get("diffuse") or m.params["base_color"]
        assert len(colour) == 3 and all(0.0 <= c <= 1.0 for c in colour)


def test05_overrides_replace_the_defaults() -> None:
    overrides = {
        "metal": MetalDistribution(conductors=["Au"], alpha=(0.1, 0.1), distributions=["ggx"]),
        "paint": PaintDistribution(metallic_probability=0.0),
        "blend": BlendDistribution(pairs=["two_roughness"]),
    }
    groups = by_family(draw_collection({"metal": 5, "paint": 5, "blend": 3}, overrides, rngs(5)))
    assert {(m.params["conductor"], m.params["alpha"]) for m in groups["metal"]} == {("Au", 0.1)}
    assert all(m.params["metallic"] == 0.0 for m in groups["paint"])
    assert all(m.params["pair"] == "two_roughness" for m in groups["blend"])


def test06_presets_have_the_merl_databases_size_and_spread() -> None:
    small, merl100 = PRESETS["small"].counts, PRESETS["merl100"].counts
    assert sum(small.values()) == 12 and set(small) == set(FAMILIES)
    assert 95 <= sum(merl100.values()) <= 105
    assert set(merl100) == set(FAMILIES) and min(merl100.values()) > 0
    # MERL is mostly metals, plastics and paints, then fabrics.
    top3 = sorted(merl100, key=merl100.__getitem__, reverse=True)[:3]
    assert set(top3) == {"metal", "plastic", "paint"}
    drawn = draw_collection(merl100, {}, rngs(6))
    assert len({m.name for m in drawn}) == sum(merl100.values())


def test07_every_drawn_source_is_a_valid_job_source() -> None:
    from generators.merl.kind import MerlSource

    for m in draw_collection(PRESETS["merl100"].counts, {}, rngs(7)):
        assert MerlSource.model_validate(m.source).as_dict() == m.source


@pytest.mark.parametrize("family", list(FAMILIES))
def test08_families_are_isotropic_and_evaluate_in_llvm(family: str) -> None:
    from generators.merl.kind import MaterialTask, tabulate_material
    from storage.formats.merl import merl_from_bytes

    for m in draw_collection({family: 2}, {}, rngs(8)):
        out = tabulate_material(MaterialTask(m.name, m.source, 180, False, None, None))
        info = out["info"]
        assert info["anisotropy_error"] < ANISOTROPY_TOL, (m.name, info)
        if "mitsuba" in m.source:
            assert info["variant"] == "llvm_ad_rgb"
        table = merl_from_bytes(out["binary"], m.name)  # validates: finite values
        valid = table.rgb[~table.missing]
        assert valid.min() >= 0.0 and valid.max() > 0.0, m.name
        assert info["below_horizon_bins"] == int(table.missing.sum())


def test09_conductor_list_is_mitsubas() -> None:
    assert "none" not in ALL_CONDUCTORS and {"Au", "Ag", "Al", "Cu", "Cr"} <= set(ALL_CONDUCTORS)
