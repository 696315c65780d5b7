"""A material source's row facts (``register_material_source(..., row_facts=...)``): what
a render of its material adds to result rows comes from the source, and
:func:`evaluators.render.rows.render_facts` names no source.

References: a source registered here, outside the built-ins, whose facts must reach the
render's row unchanged; the glint source's facts, against :func:`layer_bytes` computed
here from the data job's ``stats.json``; a source without the hook adds nothing.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any

import pytest

from evaluators.render.rows import render_facts, render_rows
from evaluators.render.sources import common, material_sources
from evaluators.render.sources.common import MaterialRowFacts, register_material_source
from evaluators.render.sources.glint import layer_bytes
from jobapi.rows import JobFacts, RowSource
from tests.helpers.glint_stats import glint_stats

DATA = "job:" + "d" * 32


class Job:
    """A finished job with given params and JSON artifacts; other jobs by id."""

    def __init__(
        self,
        kind: str,
        params: Mapping[str, Any],
        artifacts: Mapping[str, Any] | None = None,
        others: Mapping[str, Job] | None = None,
    ) -> None:
        self.job = JobFacts(id="a" * 32, kind=kind, seed=3, params=params, run_seconds=2.0,
                            measured={"render_seconds": 0.5})  # fmt: skip
        self._artifacts, self._others = artifacts or {}, others or {}

    def read(self, name: str) -> Any:
        return self._artifacts.get(name)

    def source(self, ref: str) -> RowSource | None:
        return self._others.get(ref.removeprefix("job:").split("/")[0])


@pytest.fixture
def plugin_source() -> Iterator[str]:
    """A source ``testlayer`` (as a plug-in would register it), removed afterwards."""

    def facts(src: RowSource, material: Mapping[str, Any]) -> MaterialRowFacts:
        layers = int(material["testlayer"]["layers"])
        return MaterialRowFacts(config={"layers": layers}, bytes_per_material=64.0 * layers)

    register_material_source(
        "testlayer", lambda v, ctx, mi: {"type": "diffuse"}, value_type=dict[str, int],
        summary="a test source", row_facts=facts,
    )  # fmt: skip
    yield "testlayer"
    del common._SOURCES["testlayer"]


def render(material: Mapping[str, Any], others: Mapping[str, Job] | None = None) -> Job:
    return Job("render", {"scene": "sphere_env", "spp": 16, "material": material}, None, others)


def test01_a_new_source_adds_its_facts_without_touching_rows(plugin_source: str) -> None:
    (row,) = render_rows(render({plugin_source: {"layers": 3}}))
    assert row.bytes_per_material == 192.0
    assert row.config["layers"] == 3 and row.config["source"] == plugin_source
    assert row.render_seconds == 0.5 and row.spp == 16


def test02_a_source_without_the_hook_adds_nothing() -> None:
    assert material_sources()["mitsuba"].row_facts is None
    facts = render_facts(render({"mitsuba": {"type": "diffuse"}}))
    assert "bytes_per_material" not in facts
    assert facts["config"]["source"] == "mitsuba"


def test03_glint_facts_come_from_the_glint_source() -> None:
    data = Job("generate.glint", {}, {"stats.json": glint_stats(size=16, total=5000)})
    glint = {"data": DATA, "method": "tiny_example", "texels_per_uv": 128.0}
    facts = render_facts(render({"glint": glint}, {"d" * 32: data}))
    want = layer_bytes("tiny_example", tiny_bytes=5000.0, texels_per_uv=128.0, oversample=2,
                       yan_rate=1)  # fmt: skip
    assert facts["bytes_per_material"] == want
    assert facts["config"]["method"] == "tiny_example" and facts["config"]["example"] == 16
    assert facts["config"]["texels_per_uv"] == 128.0


def test04_rows_module_names_no_source() -> None:
    # The oracle is the registry: no registered source key is a string literal of rows.py.
    import ast
    from pathlib import Path

    import evaluators.render.rows as rows

    tree = ast.parse(Path(rows.__file__).read_text())
    literals = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)}
    # "model" may appear: material_source's rule that a model key wins over its fabric
    # sibling ({"model": ..., "fabric": ...} is a model), not a row fact.
    named = literals & set(material_sources()) - {"model"}
    assert not named, f"evaluators/render/rows.py names material sources {sorted(named)}"
