"""Issue 26 §1: one schema for ``curves.json`` and one for ``pareto.json``
(:mod:`jobapi.documents`, ``docs/artifacts.md``), checked when a kind writes them.

What every writing kind writes today passes (built with the kinds' own functions); the shapes
that drew nothing (``train.brdf``'s phases under ``train``, ``report.brdf``'s ``points``
without ``panels``) are refused with the field named; and a kind that writes another shape
fails its job."""

from __future__ import annotations

import copy
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from jobapi import kinds as jobapi_kinds
from jobapi.context import JobContext
from jobapi.documents import DocumentError, check_curves, check_document, check_pareto
from jobapi.kinds import Kind
from jobapi.params import StrictModel
from service import kinds
from service.settings import Settings
from service.submission import run_in_process


def brdf_curves() -> dict[str, Any]:
    from models.brdf.train import Curves, curves_document

    train = Curves(step=[5, 10], loss=[1.0, 0.5], loss_analytic=[0.6, 0.3],
                   loss_hybrid=[None, None], lr=[0.01, 0.005])  # fmt: skip
    held = Curves(step=[4, 8], loss=[0.7, 0.4], loss_analytic=[0.4, 0.2],
                  loss_hybrid=[None, None], lr=[0.01, 0.01])  # fmt: skip
    return curves_document({"train": train, "heldout": held})


def test_brdf_phases_follow_on_and_unmeasured_series_are_left_out() -> None:
    doc = brdf_curves()
    assert doc["step"] == [5, 10, 14, 18]
    assert doc["phases"] == [
        {"name": "train", "first_step": 1, "last_step": 10},
        {"name": "heldout", "first_step": 11, "last_step": 18},
    ]
    assert doc["loss"] == [1.0, 0.5, 0.7, 0.4] and "loss_hybrid" not in doc
    check_curves(doc)


def test_every_writer_passes() -> None:
    from models.btf.train import Curves as BtfCurves
    from models.fabric.train import Curves as FabricCurves

    fabric = FabricCurves(step=[1, 2], loss=[2.0, 1.0], lr=[0.1, 0.1])
    for values in fabric.components.values():
        values += [0.5, 0.25]
    check_curves(fabric.as_dict())
    btf = BtfCurves(step=[3], epoch=[1.0], train_loss=[0.2], train_l1=[0.2], test_l1=[0.3],
                    lr=[0.001])  # fmt: skip
    check_curves(btf.as_dict())  # one check: a run of a single point is valid
    check_curves(brdf_curves())
    check_pareto(PARETO)


PARETO: dict[str, Any] = {
    "format": "matforge.pareto/1",
    "runs": ["job:ab12", "job:cd34"],
    "panels": [
        {
            "dataset": "job:ef", "scene": None, "metric": "smape", "cost": "ns_per_eval",
            "cost_label": "ns", "front": ["a"],
            "points": [
                {"candidate": "a", "mean": 0.2, "std": 0.0, "min": 0.2, "max": 0.2, "cost": 10.0,
                 "front": True, "jobs": ["job:ab12"]},
                {"candidate": "b", "mean": 0.3, "cost": 12, "front": False},
            ],
        }
    ],
    "claims": [{"claim": "a < b", "holds": True}],
}  # fmt: skip


def refused(check: Any, doc: Any, *fragments: str) -> None:
    with pytest.raises(DocumentError) as err:
        check(doc)
    for f in fragments:
        assert f in str(err.value), (f, str(err.value))
    assert "docs/artifacts.md" in str(err.value)


def test_the_shapes_that_drew_nothing_are_refused() -> None:
    old_brdf = {"train": {"step": [1, 2], "loss": [1.0, 0.5]}, "heldout": None}
    refused(check_curves, old_brdf, "curves.json: step:", "top level")
    old_report = {"format": "matforge.brdf-report/1", "runs": ["job:ab"],
                  "points": [{"config": "a", "smape_mean": 0.1, "ns_per_eval": 3.0}]}  # fmt: skip
    refused(check_pareto, old_report, "pareto.json: panels:", "non-empty")


