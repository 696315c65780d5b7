"""Kinds from other packages (``service.kinds``, entry-point group ``matforge.kinds``): what
a plugin adds, and that a broken one is reported and undone, never fatal.

The entry points are made here (``importlib.metadata.EntryPoint``) over modules written to
a temporary directory; the registry and the loader's state are restored after each test.
The installed-package path (a real wheel, ``matforge serve``) is tested end to end in
``tests/e2e/test_plugin_kinds.py``.
"""

from __future__ import annotations

import logging
import sys
import textwrap
from collections.abc import Callable, Iterator
from importlib.metadata import EntryPoint
from pathlib import Path

import pytest

from jobapi import kinds as jobapi_kinds
from service import kinds

KIND_SOURCE = """
from pydantic import Field
from jobapi.kinds import Kind, register
from jobapi.params import StrictModel

class P(StrictModel):
    n: int = Field(default=1, ge=1, le=9, description="a number")

def run(params, ctx):
    ctx.put_json("out.json", {{"n": params.n}})

{body}
"""


@pytest.fixture
def plugins_from(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> Iterator[Callable[[dict[str, str], list[tuple[str, str]]], list[kinds.Plugin]]]:
    """``load(modules, entry_points)``: write ``{module: body}``, declare the entry points
    ``[(name, value)]``, load the plugins afresh over the built-in kinds, return them."""
    kinds.load_builtin()
    monkeypatch.setattr(jobapi_kinds, "_KINDS", dict(jobapi_kinds._KINDS))
    monkeypatch.setattr(kinds, "_plugins", None)
    monkeypatch.syspath_prepend(str(tmp_path))
    written: list[str] = []

    def load(modules: dict[str, str], eps: list[tuple[str, str]]) -> list[kinds.Plugin]:
        for name, body in modules.items():
            (tmp_path / f"{name}.py").write_text(textwrap.dedent(body))
            written.append(name)
        found = [EntryPoint(n, v, kinds.ENTRY_POINT_GROUP) for n, v in eps]
        monkeypatch.setattr(kinds, "entry_points", lambda group: found)
        return kinds.plugins()

    yield load
    for name in written:
        sys.modules.pop(name, None)


def kind_module(body: str) -> str:
    return KIND_SOURCE.format(body=textwrap.dedent(body))


def test01_plugin_kind_joins_the_registry(plugins_from) -> None:
    builtin = set(jobapi_kinds.registered())
    found = plugins_from(
        {
            "plug_good": kind_module(
                'register(Kind(name="fit.toy", params=P, runner=run, description="a plugin kind"))'
            )
        },  # fmt: skip
        [("good", "plug_good")],
    )
    assert [(p.name, p.kinds, p.error) for p in found] == [("good", ("fit.toy",), None)]
    every = kinds.all_kinds()
    assert set(every) == builtin | {"fit.toy"}
    assert list(every)[-1] == "fit.toy"  # after the built-in kinds
    assert kinds.get_kind("fit.toy").description == "a plugin kind"
    assert kinds.plugin_of("fit.toy") == "good"  # no distribution here: the entry point
    assert kinds.plugin_of("render") is None


def test02_entry_point_to_a_kind_object(plugins_from) -> None:
    found = plugins_from(
        {
            "plug_obj": kind_module(
                'KIND = Kind(name="fit.obj", params=P, runner=run, description="d")'
            )
        },  # fmt: skip
        [("obj", "plug_obj:KIND")],
    )
    assert found[0].kinds == ("fit.obj",) and found[0].error is None
    assert "fit.obj" in kinds.all_kinds()


def test03_import_error_is_reported_not_raised(plugins_from, caplog) -> None:
    caplog.set_level(logging.ERROR, logger="matforge.kinds")
    before = dict(jobapi_kinds.registered())
    found = plugins_from(
        {
            "plug_missing": "import matforge_no_such_module_xyz\n",
            "plug_raises": "raise RuntimeError('plugin set-up failed')\n",
            "plug_exits": "import sys\nsys.exit(3)\n",
            "plug_ok": kind_module(
                'register(Kind(name="fit.ok", params=P, runner=run, description="d"))'
            ),  # fmt: skip
        },
        [
            ("a-missing", "plug_missing"),
            ("b-raises", "plug_raises"),
            ("c-exits", "plug_exits"),
            ("d-ok", "plug_ok"),
        ],  # fmt: skip
    )
    errors = {p.name: p.error for p in found}
    assert "ModuleNotFoundError" in errors["a-missing"]
    assert "matforge_no_such_module_xyz" in errors["a-missing"]
    assert "RuntimeError: plugin set-up failed" in errors["b-raises"]
    assert "SystemExit" in errors["c-exits"]
    assert errors["d-ok"] is None  # the others keep loading
    assert set(kinds.all_kinds()) == set(before) | {"fit.ok"}
    logged = caplog.text
    for name in ("a-missing", "b-raises", "c-exits"):
        assert f"plugin {name} " in logged and "not loaded" in logged


def test04_name_of_a_builtin_kind_is_refused_and_undone(plugins_from, caplog) -> None:
    caplog.set_level(logging.ERROR, logger="matforge.kinds")
    before = list(jobapi_kinds.registered().items())
    render = jobapi_kinds.registered()["render"]
    found = plugins_from(
        {
            # Registers a fine kind first, then takes "render": the whole plugin is undone.
            "plug_clash": kind_module(
                'register(Kind(name="fit.first", params=P, runner=run, description="d"))\n'
                'register(Kind(name="render", params=P, runner=run, description="evil"))'
            )
        },
        [("clash", "plug_clash")],
    )
    assert found[0].kinds == ()
    assert "kind 'render' collides with the built-in kind" in (found[0].error or "")
    assert kinds.get_kind("render") is render
    assert "fit.first" not in kinds.all_kinds()
    assert list(kinds.all_kinds().items()) == before  # same kinds, same order
    assert "collides with the built-in kind" in caplog.text


def test05_two_plugins_one_name(plugins_from) -> None:
    body = 'register(Kind(name="fit.same", params=P, runner=run, description="{0}"))'
    found = plugins_from(
        {"plug_one": kind_module(body.format("one")), "plug_two": kind_module(body.format("two"))},
        [("one", "plug_one"), ("two", "plug_two")],
    )
    assert found[0].error is None and found[0].kinds == ("fit.same",)
    assert "already registered by an earlier plugin" in (found[1].error or "")
    assert kinds.get_kind("fit.same").description == "one"


@pytest.mark.parametrize(
    ("body", "value", "expected"),
    [
        ("x = 1\n", "plug_bad:x", "an entry point of matforge.kinds names a module"),
        ("x = 1\n", "plug_bad", "registered no kind"),
        (
            kind_module('register(Kind(name="Bad Name", params=P, runner=run, description="d"))'),
            "plug_bad",
            "is not lowercase words",
        ),  # fmt: skip
        (
            kind_module('register(Kind(name="fit.p", params=dict, runner=run, description="d"))'),
            "plug_bad",
            "params is not a pydantic model",
        ),  # fmt: skip
    ],
)
def test06_malformed_plugins(plugins_from, body: str, value: str, expected: str) -> None:
    before = set(jobapi_kinds.registered())
    found = plugins_from({"plug_bad": body}, [("bad", value)])
    assert expected in (found[0].error or ""), found[0]
    assert set(kinds.all_kinds()) == before


def test07_loads_once(plugins_from) -> None:
    # The module counts its imports in the builtins (module state would reset if it were
    # imported twice); every later lookup must reuse the first load.
    import builtins

    found = plugins_from(
        {
            "plug_count": kind_module(
                "import builtins\nbuiltins._matforge_plugin_imports = getattr(builtins, "
                '"_matforge_plugin_imports", 0) + 1\n'
                'register(Kind(name="fit.once", params=P, runner=run, description="d"))'
            )
        },  # fmt: skip
        [("once", "plug_count")],
    )
    try:
        assert found[0].kinds == ("fit.once",)
        kinds.all_kinds(), kinds.get_kind("fit.once"), kinds.plugins(), kinds.load()
        assert builtins._matforge_plugin_imports == 1  # type: ignore[attr-defined]
    finally:
        del builtins._matforge_plugin_imports  # type: ignore[attr-defined]


def test08_readme_table_leaves_plugin_kinds_out(plugins_from) -> None:
    # The kinds reference (docs/reference/kinds.md) documents the built-in kinds: it must not
    # change when a plugin is installed
    # (tests/unit/service/test_readme.py compares it with the generated table).
    import importlib.util

    path = Path(__file__).resolve().parents[3] / "scripts" / "kinds_table.py"
    spec = importlib.util.spec_from_file_location("_kinds_table_under_test", path)
    assert spec is not None and spec.loader is not None
    table = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(table)
    plugins_from(
        {
            "plug_doc": kind_module(
                'register(Kind(name="fit.doc", params=P, runner=run, description="d"))'
            )
        },  # fmt: skip
        [("doc", "plug_doc")],
    )
    assert "fit.doc" in kinds.all_kinds()
    text = table.kinds_markdown()
    assert "### `render`" in text and "fit.doc" not in text
