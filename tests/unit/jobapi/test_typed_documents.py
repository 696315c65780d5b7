"""Typed documents (:mod:`jobapi.documents`, ``Kind.documents``): the writer's document is
validated against its ``TypedDict`` on ``put_json`` (missing, unknown or mistyped keys fail,
naming the field), its bytes are the writer's own, and readers get a typed document or
``None``.

References: the bytes of ``json.dumps(..., sort_keys=True, indent=2)`` of the same object
(validation must not change it), and hand-built documents with one fault each.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import NotRequired

import pytest
from typing_extensions import TypedDict

from jobapi import kinds as jobapi_kinds
from jobapi.context import JobContext
from jobapi.documents import DocumentError, check_typed, document, read_typed
from jobapi.kinds import Kind
from jobapi.params import StrictModel
from storage.artifacts import ArtifactStore
from storage.formats.glint_stats import GlintStats
from storage.jobs import JobStore
from tests.helpers.glint_stats import glint_stats


@document
class Inner(TypedDict):
    size: int
    """A size."""


@document
class Doc(TypedDict):
    name: str
    """A name."""
    values: list[float]
    """Numbers."""
    inner: Inner
    """A nested part."""
    note: NotRequired[str | None]
    """Optional."""


GOOD = {"name": "a", "values": [1, 2.5], "inner": {"size": 3}}


def test01_a_good_document_passes_and_reads_typed() -> None:
    check_typed("doc.json", GOOD, Doc)
    got = read_typed(GOOD, Doc)
    assert got is not None and got["inner"]["size"] == 3 and got["values"] == [1, 2.5]


@pytest.mark.parametrize(
    ("doc", "field"),
    [
        ({"name": "a", "values": [1.0]}, "inner"),  # missing
        ({**GOOD, "extra": 1}, "extra"),  # unknown
        ({**GOOD, "inner": {"size": "3"}}, "inner.size"),  # mistyped, no coercion
        ({**GOOD, "values": [1.0, None]}, "values.1"),
    ],
)
def test02_a_bad_document_fails_naming_the_field(doc: dict, field: str) -> None:
    with pytest.raises(DocumentError, match=rf"doc\.json: {field}: .*schema: .*Doc"):
        check_typed("doc.json", doc, Doc)
    assert read_typed(doc, Doc) is None


class NoParams(StrictModel):
    """No parameters."""


@pytest.fixture
def typed_kind() -> Iterator[str]:
    kind = Kind(name="test_typed_docs", params=NoParams, runner=lambda p, c: None,
                description="declares doc.json", documents={"doc.json": Doc})  # fmt: skip
    jobapi_kinds.register(kind)
    try:
        yield kind.name
    finally:
        jobapi_kinds._KINDS.pop(kind.name, None)


def _ctx(tmp_path: Path, kind: str) -> JobContext:
    return JobContext(job_id="0" * 32, seed=0, spec={"kind": kind, "params": {}},
                      store=ArtifactStore(tmp_path / "objects"), jobs=JobStore(tmp_path / "j.db"),
                      workdir=tmp_path)  # fmt: skip


def test03_put_json_validates_the_kinds_documents(typed_kind: str, tmp_path: Path) -> None:
    ctx = _ctx(tmp_path, typed_kind)
    rec = ctx.put_json("doc.json", GOOD)
    want = json.dumps(GOOD, indent=2, sort_keys=True, allow_nan=False) + "\n"
    assert ctx.store.read(rec.digest) == want.encode()  # the writer's bytes, unchanged
    with pytest.raises(DocumentError, match="doc.json: inner"):
        ctx.put_json("doc.json", {"name": "a", "values": []})
    ctx.put_json("other.json", {"anything": True})  # undeclared documents are not checked


def test04_builtin_documents_are_typed_dicts_of_json() -> None:
    from service import kinds

    kinds.load_builtin()
    declared = {(k.name, n): t for k in jobapi_kinds.registered().values()
                for n, t in k.documents.items()}  # fmt: skip
    assert declared[("generate.glint", "stats.json")] is GlintStats
    for (kind, name), typed in declared.items():
        assert name in jobapi_kinds.registered()[kind].artifacts, (kind, name)
        assert typed.__annotations__, (kind, name)
    check_typed("stats.json", glint_stats(), GlintStats)


def test05_chart_documents_are_typed_with_their_rules() -> None:
    """``curves.json`` and ``pareto.json``: each writer's document passes its type and rules
    (references: the writers' own documents, as the checkers' tests use them); a fault the
    type sees (a mistyped ``n``) and one only the rules see (steps that do not increase)
    both fail, naming the field, and readers get ``None`` for either."""
    from jobapi.documents import CHARTS, CurvesDocument, ParetoDocument, check_document
    from tests.unit.jobapi.test_documents import PARETO, brdf_curves

    assert CHARTS == {"curves.json": CurvesDocument, "pareto.json": ParetoDocument}
    curves = brdf_curves()
    check_typed("curves.json", curves, CurvesDocument)
    got = read_typed(curves, CurvesDocument)
    assert got is not None and got["step"] == curves["step"] and got.get("loss") == curves["loss"]
    bad_steps = {**curves, "step": list(reversed(curves["step"]))}
    with pytest.raises(DocumentError, match=r"curves\.json: step\[1\]: .*increase"):
        check_typed("curves.json", bad_steps, CurvesDocument)
    assert read_typed(bad_steps, CurvesDocument) is None
    bad_phase = {**curves, "phases": [{**curves["phases"][0], "first_step": "1"}]}
    with pytest.raises(DocumentError, match=r"curves\.json: phases"):
        check_document("curves.json", bad_phase)

    check_typed("pareto.json", PARETO, ParetoDocument)
    panel = PARETO["panels"][0]
    mistyped = {**PARETO, "panels": [{**panel, "points": [{**panel["points"][0], "n": "2"}]}]}
    with pytest.raises(DocumentError, match=r"pareto\.json: panels\.0\.points\.0\.n: .*Pareto"):
        check_document("pareto.json", mistyped)  # the hand-written checker let this pass
    assert read_typed(mistyped, ParetoDocument) is None
    off_front = {**PARETO, "panels": [{**panel, "front": ["nobody"]}]}
    with pytest.raises(DocumentError, match=r"pareto\.json: panels\[0\]\.front"):
        check_document("pareto.json", off_front)


def test06_kinds_that_write_a_chart_or_score_document_declare_its_type() -> None:
    """Every built-in kind that lists ``curves.json`` or ``pareto.json`` declares the one
    type, and every one that lists ``metrics.json`` its own, so the kinds reference lists
    their fields."""
    from evaluators.score.document import ScoreMetrics
    from jobapi.documents import CHARTS
    from service import kinds

    kinds.load_builtin()
    for kind in jobapi_kinds.registered().values():
        for name, typed in CHARTS.items():
            if name in kind.artifacts:
                assert kind.documents.get(name) is typed, (kind.name, name)
    assert jobapi_kinds.registered()["score"].documents == {"metrics.json": ScoreMetrics}
    # Each kind that writes a metrics.json has its own shape, and its own type.
    metrics = {k.name: k.documents.get("metrics.json") for k in jobapi_kinds.registered().values()
               if "metrics.json" in k.artifacts and kinds.plugin_of(k.name) is None}  # fmt: skip
    assert set(metrics) >= {"score", "train.brdf", "train.btf", "train.fabric", "evaluate.tss"}
    assert all(metrics.values()) and len(set(metrics.values())) == len(metrics), metrics


def test07_score_metrics_of_every_scorer_shape() -> None:
    """``score``'s ``metrics.json`` as its scorers write it (images; whole models with
    ``per_material``; BTF slices with ``cases``) passes; a label's metrics that are not
    numbers fail, naming the field."""
    from evaluators.score.document import ScoreMetrics

    images = {"reference": "job:ab/image.exr", "metrics": {"same": {"flip": 0.0, "psnr": None}},
              "settings": {"data_range": 1.0}}  # fmt: skip
    check_typed("metrics.json", images, ScoreMetrics)
    tables = {**images, "reference": {"gold": "sha256:00"},
              "per_material": {"same": {"gold": {"smape": 0.1, "mae": None}}}}  # fmt: skip
    check_typed("metrics.json", tables, ScoreMetrics)
    btf = {**images, "cases": {"same": [{"case": "grazing", "l1": 0.2}]}}
    check_typed("metrics.json", btf, ScoreMetrics)
    bad = {**images, "metrics": {"same": {"flip": "0.1"}}}
    with pytest.raises(DocumentError, match=r"metrics\.json: metrics\.same\.flip: "):
        check_typed("metrics.json", bad, ScoreMetrics)
    assert read_typed(bad, ScoreMetrics) is None


def test08_documents_of_every_train_and_generate_kind_are_declared() -> None:
    """The JSON documents of the train, generate, report.brdf and evaluate.tss kinds each
    have their type (a real job's document of each is checked in
    ``tests/integration/test_kinds_smoke.py``)."""
    from evaluators.tss.document import TssMetrics, TssPath, TssTiming
    from models.brdf.document import BrdfFamilies, BrdfModelDocument, BrdfSpread, TrainBrdfMaterials
    from models.btf.document import BtfModelDocument
    from models.fabric.document import FabricLatents, FabricModelDocument
    from service import kinds
    from storage.formats.fabric_documents import FabricMaterials, FabricStats
    from storage.formats.merl_materials import MerlMaterials

    kinds.load_builtin()
    declared = {(k.name, n): t for k in jobapi_kinds.registered().values()
                for n, t in k.documents.items()}  # fmt: skip
    assert (
        declared.items()
        >= {
            ("train.brdf", "model.json"): BrdfModelDocument,
            ("train.brdf", "materials.json"): TrainBrdfMaterials,
            ("train.btf", "model.json"): BtfModelDocument,
            ("train.fabric", "model.json"): FabricModelDocument,
            ("train.fabric", "latents.json"): FabricLatents,
            ("report.brdf", "spread.json"): BrdfSpread,
            ("report.brdf", "families.json"): BrdfFamilies,
            ("evaluate.tss", "metrics.json"): TssMetrics,
            ("evaluate.tss", "timing.json"): TssTiming,
            ("evaluate.tss", "path.json"): TssPath,
            ("generate.merl", "materials.json"): MerlMaterials,
            ("generate.fabric", "materials.json"): FabricMaterials,
            ("generate.fabric", "stats.json"): FabricStats,
        }.items()
    )


def test09_readers_test_documents_are_whole() -> None:
    """The documents the readers' tests build (``tests.helpers.job_documents``) are of
    their types, so those tests read what the kinds write; a row of ``evaluate.tss`` whose
    ``pass`` (a keyword, so the type's functional form) is missing fails naming it."""
    from evaluators.tss.document import TssMetrics, TssTiming
    from models.brdf.document import TrainBrdfMaterials, TrainBrdfMetrics
    from models.btf.document import TrainBtfMetrics
    from models.fabric.document import TrainFabricMetrics
    from storage.formats.fabric_documents import FabricStats
    from storage.formats.merl_materials import MerlMaterials
    from tests.helpers import job_documents as td

    gold = td.brdf_scores("gold", "metal", smape=0.4)
    check_typed("metrics.json", td.brdf_metrics([gold], smape=0.4), TrainBrdfMetrics)
    check_typed("materials.json", td.brdf_materials([("gold", "metal", "train")]),
                TrainBrdfMaterials)  # fmt: skip
    check_typed("metrics.json", td.btf_metrics(), TrainBtfMetrics)
    check_typed("metrics.json", td.fabric_metrics([{"name": "a"}], {"count": 1}),
                TrainFabricMetrics)  # fmt: skip
    row = td.tss_row(64, 2, flip_mean=0.1, flip_max=0.2, psnr_mean=None, psnr_min=None)
    check_typed("metrics.json", td.tss_metrics([row]), TssMetrics)
    check_typed("timing.json", td.tss_timing({"64/N=2": (0.01, None)}), TssTiming)
    check_typed("stats.json", td.fabric_stats(seconds=1.0, samples_per_second=2.0), FabricStats)
    merl = td.merl_materials([{"name": "a", "family": "custom", "source": {}, "tabulation": {}}])
    check_typed("materials.json", merl, MerlMaterials)
    passless = {k: v for k, v in row.items() if k != "pass"}
    with pytest.raises(DocumentError, match=r"metrics\.json: rows\.0\.pass: Field required"):
        check_typed("metrics.json", td.tss_metrics([passless]), TssMetrics)