def test_curves_errors_name_the_field() -> None:
    good = {"step": [1, 2, 3], "loss": [3.0, 2.0, 1.0], "lr": [0.1, 0.1, 0.1], "note": "x"}
    check_curves(good)
    refused(check_curves, [1, 2], "(document)", "object expected")
    refused(check_curves, {**good, "step": [1, 1, 2]}, "step[1]", "increase")
    refused(check_curves, {**good, "step": [1, True, 3]}, "step[1]")
    refused(check_curves, {**good, "loss": [1.0, 2.0]}, "loss:", "3 values", "got 2")
    refused(check_curves, {**good, "loss": [1.0, float("nan"), 2.0]}, "loss[1]", "finite")
    refused(check_curves, {**good, "loss": [None, None, None]}, "loss:", "every value is null")
    refused(check_curves, {**good, "mse": {"a": [1.0]}}, "mse.a:")
    refused(check_curves, {**good, "mse": {}}, "mse:", "empty group")
    refused(check_curves, {**good, "loss": 3}, "loss:", "got int")
    refused(check_curves, {"step": [1], "lr": [0.1], "epoch": [1.0]}, "nothing to draw")
    refused(check_curves, {**good, "epoch": ["a", "b", "c"]}, "epoch[0]")
    phases = [{"name": "train", "first_step": 1, "last_step": 2}]
    refused(check_curves, {**good, "phases": phases}, "phases:", "after the last phase")
    gap = phases + [{"name": "heldout", "first_step": 4, "last_step": 9}]
    refused(check_curves, {**good, "phases": gap}, "phases[1]", "consecutive")
    refused(check_curves, {**good, "phases": [{"name": "train"}]}, "phases[0]")


def test_pareto_errors_name_the_field() -> None:
    def bad(change: Any, *fragments: str) -> None:
        doc = copy.deepcopy(PARETO)
        change(doc)
        refused(check_pareto, doc, *fragments)

    bad(lambda d: d.pop("format"), "format:")
    bad(lambda d: d.update(runs="job:ab"), "runs:")
    bad(lambda d: d["panels"][0].pop("metric"), "panels[0].metric")
    bad(lambda d: d["panels"][0].update(points=[]), "panels[0].points", "non-empty")
    bad(lambda d: d["panels"][0]["points"][1].update(cost=None), "points[1].cost", "finite")
    bad(lambda d: d["panels"][0]["points"][0].update(mean=float("inf")), "points[0].mean")
    bad(lambda d: d["panels"][0]["points"][0].pop("front"), "points[0].front")
    bad(lambda d: d["panels"][0].update(front=["b"]), "panels[0].front", "['b']", "['a']")
    bad(lambda d: d["panels"][0].update(front=["zz"]), "panels[0].front", "candidates")
    bad(lambda d: d["claims"][0].update(holds="yes"), "claims[0].holds")


def test_only_chart_documents_are_checked() -> None:
    check_document("metrics.json", {"anything": [1, 2]})
    with pytest.raises(DocumentError, match="phase2/curves.json: step"):
        check_document("phase2/curves.json", {"loss": [1.0]})


class NoParams(StrictModel):
    """No parameters."""


def run_bad_curves(params: NoParams, ctx: JobContext) -> None:
    ctx.put_json("curves.json", {"train": {"step": [1, 2], "loss": [1.0, 0.5]}})


@pytest.fixture
def bad_kind() -> Iterator[str]:
    kinds.load_builtin()
    kind = Kind(name="test_bad_curves", params=NoParams, runner=run_bad_curves,
                description="writes curves.json in a shape of its own")  # fmt: skip
    jobapi_kinds.register(kind)
    try:
        yield kind.name
    finally:
        jobapi_kinds._KINDS.pop(kind.name, None)


def test_a_kind_that_writes_another_shape_fails(bad_kind: str, tmp_path: Path) -> None:
    settings = Settings.from_env({}).with_(data_dir=tmp_path / "data", pool_processes=1)
    (settings.data_dir / "scratch").mkdir(parents=True)
    job = run_in_process({"kind": bad_kind, "params": {}}, settings)
    assert job.state == "failed" and not job.artifacts
    assert job.error is not None and "curves.json: step:" in job.error, job.error
