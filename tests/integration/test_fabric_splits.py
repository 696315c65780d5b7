"""Held-out sets end to end: ``generate.fabric``'s ``unseen_small`` preset writes each
material's ``split``; ``train.fabric`` trains on ``train`` alone and reports every split
apart (``metrics.json``'s ``sets``). Also that the older presets' ``materials.json`` keeps
its bytes (digests taken before the ``split`` field existed, same spec)."""

from __future__ import annotations

import json
from typing import Any

import pytest

from generators.fabric.kind import summarize as fabric_summary
from service.settings import Settings
from service.submission import run_in_process
from storage.artifacts import ArtifactStore
from storage.jobs import Job

#: unseen_small cut down: 8 materials x 128 queries x 16 samples.
UNSEEN: dict[str, Any] = {
    "preset": "unseen_small",
    "queries_per_material": 128,
    "shard_queries": 128,
    "samples": 16,
    "map_resolution": 16,
    "backend": "numpy",
    "sizes": "log_uniform",
}
TINY_TRAIN: dict[str, Any] = {
    "encoder_width": 16,
    "decoder_width": 16,
    "map_resolution": 16,
    "steps": 3,
    "batch": 32,
    "materials_per_step": 1,
    "holdout": 0.25,
    "device": "cpu",
}


def read(settings: Settings, job: Job, name: str) -> bytes:
    (digest,) = [a.digest for a in job.artifacts if a.name == name]
    return ArtifactStore(settings.store_dir).read(digest)


@pytest.fixture
def dataset(settings: Settings) -> Job:
    job = run_in_process({"kind": "generate.fabric", "seed": 5, "params": UNSEEN}, settings)
    assert job.state == "succeeded", job.error
    return job


def test01_splits_recorded_and_reported_apart(settings: Settings, dataset: Job) -> None:
    doc = json.loads(read(settings, dataset, "materials.json"))
    assert doc["config"]["splits"] is True and doc["config"]["sizes"] == "log_uniform"
    splits = {m["name"]: m["split"] for m in doc["materials"]}
    assert splits == {
        **{f"{p}-t00-s00": "train" for p in ("plain", "twill_3x3", "satin_5x5")},
        **{f"{p}-t00-s01": "unseen_material" for p in ("plain", "twill_3x3", "satin_5x5")},
        "twill_4x4-t00-s00": "unseen_pattern",
        "twill_4x4-t00-s01": "unseen_pattern",
    }
    table = fabric_summary(lambda name: json.loads(read(settings, dataset, name)))
    assert table is not None and table.columns[-1] == "split"
    assert {k: r["split"] for k, r in table.rows.items()} == splits
    job = run_in_process(
        {"kind": "train.fabric", "seed": 1,
         "params": {"dataset": f"job:{dataset.id}", **TINY_TRAIN}},
        settings,
    )  # fmt: skip
    assert job.state == "succeeded", job.error
    metrics = json.loads(read(settings, job, "metrics.json"))
    assert {r["name"]: r["split"] for r in metrics["materials"]} == splits
    sets = {s["split"]: s for s in metrics["sets"]}
    assert list(sets) == ["train", "unseen_material", "unseen_pattern"]
    assert [sets[k]["materials"] for k in sets] == [3, 3, 2]
    assert sets["unseen_pattern"]["patterns"] == ["twill_4x4"]
    for s in sets.values():
        spread = s["cloth_mean_error"]
        assert spread["min"] <= spread["mean"] <= spread["max"] and spread["std"] >= 0
        assert s["brdf"]["queries"] + s["btdf"]["queries"] == s["queries"]
    assert "beta_response" not in sets["train"]
    (resp,) = sets["unseen_pattern"]["beta_response"]
    assert resp["pattern"] == "twill_4x4" and len(resp["beta"]) == 2
    assert resp["paired"] is False  # each material its own queries


def test02_all_held_out_is_refused(settings: Settings) -> None:
    params = {**UNSEEN, "patterns": ["twill_4x4"]}
    gen = run_in_process({"kind": "generate.fabric", "seed": 5, "params": params}, settings)
    assert gen.state == "succeeded", gen.error
    job = run_in_process(
        {"kind": "train.fabric", "seed": 1, "params": {"dataset": f"job:{gen.id}", **TINY_TRAIN}},
        settings,
    )
    assert job.state == "failed" and "every material is held out" in (job.error or "")


#: Digests of ``materials.json`` (numpy backend; its bytes are parameters drawn by numpy's
#: seeded generators and the config) from the code before ``split`` existed.
OLD_PRESETS: dict[str, tuple[dict[str, Any], str]] = {
    "small": (
        {"preset": "small", "queries_per_material": 256, "shard_queries": 128, "samples": 64,
         "map_resolution": 16},
        "4d050fa1284d23eec5574240712c8938c48ce32432505202a9b4da7eab9615b9",
    ),
    "beta": (
        {"preset": "beta", "patterns": ["twill_3x3"], "shading_sets": 3,
         "queries_per_material": 128, "shard_queries": 128, "samples": 64,
         "map_resolution": 16},
        "756166bff6ca3e78b1f4b037fa2cc579c03210a19faa78a77e8c26c8603c9dbe",
    ),
}  # fmt: skip


@pytest.mark.parametrize("name", sorted(OLD_PRESETS))
def test03_older_presets_keep_their_bytes(settings: Settings, name: str) -> None:
    params, digest = OLD_PRESETS[name]
    spec = {"kind": "generate.fabric", "seed": 5, "params": {**params, "backend": "numpy"}}
    job = run_in_process(spec, settings)
    assert job.state == "succeeded", job.error
    (got,) = [a.digest for a in job.artifacts if a.name == "materials.json"]
    assert got == digest
    assert "split" not in json.loads(read(settings, job, "materials.json"))["materials"][0]
