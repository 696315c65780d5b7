"""The ``material`` param: spec-time validation and job-time instantiation.

Oracles: pydantic's error locations and messages, Mitsuba's own plugin loader (a valid
dict gives an ``mi.BSDF``; an invalid one gives Mitsuba's message), and the registry
(a newly registered source is accepted without touching the params model).
"""

from __future__ import annotations

import types

import pytest
from pydantic import Field, ValidationError

from evaluators.render.kind import RenderParams
from evaluators.render.sources import common as ms
from jobapi.errors import JobFailed
from jobapi.params import StrictModel
from materials.backend import load_mitsuba


@pytest.fixture(scope="module")
def mitsuba_module() -> types.ModuleType:
    """Mitsuba with matforge's variant (LLVM, or the scalar fallback)."""
    return load_mitsuba()


def errors(data: dict) -> list[tuple[tuple, str]]:
    with pytest.raises(ValidationError) as exc:
        RenderParams.model_validate(data)
    return [(e["loc"], e["msg"]) for e in exc.value.errors()]


def test01_spec_time_validation() -> None:
    ok = RenderParams.model_validate(
        {"material": {"mitsuba": {"type": "roughconductor", "alpha": 0.2}}}
    )
    assert ok.material == {"mitsuba": {"type": "roughconductor", "alpha": 0.2}}
    assert RenderParams().material["mitsuba"]["type"] == "diffuse"
    [(loc, msg)] = errors({"material": {"nope": {}}})
    assert loc == ("material",) and msg.startswith("unknown material source 'nope'; known: ")
    assert "mitsuba" in msg.split("known: ")[1].split(", ")
    [(loc, msg)] = errors({"material": {"mitsuba": {"type": "diffuse"}, "extra": 1}})
    assert loc == ("material",) and "exactly one material source key" in msg
    [(loc, msg)] = errors({"material": {"mitsuba": {"alpha": 0.1}}})
    assert msg.startswith("mitsuba: a Mitsuba plugin dict needs a 'type' string")
    [(loc, msg)] = errors(
        {
            "material": {
                "mitsuba": {
                    "type": "diffuse",
                    "reflectance": {"type": "bitmap", "filename": "/etc/passwd"},
                }
            }
        }
    )
    assert msg.startswith("mitsuba: reflectance.filename: file paths are not allowed")


def test02_json_schema_lists_sources() -> None:
    schema = RenderParams.model_json_schema()["properties"]["material"]
    assert schema["description"]
    required = [o["required"] for o in schema["oneOf"]]
    assert ["mitsuba"] in required and ["merl"] in required


def test03_job_time_instantiation(mitsuba_module) -> None:
    mi = mitsuba_module
    bsdf = ms.resolve_material({"mitsuba": {"type": "roughconductor", "alpha": 0.3}}, None, mi)
    assert isinstance(bsdf, mi.BSDF)
    with pytest.raises(JobFailed) as exc:
        ms.resolve_material({"mitsuba": {"type": "no_such_plugin"}}, None, mi)
    text = str(exc.value)
    assert text.startswith("material.mitsuba: ") and "no_such_plugin" in text
    assert "[parser.cpp" not in text and "\n" not in text
    with pytest.raises(JobFailed, match="unreferenced property"):
        ms.resolve_material({"mitsuba": {"type": "diffuse", "bogus": 1.0}}, None, mi)
    with pytest.raises(JobFailed, match="material.mitsuba: plugin is a .*not a BSDF"):
        ms.resolve_material({"mitsuba": {"type": "sphere"}}, None, mi)


def test04_new_sources_plug_in(monkeypatch, mitsuba_module) -> None:
    monkeypatch.setattr(ms, "_SOURCES", dict(ms._SOURCES))
    ms.register_material_source(
        "grey",
        lambda value, ctx, mi: {
            "type": "diffuse",
            "reflectance": {"type": "rgb", "value": [value] * 3},
        },
        value_type=float,
        summary="test-only grey diffuse",
    )

    class P(StrictModel):
        material: ms.MaterialParam = Field(description="m")

    assert P.model_validate({"material": {"grey": 0.25}}).material == {"grey": 0.25}
    with pytest.raises(ValidationError, match="grey: Input should be a valid number"):
        P.model_validate({"material": {"grey": "dark"}})
    bsdf = ms.resolve_material({"grey": 0.25}, None, mitsuba_module)
    assert isinstance(bsdf, mitsuba_module.BSDF)


def test05_mitsubas_whole_message_is_kept(mitsuba_module) -> None:
    """Issue 26 §4: Mitsuba names the unreferenced property on its message's second line;
    the job's one-line error joins the lines instead of cutting at the first."""
    with pytest.raises(JobFailed) as exc:
        ms.resolve_material(
            {"mitsuba": {"type": "roughconductor", "alpah": 0.2}}, None, mitsuba_module
        )
    text = str(exc.value)
    assert "\n" not in text and "[parser.cpp" not in text, text
    assert text.startswith("material.mitsuba: ") and 'type "roughconductor":' in text, text
    assert '- float "alpah": 0.2' in text, text
