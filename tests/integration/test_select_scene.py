"""``select`` in its scene mode: render each rung, score it, choose the cheapest that meets
the target (:mod:`evaluators.report.select_scene`).

Oracles: the FLIP of every stored rung image against the stored reference, recomputed here
with :func:`evaluators.metrics.images.flip` directly (the ``score`` kind's conventions:
HDR-FLIP, exposures derived from the reference), and the chosen rung recomputed from those
values and the stored costs; the same spec run twice (same images, same values); a sentinel
shard recorded before the job runs (it is kept, not re-rendered); the spec validator's
messages (the field named).
"""

from __future__ import annotations

import json
import pickle
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from evaluators.metrics.images import flip, hdr_exposure_range
from jobapi.errors import SpecError
from service import kinds
from service.settings import Settings
from service.specs import validate_spec
from service.submission import run_in_process, submit
from storage.artifacts import ArtifactStore
from storage.formats.exr import read_exr
from storage.jobs import Job, JobStore

ROUGH = {"mitsuba": {"type": "roughconductor", "alpha": 0.2}}
SPEC: dict[str, Any] = {
    "kind": "select",
    "seed": 3,
    "params": {
        "scene": {"scene": "sphere_env", "resolution": [16, 16], "spp": 4, "max_depth": 4},
        "reference": {"material": ROUGH, "spp": 64},
        "ladder": [
            {"name": "diffuse", "material": {"mitsuba": {"type": "diffuse"}}},
            {"name": "rough1", "material": ROUGH, "spp": 1},
            {"name": "rough16", "material": ROUGH, "spp": 16},
        ],
        "metric": "flip",
        "target": 0.1,
        "cost": "spp",
    },
}
#: Timings vary from run to run; everything else in select.json must not.
TIMED = ("render_seconds", "frame_seconds")


@pytest.fixture
def inline(settings: Settings) -> Settings:
    """One pool process: the shards run inline (no spawned Mitsuba imports)."""
    kinds.load_builtin()
    return settings.with_(pool_processes=1)


def art(settings: Settings, job: Job, name: str) -> bytes:
    (digest,) = [a.digest for a in job.artifacts if a.name == name]
    return ArtifactStore(settings.store_dir).read(digest)


def image(settings: Settings, job: Job, name: str, tmp_path: Path) -> np.ndarray:
    path = tmp_path / f"{job.id}-{name}"
    path.write_bytes(art(settings, job, name))
    return np.asarray(read_exr(path, name), dtype=np.float32)


def doc(settings: Settings, job: Job) -> dict[str, Any]:
    out: dict[str, Any] = json.loads(art(settings, job, "select.json"))
    return out


def spec_with(**params: Any) -> dict[str, Any]:
    spec = json.loads(json.dumps(SPEC))
    spec["params"].update(params)
    return spec


