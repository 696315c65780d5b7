"""``score`` of trained-model materials against MERL tables, through ``run_in_process``.

The models are freshly initialised torch models (:func:`models.brdf.networks.build_model`)
exported with :func:`models.brdf.portable.to_portable`, an analytic one and a hybrid one,
written as ``model.json`` and imported into the store as ``matforge import`` does; the
reference table is the tabulation of the analytic model's first material. Oracles: metrics
equal a direct computation (table lookup against ``eval_portable`` at the documented pairs,
through :mod:`evaluators.metrics.brdf`), in the same job as a table candidate; the analytic
material scored against its own tabulation is close (interpolation error only) and closer
than the other material; errors are clear for an image reference, a model without a
material, an unknown material, a table given as a model, and a model as the reference.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from pydantic import ValidationError

from evaluators.metrics.brdf import DEFAULT_PAIRS, PAIRS_SEED, brdf_mae, direction_pairs, smape
from evaluators.score.kind import ScoreParams
from materials import halfdiff as hd
from materials.tabulate import tabulate_analytic
from models.brdf.networks import Architecture, build_model
from models.brdf.portable import eval_portable, to_portable
from service.settings import Settings
from service.submission import import_file
from storage.artifacts import ArtifactStore
from storage.formats.exr import write_exr
from storage.formats.merl import MerlTable, write_merl
from storage.jobs import JobStore
from tests.helpers.score_jobs import metrics_json, run_score

NAMES = ["gold", "plastic"]


def model_doc(arch: Architecture, seed: int) -> dict[str, Any]:
    model = build_model(arch, len(NAMES), torch.Generator().manual_seed(seed))
    doc = to_portable(model, NAMES, ["metal", "plastic"])
    # Fresh materials start alike; make the second one a rough, diffuse one.
    doc["materials"][1].update(kd=[0.4, 0.2, 0.1], alpha=0.6)
    return doc


@pytest.fixture(scope="module")
def docs() -> dict[str, dict[str, Any]]:
    return {
        "analytic": model_doc(Architecture("analytic", 0, 0, 0), 1),
        "hybrid": model_doc(Architecture("hybrid", 8, 2, 2), 2),
    }


@pytest.fixture(scope="module")
def table(docs: dict[str, dict[str, Any]]) -> MerlTable:
    doc = docs["analytic"]
    return tabulate_analytic(lambda wi, wo: eval_portable(doc, "gold", wi, wo))[0]


def upload(path: Path, jobs: JobStore, store: ArtifactStore) -> str:
    return f"sha256:{import_file(path, jobs, store).digest}"


def upload_json(doc: dict[str, Any], path: Path, jobs: JobStore, store: ArtifactStore) -> str:
    path.write_text(json.dumps(doc, sort_keys=True))
    return upload(path, jobs, store)


def direct(table: MerlTable, doc: dict[str, Any], material: str) -> tuple[float, float]:
    """``(SMAPE, MAE)`` of ``material`` against ``table`` over the documented pairs."""
    wi, wo = direction_pairs(DEFAULT_PAIRS, seed=PAIRS_SEED, distribution="cosine")
    f = hd.lookup(table.rgb, wi, wo, interpolate=True)
    keep = np.all(f >= 0, axis=1)
    g = eval_portable(doc, material, wi[keep], wo[keep])
    return smape(f[keep], g, eps=0.0), brdf_mae(f[keep], g)


def test01_model_materials_scored_against_a_table(
    docs: dict[str, dict[str, Any]],
    table: MerlTable,
    tmp_path: Path,
    settings: Settings,
    jobs: JobStore,
    store: ArtifactStore,
) -> None:
    write_merl(tmp_path / "gold.binary", table)
    ref = upload(tmp_path / "gold.binary", jobs, store)
    analytic = upload_json(docs["analytic"], tmp_path / "analytic.json", jobs, store)
    hybrid = upload_json(docs["hybrid"], tmp_path / "model.json", jobs, store)
    params = {
        "reference": ref,
        "candidates": {
            "table": ref,
            "analytic": {"model": analytic, "material": "gold"},
            "analytic_plastic": {"model": analytic, "material": "plastic"},
            "hybrid": {"model": hybrid, "material": "gold"},
        },
    }
    doc = metrics_json(run_score(params, settings), store)
    rows = doc["metrics"]
    assert rows["table"] == {"smape": 0.0, "mae": 0.0}
    for label, model, material in [
        ("analytic", "analytic", "gold"),
        ("analytic_plastic", "analytic", "plastic"),
        ("hybrid", "hybrid", "gold"),
    ]:
        s, m = direct(table, docs[model], material)
        assert rows[label]["smape"] == pytest.approx(s, rel=1e-9), label
        assert rows[label]["mae"] == pytest.approx(m, rel=1e-9), label
    # Against its own tabulation only the interpolation error is left.
    assert 0.0 < rows["analytic"]["smape"] < 0.05
    assert rows["analytic"]["smape"] < rows["analytic_plastic"]["smape"]

    st = doc["settings"]
    assert st["artifact_kind"] == "merl"
    assert st["candidate_models"] == {
        "analytic": {"model": analytic, "material": "gold", "model_type": "analytic"},
        "analytic_plastic": {"model": analytic, "material": "plastic", "model_type": "analytic"},
        "hybrid": {"model": hybrid, "material": "gold", "model_type": "hybrid"},
    }
    assert st["candidate_missing_pairs"]["hybrid"] == 0


def test02_model_candidates_fail_clearly(
    docs: dict[str, dict[str, Any]],
    table: MerlTable,
    tmp_path: Path,
    settings: Settings,
    jobs: JobStore,
    store: ArtifactStore,
) -> None:
    write_merl(tmp_path / "gold.binary", table)
    tab = upload(tmp_path / "gold.binary", jobs, store)
    model = upload_json(docs["hybrid"], tmp_path / "model.json", jobs, store)
    write_exr(tmp_path / "img.exr", np.full((8, 8, 3), 0.5, dtype=np.float32))
    image = upload(tmp_path / "img.exr", jobs, store)
    gold = {"model": model, "material": "gold"}
    cases = [
        (
            {"reference": image, "candidates": {"m": gold}},
            "candidate 'm' is a trained BRDF model (model.json) but the reference is an EXR "
            "(HDR) image",
        ),
        (
            {"reference": tab, "candidates": {"m": model}},
            f"candidate 'm': {model} is a trained BRDF model (model.json); name one of its "
            f'materials with {{"model": "{model}", "material": NAME}}',
        ),
        (
            {"reference": tab, "candidates": {"m": {"model": model, "material": "silver"}}},
            "no material 'silver' in the model; it has gold, plastic",
        ),
        (
            {"reference": tab, "candidates": {"m": {"model": tab, "material": "gold"}}},
            "candidate 'm': {model, material} needs a trained model, but "
            f"{tab} is a MERL BRDF table",
        ),
        (
            {"reference": model, "candidates": {"t": tab}},
            f"reference {model} is a trained BRDF model (model.json); a model can only be a "
            "candidate",
        ),
    ]
    for params, message in cases:
        job = run_score(params, settings)
        assert job.state == "failed" and job.error is not None
        assert message in job.error, job.error

    # The candidate object is strict: unknown fields and a missing material are refused.
    for bad in ({"model": model, "material": "gold", "scale": 2}, {"model": model}):
        with pytest.raises(ValidationError):
            ScoreParams.model_validate({"reference": tab, "candidates": {"m": bad}})
