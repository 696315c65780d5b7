"""Mitsuba plugin and conductor names are checked before queueing (issue 14 §6), from a
list checked into the repo (the web process never imports Mitsuba), and the list matches
the installed Mitsuba."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import types
from pathlib import Path
from typing import Any

import pytest

from jobapi.errors import SpecError
from service import kinds
from service.specs import validate_spec

REPO = Path(__file__).resolve().parents[4]


def render(material: dict[str, Any]) -> dict[str, Any]:
    return {"kind": "render", "params": {"material": {"mitsuba": material}}}


def test01_the_checked_in_list_matches_mitsuba(mi: types.ModuleType) -> None:
    spec = importlib.util.spec_from_file_location(
        "mitsuba_names", REPO / "scripts/mitsuba_names.py"
    )
    assert spec and spec.loader
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    checked_in = (REPO / "evaluators/render/mitsuba_names.py").read_text(encoding="utf-8")
    assert checked_in == script.names_module(mi), (
        "evaluators/render/mitsuba_names.py does not match the installed Mitsuba: run "
        "`.venv/bin/python scripts/mitsuba_names.py --write`"
    )
    from evaluators.render.mitsuba_names import BSDF_PLUGINS, CONDUCTOR_MATERIALS

    assert {"diffuse", "roughconductor", "principled"} <= BSDF_PLUGINS
    assert {"Au", "Ag", "Cu", "Al", "none"} <= CONDUCTOR_MATERIALS
    for name in ("Au", "Cu_palik"):  # Mitsuba builds a conductor from each listed name
        mi.load_dict({"type": "conductor", "material": name})


def assert_refused(material: dict[str, Any], words: list[str]) -> None:
    """``validate_spec`` refuses a render of ``material`` with a ``SpecError`` naming
    ``params.material`` and every one of ``words``."""
    kinds.load_builtin()
    with pytest.raises(SpecError) as exc:
        validate_spec(render(material))
    text = str(exc.value)
    assert "params.material" in text
    for word in words:
        assert word in text, text


@pytest.mark.parametrize(
    ("material", "words"),
    [
        ({"type": "roughconductr"}, ["type", "'roughconductr'", "did you mean 'roughconductor'"]),
        ({"type": "roughconductor", "material": "Gold"}, ["material", "'Gold'", "'Au'"]),
        ({"type": "conductor", "material": "cu"}, ["did you mean 'Cu'"]),
        ({"type": "sphere"}, ["'sphere' is a Mitsuba plugin, but not a BSDF"]),
        ({"type": "twosided", "bsdf": {"type": "difuse"}}, ["bsdf.type", "'diffuse'"]),
        ({"type": "diffuse", "reflectance": {"type": "rgbb", "value": [1, 0, 0]}}, ["'rgb'"]),
    ],
)
def test02_typos_are_refused_before_queueing(material: dict[str, Any], words: list[str]) -> None:
    assert_refused(material, words)


@pytest.mark.parametrize(
    "material",
    [
        {"type": "roughconductor", "material": "Au", "alpha": 0.2},
        {"type": "conductor", "material": "none"},
        {"type": "twosided", "bsdf": {"type": "diffuse"}},
        {"type": "diffuse", "reflectance": {"type": "checkerboard"}},
        {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.2, 0.5, 0.8]}},
        {"type": "roughplastic", "diffuse_reflectance": {"type": "spectrum", "value": 0.5}},
    ],
)
def test03_good_dicts_pass(material: dict[str, Any]) -> None:
    kinds.load_builtin()
    validate_spec(render(material))


def test04_generate_kinds_check_the_same_names() -> None:
    kinds.load_builtin()
    merl = {"kind": "generate.merl", "params": {"source": {"mitsuba": {"type": "difuse"}}}}
    with pytest.raises(SpecError, match="did you mean 'diffuse'"):
        validate_spec(merl)
    btf = {
        "kind": "generate.btf",
        "params": {"surface": {"bsdf": {"type": "roughconductor", "material": "Gold"}}},
    }
    with pytest.raises(SpecError, match="'Au'"):
        validate_spec(btf)


def test05_the_web_process_does_not_import_mitsuba(tmp_path: Path) -> None:
    code = (
        "import sys; from pathlib import Path; "
        "from service.api import create_app; from service.settings import Settings; "
        "from service import kinds; from service.specs import validate_spec; "
        f"create_app(Settings.from_env({{}}).with_(data_dir=Path({str(tmp_path)!r}))); "
        "kinds.load_builtin(); "
        "validate_spec({'kind': 'render', 'params': {'material': {'mitsuba': "
        "{'type': 'roughconductor', 'material': 'Au'}}}}); "
        "print(sorted(m for m in ('mitsuba', 'drjit') if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=120
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def _script() -> types.ModuleType:
    spec = importlib.util.spec_from_file_location(
        "mitsuba_names", REPO / "scripts/mitsuba_names.py"
    )
    assert spec and spec.loader
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    return script


def test06_listed_properties_are_what_mitsuba_reads(mi: types.ModuleType) -> None:
    """Issue 26 §4: each listed property, given alone, is read by its plugin (Mitsuba calls
    it unreferenced only when not), and a misspelt one is refused by Mitsuba as
    unreferenced: the table says what Mitsuba says, independently of how it was found."""
    from evaluators.render.mitsuba_names import PLUGIN_PROPERTIES

    script = _script()
    assert {"alpha", "alpha_u", "distribution", "material"} <= PLUGIN_PROPERTIES["roughconductor"]
    assert {"int_ior", "ext_ior"} <= PLUGIN_PROPERTIES["dielectric"]  # not in its strings
    assert {"reflectance"} <= PLUGIN_PROPERTIES["diffuse"]
    for plugin, props in PLUGIN_PROPERTIES.items():
        base = {"type": plugin, **script.BASES.get(plugin, {})}
        for prop in sorted(props - set(base)):
            try:
                mi.load_dict({**base, prop: 0.5})
            except Exception as exc:  # a type or value error: read, and refused
                assert "unreferenced" not in str(exc), (plugin, prop, str(exc))
        with pytest.raises(Exception, match=r'(?s)unreferenced propert.*"alpah"'):
            mi.load_dict({**base, "alpah": 0.5})


@pytest.mark.parametrize(
    ("material", "words"),
    [
        (
            {"type": "roughconductor", "alpah": 0.2},
            ["alpah: unknown property 'alpah'", "'roughconductor'", "did you mean 'alpha'?"],
        ),
        (
            {"type": "twosided", "bsdf": {"type": "plastic", "int_iro": 1.5}},
            ["bsdf.int_iro", "did you mean 'int_ior'?"],
        ),
        (
            {"type": "diffuse", "reflectance": {"type": "checkerboard", "colour0": 0.1}},
            ["reflectance.colour0", "did you mean 'color0'?"],
        ),
        ({"type": "diffuse", "reflectance": {"type": "rgb", "vlaue": [1, 0, 0]}}, ["'value'"]),
        ({"type": "twosided", "bsdf": {"type": "diffuse"}, "alpha": 0.2}, ["alpha", "twosided"]),
    ],
)
def test07_unknown_properties_are_refused_before_queueing(
    material: dict[str, Any], words: list[str]
) -> None:
    assert_refused(material, words)


@pytest.mark.parametrize(
    "material",
    [
        {"type": "twosided", "front": {"type": "diffuse"}, "back": {"type": "conductor"}},
        {
            "type": "blendbsdf",
            "weight": {"type": "checkerboard", "color0": 0.2},
            "bsdf_0": {"type": "roughconductor", "alpha_u": 0.1, "alpha_v": 0.3},
            "bsdf_1": {"type": "roughplastic", "int_ior": 1.5, "nonlinear": True},
        },
        {"type": "mask", "opacity": 0.5, "material": {"type": "diffuse"}},
        {"type": "principled", "base_color": {"type": "rgb", "value": [1, 0, 0]}, "id": "p"},
        {"type": "dielectric", "int_ior": "water", "ext_ior": "air"},
    ],
)
def test08_nested_and_any_name_children_pass(
    mi: types.ModuleType, material: dict[str, Any]
) -> None:
    """No false refusals: what the check lets through, Mitsuba builds."""
    kinds.load_builtin()
    validate_spec(render(material))
    mi.load_dict(material)


def test09_loader_types_take_what_mitsuba_says(mi: types.ModuleType) -> None:
    """``rgb`` and ``spectrum`` are built by Mitsuba's loader, not plugins: the hand-written
    LOADER_PROPERTIES is held to Mitsuba here (``filename`` is refused anyway)."""
    from evaluators.render.sources.mitsuba import LOADER_PROPERTIES

    assert set(LOADER_PROPERTIES) == {"rgb", "spectrum"}
    for t, value in (("rgb", [0.2, 0.5, 0.8]), ("spectrum", 0.5)):
        assert LOADER_PROPERTIES[t] == {"value", "filename"}
        mi.load_dict({"type": "diffuse", "reflectance": {"type": t, "value": value}})
        with pytest.raises(Exception, match="either 'value' or 'filename'"):
            mi.load_dict({"type": "diffuse", "reflectance": {"type": t, "value": value, "x": 1}})
