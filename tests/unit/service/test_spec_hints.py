"""Issue 26 §4: errors that keep the fact you need. A typo in an enum or ``Literal`` value
gets "did you mean" at any depth, a union whose one member fits the input's shape reports
that member's error at its own field (not four clauses, one per member and key), and
``matforge kinds KIND`` shows the fields and allowed values of nested models."""

from __future__ import annotations

from typing import Any

import pytest

from jobapi.errors import SpecError
from service import kinds
from service.kind_docs import nested_models
from service.specs import validate_spec


def glint(params: dict[str, Any]) -> dict[str, Any]:
    return {"kind": "generate.glint", "params": params}


def errors_of(spec: dict[str, Any]) -> list[tuple[str, str]]:
    kinds.load_builtin()
    with pytest.raises(SpecError) as exc:
        validate_spec(spec)
    return exc.value.errors


def test01_a_typo_in_a_nested_union_gets_one_error_and_a_hint() -> None:
    errors = errors_of(glint({"example": {"procedural": "scratch", "size": 16}}))
    assert len(errors) == 1, errors
    field, msg = errors[0]
    assert field == "params.example.procedural", errors
    assert "did you mean 'scratches'?" in msg and "accepted forms" not in msg, msg
    assert "normal_map" not in msg and "Extra inputs" not in msg, msg


@pytest.mark.parametrize(
    ("params", "field", "hint"),
    [
        ({"example": {"procedural": "leather"}, "preset": "smal"}, "params.preset", "'small'"),
        (
            {"example": {"procedural": "leather"}, "surface": {"distribution": "stochastc"}},
            "params.surface.distribution",
            "'stochastic'",
        ),
        ({"example": {"procedural": "Leather"}}, "params.example.procedural", "'leather'"),
    ],
)
def test02_did_you_mean_at_any_depth(params: dict[str, Any], field: str, hint: str) -> None:
    errors = errors_of(glint(params))
    assert [f for f, _ in errors] == [field], errors
    assert f"did you mean {hint}?" in errors[0][1], errors


def test03_a_union_no_member_fits_still_lists_every_form() -> None:
    (error,) = errors_of(glint({"example": {"size": 16}}))
    assert error[0] == "params.example"
    assert "none of its accepted forms fits" in error[1] and "normal_map" in error[1], error
    (far,) = errors_of(glint({"example": {"procedural": "zzz"}}))
    assert "did you mean" not in far[1], far  # no guess when nothing is close


def test04_kinds_document_nested_models() -> None:
    kinds.load_builtin()
    models = {name: rows for name, _, rows in nested_models(kinds.get_kind("generate.glint"))}
    assert {"ProceduralExample", "MapExample", "SurfaceSpec"} <= set(models)
    procedural = {row[0]: row for row in models["ProceduralExample"]}
    assert "scratches" in procedural["procedural"][1], procedural
    assert procedural["procedural"][2] == "required"
    assert "stochastic" in {row[0]: row for row in models["SurfaceSpec"]}["distribution"][1]


def render(params: dict[str, Any], **envelope: Any) -> dict[str, Any]:
    material = {"mitsuba": {"type": "diffuse"}}
    return {"kind": "render", **envelope, "params": {"material": material, **params}}


@pytest.mark.parametrize(
    ("spec", "field", "hint"),
    [
        (render({"sppp": 4}), "params.sppp", "did you mean 'spp'?"),
        (render({"Spp": 4}), "params.Spp", "did you mean 'spp'?"),  # case alone
        (render({"resolutoin": [8, 8]}), "params.resolutoin", "did you mean 'resolution'?"),
        (render({}, nmae="x"), "nmae", "did you mean 'name'?"),  # the envelope's fields
        ({"kind": "render", "parms": {}}, "parms", "did you mean 'params'?"),
        (glint({"example": {"procedural": "scratches", "sizee": 16}}), "params.example.sizee",
         "did you mean 'size'?"),  # a typo inside the one union member that fits
    ],
)  # fmt: skip
def test_unknown_field_gets_did_you_mean(spec: dict[str, Any], field: str, hint: str) -> None:
    errors = errors_of(spec)
    assert [f for f, _ in errors] == [field], errors
    assert errors[0][1] == "Extra inputs are not permitted; " + hint, errors


def test_unknown_field_far_from_any_gets_no_guess() -> None:
    assert errors_of(render({"zzzzzz": 1})) == [("params.zzzzzz", "Extra inputs are not permitted")]


def test_unknown_kind_gets_did_you_mean_first() -> None:
    ((field, msg),) = errors_of({"kind": "rendr", "params": {}})
    assert field == "kind"
    assert msg.startswith("unknown job kind 'rendr'; did you mean 'render'? (known kinds: ")
    assert "train.brdf" in msg  # the list stays, after the guess
    ((_, msg),) = errors_of({"kind": "no_such_thing"})
    assert "did you mean" not in msg and msg.startswith("unknown job kind 'no_such_thing' (")


def test_every_error_is_reported_envelope_kind_and_params() -> None:
    """The envelope's errors do not hide the params' (each part is checked)."""
    errors = errors_of(render({"sppp": 4, "spp": 0}, seed=-1, nmae="x"))
    assert [f for f, _ in errors] == ["seed", "nmae", "params.spp", "params.sppp"], errors
    errors = errors_of({"kind": "rendr", "seed": -1, "params": {}})
    assert [f for f, _ in errors] == ["seed", "kind"], errors


def test_kinds_render_lists_every_material_source(monkeypatch: pytest.MonkeyPatch) -> None:
    """``matforge kinds render`` names each form a ``material`` takes, ``external`` (a
    user's own model) included; the params table alone calls it an ``object``."""
    from typer.testing import CliRunner

    from evaluators.render.sources.common import material_sources
    from service.cli.main import app

    monkeypatch.setenv("COLUMNS", "200")
    res = CliRunner().invoke(app, ["kinds", "render"])
    assert res.exit_code == 0, res.output
    assert "material: an object of one of these forms" in res.stdout
    keys = sorted(material_sources())
    assert "external" in keys and "mitsuba" in keys
    for key in keys:
        assert f"│ {key} " in res.stdout, key
    assert "ONNX model through onnxruntime" in res.stdout
