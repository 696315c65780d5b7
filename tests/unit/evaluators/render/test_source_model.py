"""Sibling keys of material sources, and the ``model`` source's spec-time validation.

Oracle: the messages and locations pydantic reports through a params model that has a
:data:`evaluators.render.sources.common.MaterialParam` field, and the value a resolver receives.
"""

from __future__ import annotations

from typing import Any

import pytest
from pydantic import Field, ValidationError

import evaluators.render.sources.merl  # noqa: F401  (registers "merl", a source without siblings)
import evaluators.render.sources.model  # noqa: F401  (registers the "model" source)
from evaluators.render.sources import common as ms
from jobapi.params import StrictModel

REF = "sha256:" + "a" * 64


class P(StrictModel):
    material: ms.MaterialParam = Field(description="m")


def error(material: Any) -> str:
    with pytest.raises(ValidationError) as exc:
        P.model_validate({"material": material})
    [err] = exc.value.errors()
    assert err["loc"] == ("material",)
    return str(err["msg"])


def test01_model_source_validation() -> None:
    ok = P.model_validate({"material": {"model": REF, "material": "gold"}}).material
    assert ok == {"model": REF, "material": "gold"}  # no null neural_max_depth added
    deep = {"model": REF, "material": "gold", "neural_max_depth": 2}
    assert P.model_validate({"material": deep}).material == deep
    assert error({"model": REF}) == "material: this key is required"
    assert error({"model": REF, "material": ""}).startswith("material: String should have")
    assert error({"model": REF, "material": "g", "neural_max_depth": -1}).startswith(
        "neural_max_depth: Input should be greater than or equal to 0"
    )
    assert error({"model": REF, "material": "g", "neural_max_depth": "1"}).startswith(
        "neural_max_depth: Input should be a valid integer"
    )
    assert error({"model": "gold.json", "material": "g"}).startswith(
        "model: must be an artifact reference"
    )
    assert error({"model": REF, "material": "g", "spp": 3}) == (
        "spp: not a key of a 'model' material (allowed: model, material, fabric, interpolate, "
        "neural_max_depth, uv_scale)"
    )


def test02_sources_without_siblings_keep_one_key() -> None:
    msg = error({"mitsuba": {"type": "diffuse"}, "material": "gold"})
    assert msg.startswith("must have exactly one material source key") and "'material'" in msg
    assert error({"model": REF, "merl": REF}).startswith("must have exactly one material source")
    assert error({"material": "gold"}).startswith("unknown material source 'material'")
    assert error({}).startswith("must have exactly one material source key")


def test03_resolver_receives_the_whole_object(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ms, "_SOURCES", dict(ms._SOURCES))
    seen: list[Any] = []

    class Extra(StrictModel):
        scale: float = Field(default=1.0, description="s")

    def resolver(value: Any, ctx: Any, mi: Any) -> Any:
        seen.append(value)
        return "not a bsdf"

    ms.register_material_source("grey2", resolver, value_type=float, summary="t", siblings=Extra)
    assert P.model_validate({"material": {"grey2": 0.5, "scale": 2.0}}).material == {
        "grey2": 0.5,
        "scale": 2.0,
    }
    with pytest.raises(ms.JobFailed):  # the resolver ran; its result is not a BSDF

        class FakeMi:
            BSDF = type("BSDF", (), {})

        ms.resolve_material({"grey2": 0.5, "scale": 2.0}, None, FakeMi)  # type: ignore[arg-type]
    assert seen == [{"grey2": 0.5, "scale": 2.0}]
    schema = P.model_json_schema()["properties"]["material"]["oneOf"]
    [opt] = [o for o in schema if o["title"] == "grey2"]
    assert set(opt["properties"]) == {"grey2", "scale"} and opt["required"] == ["grey2"]
    with pytest.raises(ValueError, match="cannot also be one of its sibling keys"):

        class Clash(StrictModel):
            grey3: int = Field(description="x")

        ms.register_material_source("grey3", resolver, value_type=int, summary="t", siblings=Clash)