def test01_chooses_the_cheapest_rung_meeting_the_recomputed_target(
    inline: Settings, tmp_path: Path
) -> None:
    job = run_in_process(SPEC, inline)
    assert job.state == "succeeded", job.error
    d = doc(inline, job)
    assert d["format"] == "matforge.select/1" and d["mode"] == "scene"
    (lad,) = d["ladders"]
    ref = image(inline, job, "reference.exr", tmp_path)
    exposure = hdr_exposure_range(ref, tonemapper="aces")
    recomputed = {}
    for rung in lad["rungs"]:
        img = image(inline, job, rung["image"], tmp_path)
        value, _ = flip(ref, img, mode="hdr", exposure_range=exposure)
        recomputed[rung["candidate"]] = value
        assert rung["value"] == pytest.approx(value, rel=1e-6, abs=1e-9)
        assert rung["meets"] == (value <= 0.1)
        assert rung["cost"] == rung["spp"]
        # one pass each at 16x16: the frame time is that pass, inside the shard's wall time
        assert 0 < rung["frame_seconds"] <= rung["render_seconds"]
    meeting = [r for r in lad["rungs"] if recomputed[r["candidate"]] <= 0.1]
    assert meeting, recomputed  # the ladder is built so that some rung meets the target
    cheapest = min(meeting, key=lambda r: (r["cost"], r["candidate"]))
    assert lad["chosen"] == cheapest["candidate"] == "rough16"
    # The ladder spans the target: the diffuse stand-in for a conductor does not meet it.
    assert recomputed["diffuse"] > 0.1 > recomputed["rough16"]
    assert recomputed["rough16"] < recomputed["rough1"]
    png = art(inline, job, "select.png")
    assert png.startswith(b"\x89PNG")
    # Result rows: one per rung, with its spp and render seconds.
    from jobapi.kinds import registered
    from jobapi.row_sources import StoreSource

    jobs = JobStore(inline.db_path)
    try:
        rows = registered()["select"].rows(  # type: ignore[misc]
            StoreSource(jobs.get(job.id), jobs, ArtifactStore(inline.store_dir))
        )
    finally:
        jobs.close()
    assert sorted(str(r.candidate) for r in rows) == ["diffuse", "rough1", "rough16"]
    assert all(r.metric == "image.flip" and r.scene == "sphere_env" for r in rows)
    assert {r.candidate: r.spp for r in rows} == {"diffuse": 4, "rough1": 1, "rough16": 16}
    assert all(r.render_seconds is not None and r.render_seconds > 0 for r in rows)
    # ... which report.pareto reads as any scored renders.
    pareto = run_in_process(
        {"kind": "report.pareto", "params": {"runs": [f"job:{job.id}"]}}, inline
    )
    assert pareto.state == "succeeded", pareto.error
    panels = json.loads(art(inline, pareto, "pareto.json"))["panels"]
    spp_panel = [p for p in panels if p["metric"] == "image.flip" and p["cost"] == "spp"]
    assert spp_panel and {pt["candidate"] for pt in spp_panel[0]["points"]} == set(recomputed)


def test02_same_spec_same_values(inline: Settings, tmp_path: Path) -> None:
    first = run_in_process(SPEC, inline)
    again = run_in_process({**SPEC, "force": True}, inline)
    assert first.state == again.state == "succeeded", (first.error, again.error)
    assert first.id != again.id

    def untimed(job: Job) -> Any:
        d = doc(inline, job)
        for r in d["ladders"][0]["rungs"]:
            for key in TIMED:
                r.pop(key)
        return d

    assert untimed(first) == untimed(again)
    for name in ("reference.exr", "rung_diffuse.exr", "rung_rough1.exr", "rung_rough16.exr"):
        assert art(inline, first, name) == art(inline, again, name), name
    # Every artifact but the declared timing ones (select.json; cost spp: not select.png)
    # is the same bytes.
    kind = kinds.get_kind("select")
    params = kind.params.model_validate(SPEC["params"])
    assert kind.is_timing_artifact("select.json", params)
    assert not kind.is_timing_artifact("select.png", params)  # ranked by spp
    timed = kind.is_timing_artifact(
        "select.png", params.model_copy(update={"cost": "frame_seconds"})
    )
    assert timed
    same = {
        a.name: a.digest for a in first.artifacts if not kind.is_timing_artifact(a.name, params)
    }
    assert same == {
        a.name: a.digest for a in again.artifacts if not kind.is_timing_artifact(a.name, params)
    }

    # The same reference given as an image ref: the same rung image, the same value.
    by_ref = spec_with(
        reference=f"job:{first.id}/reference.exr", ladder=SPEC["params"]["ladder"][1:2]
    )
    third = run_in_process(by_ref, inline)
    assert third.state == "succeeded", third.error
    (lad,) = doc(inline, third)["ladders"]
    (rung,) = lad["rungs"]
    before = {r["candidate"]: r for r in doc(inline, first)["ladders"][0]["rungs"]}
    assert art(inline, third, "rung_rough1.exr") == art(inline, first, "rung_rough1.exr")
    assert rung["value"] == pytest.approx(before["rough1"]["value"], rel=1e-6)
    assert lad["dataset"] == by_ref["params"]["reference"]


