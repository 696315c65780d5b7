"""``report.stability`` reads a training loss from the one ``curves.json`` schema (issue 26
§1): ``train.brdf``'s ``train`` phase only (the held-out phase fits other materials), and
a ``train.brdf`` document of before the schema (phases under ``train``) still. Each kind's
loss key and reader are its own (:attr:`jobapi.reports.ReportFacts.loss_key`), read through
the registry."""

from __future__ import annotations

import pytest

from evaluators.report.stability import loss_curve
from jobapi.documents import check_curves
from service import kinds


@pytest.fixture(autouse=True)
def _builtin_kinds() -> None:
    kinds.load_builtin()


def test_train_phase_of_the_one_schema() -> None:
    doc = {
        "step": [5, 10, 14, 18],
        "loss": [1.0, 0.5, 0.7, 0.4],
        "lr": [0.1, 0.1, 0.1, 0.1],
        "phases": [
            {"name": "train", "first_step": 1, "last_step": 10},
            {"name": "heldout", "first_step": 11, "last_step": 18},
        ],
    }
    check_curves(doc)
    assert loss_curve("train.brdf", doc) == [1.0, 0.5]
    assert loss_curve("train.brdf", {k: v for k, v in doc.items() if k != "phases"}) == doc["loss"]


def test_other_kinds_and_old_documents() -> None:
    old = {"train": {"step": [1, 2], "loss": [3.0, 2.0]}, "heldout": None}
    assert loss_curve("train.brdf", old) == [3.0, 2.0]
    assert loss_curve("train.btf", {"step": [1], "train_loss": [0.2], "epoch": [1.0]}) == [0.2]
    assert loss_curve("train.fabric", {"step": [1], "loss": [0.9]}) == [0.9]
    assert loss_curve("train.fabric", None) == []
    # a kind that declares nothing: the one schema's "loss"
    assert loss_curve("no.such.kind", {"step": [1], "loss": [0.5]}) == [0.5]
