"""The ``fabric`` material source: strict spec-time validation and the integrator swap.

Oracles: ``FabricParams`` itself (the validated spec must build the very material it
describes) and the exact error lines a user sees (field named, allowed values listed).
"""

from __future__ import annotations

import types

import pytest
from pydantic import ValidationError

import evaluators.render.sources.fabric  # noqa: F401  (registers the "fabric" source)
from evaluators.render.integrators import integrator_for
from evaluators.render.integrators.fabric_path import FABRIC_INTEGRATOR
from evaluators.render.kind import RenderParams
from evaluators.render.sources.fabric import FabricSpec, resolve_fabric
from materials.fabric.params import FabricParams
from materials.fabric.patterns import PATTERNS


def error_of(material: dict) -> str:
    with pytest.raises(ValidationError) as info:
        RenderParams(material=material)
    return str(info.value.errors()[0]["msg"])


def test01_defaults_and_round_trip() -> None:
    params = RenderParams(material={"fabric": {}})
    value = params.material["fabric"]
    assert value["pattern"] == "twill_3x3" and value["tiles_per_uv"] == 16.0
    assert value["visibility"] is True
    # The stored form is plain JSON and validates again to itself (canonical specs).
    assert RenderParams(material=params.material).material == params.material
    spec = FabricSpec.model_validate(value)
    assert spec.to_params() == FabricParams("twill_3x3")


def test02_fields_reach_fabric_params() -> None:
    value = {
        "pattern": "satin_5x10",
        "psi_deg": [25, -10],
        "u_max_deg": 30,
        "alpha": [0.2, 0.6],
        "beta": 0.5,
        "w": 0.9,
        "kd_warp": [0.6, 0.2, 0.1],
        "ks_weft": 0.3,
        "tiles_per_uv": 8,
        "visibility": False,
    }
    material = RenderParams(material={"fabric": value}).material["fabric"]
    got = FabricSpec.model_validate(material).to_params()
    want = FabricParams(
        "satin_5x10",
        psi_deg=(25, -10),
        u_max_deg=30,
        alpha=(0.2, 0.6),
        beta=0.5,
        w=0.9,
        kd_warp=(0.6, 0.2, 0.1),
        ks_weft=0.3,
    )
    assert got == want
    assert material["tiles_per_uv"] == 8.0 and material["visibility"] is False


def test02b_yarn_profile_reaches_fabric_params() -> None:
    """``yarn_profile`` is kept when set and left out of the stored form at its default
    (older specs keep their stored bytes); a wrong value names the field."""
    default = RenderParams(material={"fabric": {}}).material["fabric"]
    assert "yarn_profile" not in default
    material = RenderParams(material={"fabric": {"yarn_profile": "jin"}}).material["fabric"]
    assert material["yarn_profile"] == "jin"
    assert RenderParams(material={"fabric": material}).material["fabric"] == material
    got = FabricSpec.model_validate(material).to_params()
    assert got == FabricParams("twill_3x3", yarn_profile="jin")
    assert error_of({"fabric": {"yarn_profile": "round"}}).startswith("fabric.yarn_profile:")


def test03_errors_are_clear() -> None:
    allowed = ", ".join(sorted(PATTERNS))
    assert error_of({"fabric": {"pattern": "twill9"}}) == (
        f"fabric.pattern: unknown pattern 'twill9'; allowed: {allowed}"
    )
    assert error_of({"fabric": {"alpha": -0.1}}) == (
        "fabric: alpha must lie in [0.02, 1.0], got -0.1"
    )
    assert error_of({"fabric": {"kd_warp": [0.1, 0.2]}}) == (
        "fabric.kd_warp: must be a number or a list of 3 numbers [r, g, b], got [0.1, 0.2]"
    )
    assert error_of({"fabric": {"beta": [0.1, 0.2, 0.3]}}).startswith(
        "fabric.beta: must be a number or a list of 2 numbers [warp, weft]"
    )
    assert error_of({"fabric": {"colour": 1}}) == "fabric.colour: Extra inputs are not permitted"
    assert error_of({"fabric": {"tiles_per_uv": 0}}) == (
        "fabric.tiles_per_uv: Input should be greater than 0"
    )
    assert error_of({"fabric": {"visibility": "yes"}}).startswith("fabric.visibility:")
    assert error_of({"fabric": "twill_3x3"}).startswith("fabric:")


def test04_resolves_to_a_footprint_bsdf(mi: types.ModuleType) -> None:
    value = RenderParams(material={"fabric": {"pattern": "plain"}}).material["fabric"]
    bsdf = resolve_fabric(value, None, mi)  # type: ignore[arg-type]
    assert isinstance(bsdf, mi.BSDF) and bsdf.needs_footprint
    path = {"type": "path", "max_depth": 5}
    assert integrator_for(mi, bsdf, path) == {"type": FABRIC_INTEGRATOR, "max_depth": 5}
    diffuse = mi.load_dict({"type": "diffuse"})
    assert integrator_for(mi, diffuse, path) is path