def test03_resumes_from_recorded_renders(inline: Settings, tmp_path: Path) -> None:
    """A re-run after a crash keeps a recorded render: the sentinel shard proves it."""
    from service.workers.worker import run_worker

    jobs, store = JobStore(inline.db_path), ArtifactStore(inline.store_dir)
    try:
        job, created = submit(SPEC, jobs, store)
        assert created
        stored = np.full((16, 16, 3), 0.25, np.float32)
        sentinel = {
            "image": stored,
            "seconds": 123.0,
            "integrator": "path",
            "passes": [4],
        }
        digest = store.put_bytes(pickle.dumps(sentinel, protocol=5)).digest
        jobs.record_shard(job.id, "render-diffuse", digest)
        assert run_worker(inline, max_jobs=1) == 1
        done = jobs.get(job.id)
        assert done.state == "succeeded", done.error
        rungs = {r["candidate"]: r for r in doc(inline, done)["ladders"][0]["rungs"]}
        assert rungs["diffuse"]["render_seconds"] == 123.0  # loaded, not rendered again
        assert rungs["rough1"]["render_seconds"] != 123.0
        img = image(inline, done, "rung_diffuse.exr", tmp_path)
        assert np.array_equal(img, stored)
    finally:
        jobs.close()


BAD = [
    ({"ladder": []}, "params.ladder", "at least 1"),
    ({"metric": "smape"}, "params", "metric: 'smape' is not an image metric"),
    (
        {"ladder": [{"name": "a", "material": ROUGH}, {"name": "a", "material": ROUGH}]},
        "params",
        "ladder: rung names listed more than once: a",
    ),
    ({"runs": ["job:" + "0" * 32]}, "params", "runs: give either runs"),
    ({"reference": None}, "params", "reference: required"),
    ({"scene": {"scene": "sphere_env", "material": ROUGH}}, "params", "scene.material"),
    ({"cost": "ns_per_eval"}, "params", "ladder.0.material: cost ns_per_eval"),
    (
        {
            "runs": ["job:" + "0" * 32],
            "scene": None,
            "reference": None,
            "ladder": None,
            "cost": "frame_seconds",
        },
        "params",
        "cost: frame_seconds is measured by the scene mode",
    ),  # fmt: skip
    (
        {"ladder": [{"name": "a", "material": {"mitsuba": {"type": "diffuse"}}, "spp": 0}]},
        "params.ladder.0.spp",
        "greater than or equal to 1",
    ),
    ({"ladder": [{"name": "a", "material": {"nope": 1}}]}, "params.ladder.0.material", "nope"),
    (
        {
            "ladder": [{"name": "big", "material": ROUGH, "spp": 65536}],
            "scene": {"scene": "sphere_env", "resolution": [4096, 4096]},
        },
        "params",
        "ladder.0: width * height * spp",
    ),  # fmt: skip
]


@pytest.mark.parametrize(("params", "loc", "text"), BAD)
def test04_bad_specs_refused_naming_the_field(params: dict[str, Any], loc: str, text: str) -> None:
    kinds.load_builtin()
    spec = spec_with(**params)
    spec["params"] = {k: v for k, v in spec["params"].items() if v is not None}
    with pytest.raises(SpecError) as err:
        validate_spec(spec)
    found = dict(err.value.errors)
    assert loc in found, found
    assert text in found[loc], found


def test05_runs_spec_keeps_its_canonical_form() -> None:
    """The runs mode's canonical params have no scene-mode keys (the same hash as before)."""
    kinds.load_builtin()
    spec = {"kind": "select", "params": {"runs": ["job:" + "1" * 32], "target": 0.05}}
    params = json.loads(validate_spec(spec).canonical)["params"]
    assert sorted(params) == ["cost", "metric", "runs", "target"]
    scene = json.loads(validate_spec(SPEC).canonical)["params"]
    assert "runs" not in scene and "material" not in scene["scene"]


def test06_the_metric_may_be_given_by_its_row_name() -> None:
    """``image.flip``, the name of the scene mode's result rows, is accepted as ``flip``
    is (a name read off ``matforge results`` works in the spec); ``image.smape`` is not."""
    kinds.load_builtin()
    validate_spec(spec_with(metric="image.flip"))
    with pytest.raises(SpecError, match="is not an image metric"):
        validate_spec(spec_with(metric="image.smape"))
