"""``report.pareto`` through the registry over small real jobs, and the results table
(:mod:`service.results`) they make.

Jobs: a 2-material MERL collection; ``train.brdf`` analytic (seeds 0 and 1) and hybrid
16x2 (seed 0), 12 steps each; a sphere at 8 spp (the reference) and at 1 and 2 spp, scored
with FLIP. References: each run's own ``metrics.json`` and speed timings (its manifest's
``timings.measured.speed``: the points' errors and costs), the renders' spp and job times,
the front by brute force, the claim recomputed from those numbers.
Errors: a job without result rows, a duplicate, nothing to chart.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from service.results import RowFilter, batch_rows, rows_csv, select_rows
from service.settings import Settings
from service.submission import run_in_process
from storage.artifacts import ArtifactStore
from storage.jobs import Job, JobStore
from tests.helpers.manifests import measured
from tests.helpers.renders import own_render_seconds

TINY = {"steps": 12, "batch_pairs": 64, "eval_pairs": 2048, "speed_batch": 4096}
PNG = b"\x89PNG\r\n\x1a\n"


def render(seed: int, spp: int) -> dict[str, Any]:
    return {
        "kind": "render",
        "seed": seed,
        "params": {"resolution": [24, 24], "spp": spp, "max_depth": 3},
    }


def score(ref: Job, cands: dict[str, Job]) -> dict[str, Any]:
    return {
        "kind": "score",
        "params": {
            "reference": f"job:{ref.id}/image.exr",
            "metrics": ["flip", "psnr"],
            "candidates": {k: f"job:{j.id}/image.exr" for k, j in cands.items()},
        },
    }


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Settings, dict[str, Job]]]:
    data = tmp_path_factory.mktemp("report_pareto")
    settings = Settings.from_env({}).with_(data_dir=Path(data) / "data", pool_processes=1)
    (settings.data_dir / "scratch").mkdir(parents=True, exist_ok=True)

    def run(spec: dict[str, Any]) -> Job:
        job = run_in_process(spec, settings)
        assert job.state == "succeeded", job.error
        return job

    jobs = {
        "gen": run(
            {
                "kind": "generate.merl",
                "seed": 1,
                "params": {"collection": {"families": {"plastic": 1, "blend": 1}}},
            }
        )
    }
    for name, seed, model in (
        ("a0", 0, {"model": "analytic"}),
        ("a1", 1, {"model": "analytic"}),
        ("h0", 0, {"model": "hybrid", "width": 16, "depth": 2}),
    ):
        params = {**TINY, **model, "dataset": f"job:{jobs['gen'].id}"}
        jobs[name] = run({"kind": "train.brdf", "seed": seed, "params": params})
    jobs["gt"], jobs["spp1"], jobs["spp2"] = run(render(1, 8)), run(render(2, 1)), run(render(2, 2))
    jobs["score"] = run(score(jobs["gt"], {"spp1": jobs["spp1"], "spp2": jobs["spp2"]}))
    yield settings, jobs


def read(settings: Settings, job: Job, name: str) -> Any:
    (digest,) = [a.digest for a in job.artifacts if a.name == name]
    data = ArtifactStore(settings.store_dir).read(digest)
    return data if name.endswith(".png") else json.loads(data)


def report(settings: Settings, runs: list[Job], **params: Any) -> Job:
    spec = {"kind": "report.pareto", "params": {"runs": [f"job:{j.id}" for j in runs], **params}}
    return run_in_process(spec, settings)


def test01_fronts_over_brdf_runs_and_renders(study: tuple[Settings, dict[str, Job]]) -> None:
    settings, jobs = study
    runs = [jobs[k] for k in ("a0", "a1", "h0", "score")]
    job = report(settings, runs)
    assert job.state == "succeeded", job.error
    doc = read(settings, job, "pareto.json")
    panels = {(p["metric"], p["cost"]): p for p in doc["panels"]}
    assert {
        ("brdf.smape", "ns_per_eval"),
        ("brdf.smape", "bytes_per_material"),
        ("image.flip", "spp"),
        ("image.flip", "render_seconds"),
    } <= set(panels)
    # BRDF: each point is its runs' stored mean SMAPE, its cost their kernel ns/eval
    smape = {p["candidate"]: p for p in panels[("brdf.smape", "ns_per_eval")]["points"]}
    means = [read(settings, jobs[k], "metrics.json")["mean"]["smape"] for k in ("a0", "a1")]
    analytic = smape["analytic"]
    assert analytic["n"] == 2 and analytic["per_seed"] == means and analytic["seeds"] == [0, 1]
    assert analytic["mean"] == pytest.approx(np.mean(means))
    assert (analytic["min"], analytic["max"]) == (min(means), max(means))
    # its cost is this job's own timing pass (the training jobs' timings are their own
    # diagnostics): every candidate and the reference kernel, interleaved, 5 repeats
    timing = doc["timing"]
    assert timing["costs"] == measured(settings, job)["timing"]["costs"]
    assert set(timing["costs"]) == {"reference", "analytic", "hybrid 16x2"}
    assert timing["repeats"] == 5 and len(timing["order"]) == 5
    assert all(sorted(r) == sorted(timing["costs"]) for r in timing["order"])
    assert timing["machine"]["threads"] == 2 and timing["machine"]["processor"]
    assert timing["machine"]["runtimes"]["mitsuba_variant"].startswith("llvm_")
    dist = timing["costs"]["analytic"]["distribution"]
    assert analytic["cost"] == dist["median"] and analytic["cost_n"] == 5
    assert analytic["cost_min"] <= analytic["cost"] <= analytic["cost_max"]
    rel = analytic["relative"]
    assert rel["n"] == 5 and rel["min"] <= rel["median"] <= rel["max"] and rel["median"] > 0
    assert isinstance(analytic["resolved"], bool) and isinstance(analytic["tied_with"], list)
    assert panels[("brdf.smape", "ns_per_eval")]["cost_label"].startswith("ns_per_eval:")
    assert "one timing pass" in panels[("brdf.smape", "ns_per_eval")]["cost_label"]
    # render seconds are each render job's own timing: charted, not ranked
    secs_panel = panels[("image.flip", "render_seconds")]
    assert secs_panel["resolved"] is False
    assert "separate passes" in secs_panel["not_resolved"]
    # renders: FLIP against the candidate render's spp and time
    flip = {p["candidate"]: p for p in panels[("image.flip", "spp")]["points"]}
    scored = read(settings, jobs["score"], "metrics.json")["metrics"]
    assert {k: p["cost"] for k, p in flip.items()} == {"spp1": 1, "spp2": 2}
    assert {k: p["mean"] for k, p in flip.items()} == {k: scored[k]["flip"] for k in flip}
    secs = {p["candidate"]: p["cost"] for p in panels[("image.flip", "render_seconds")]["points"]}
    for k in secs:  # the render's own time (manifest), as its result rows give it
        assert secs[k] == pytest.approx(
            own_render_seconds(ArtifactStore(settings.store_dir), jobs[k])
        )
    for panel in doc["panels"]:  # the front by brute force
        pts = panel["points"]
        for p in pts:
            beaten = any(
                q is not p
                and q["cost"] <= p["cost"]
                and q["mean"] <= p["mean"]
                and (q["cost"] < p["cost"] or q["mean"] < p["mean"])
                for q in pts
            )
            assert p["front"] == (not beaten)
    # families from the per-material rows; the BRDF claim recomputed
    fams = {(f["candidate"], f["family"]) for f in doc["families"] if f["metric"] == "brdf.smape"}
    assert ("analytic", "blend") in fams and ("hybrid 16x2", "plastic") in fams
    claims = {c["claim"]: c for c in doc["claims"]}
    h = read(settings, jobs["h0"], "metrics.json")["mean"]["smape"]
    assert claims["hybrid 16x2 mean SMAPE < analytic"]["holds"] == bool(h < np.mean(means))
    assert claims["hybrid 16x2 mean SMAPE < analytic"]["why"]
    assert read(settings, job, "pareto.png")[:8] == PNG
    assert len(read(settings, job, "rows.json")) > 10


def test02_bad_runs(study: tuple[Settings, dict[str, Job]]) -> None:
    settings, jobs = study
    failed = report(settings, [jobs["gen"]])  # rows, but none of an error with a cost
    assert failed.state == "failed" and "no error metric with a cost" in str(failed.error)
    assert "tabulation." in str(failed.error)
    first = report(settings, [jobs["a0"]])
    assert first.state == "succeeded", first.error
    failed = report(settings, [first])  # a report re-states rows: it has none of its own
    assert failed.state == "failed" and "has no result rows" in str(failed.error)
    failed = report(settings, [jobs["a0"], jobs["a0"]])
    assert failed.state == "failed" and "listed twice" in str(failed.error)
    failed = report(settings, [jobs["a0"]], metrics=["flip"])
    assert failed.state == "failed" and "no error metric with a cost" in str(failed.error)


def test03_results_table_and_batches(study: tuple[Settings, dict[str, Job]]) -> None:
    settings, jobs = study
    js, store = JobStore(settings.db_path), ArtifactStore(settings.store_dir)
    rows = select_rows(js, store, job_ids=[jobs["score"].id, jobs["a0"].id])
    assert [r.job for r in rows] == sorted(
        [r.job for r in rows], key=[jobs["score"].id, jobs["a0"].id].index
    )
    only = select_rows(js, store, where=RowFilter(metric=("flip",)))
    assert {(r.candidate, r.spp) for r in only} == {("spp1", 1), ("spp2", 2)}
    by_ds = select_rows(js, store, where=RowFilter(dataset=jobs["gen"].id, kind="train.brdf"))
    assert {r.job for r in by_ds} == {jobs[k].id for k in ("a0", "a1", "h0")}
    assert rows_csv(only).splitlines()[0].startswith("job,step,kind,dataset,scene,candidate")
    # a batch's steps found again by their specs, in step order, refs resolved
    steps = [
        {"name": "gt", "spec": render(1, 8)},
        {"name": "one", "spec": render(2, 1)},
        {
            "name": "s",
            "spec": {
                "kind": "score",
                "params": {
                    "reference": "step:gt/image.exr",
                    "metrics": ["flip", "psnr"],
                    "candidates": {"spp1": "step:one/image.exr"},
                },
            },
        },
        {"name": "never", "spec": render(9, 1)},
    ]
    res = batch_rows(steps, js, store)
    assert [(s["step"], s["state"]) for s in res.steps] == [
        ("gt", "succeeded"),
        ("one", "succeeded"),
        ("s", "missing"),
        ("never", "missing"),
    ]
    assert [r.step for r in res.rows] == ["gt", "one"]  # render_seconds of each, in order
    steps[2]["spec"]["params"]["candidates"]["spp2"] = f"job:{jobs['spp2'].id}/image.exr"
    res = batch_rows(steps[:3], js, store)
    assert res.steps[2] == {
        "step": "s",
        "kind": "score",
        "job": jobs["score"].id,
        "state": "succeeded",
    }
    assert [(r.step, r.metric) for r in res.rows][2:] == [
        ("s", "image.flip"),
        ("s", "image.psnr"),
        ("s", "image.flip"),
        ("s", "image.psnr"),
    ]


def test04_stability_of_the_runs(study: tuple[Settings, dict[str, Job]]) -> None:
    """``report.stability`` over the same runs: each run's stored mean SMAPE, a convergence
    verdict from its own ``curves.json``, the model checks per material, the seed spread."""
    from evaluators.metrics.convergence import convergence

    settings, jobs = study
    runs = [jobs[k] for k in ("a0", "a1", "h0")]
    spec = {"kind": "report.stability", "params": {"runs": [f"job:{j.id}" for j in runs]}}
    job = run_in_process(spec, settings)
    assert job.state == "succeeded", job.error
    doc = read(settings, job, "stability.json")
    for run, src in zip(doc["runs"], runs, strict=True):
        metrics = read(settings, src, "metrics.json")
        assert run["error"] == metrics["mean"]["smape"] and run["metric"] == "brdf.smape"
        curves = read(settings, src, "curves.json")  # one phase: every point is training
        assert [p["name"] for p in curves["phases"]] == ["train"]
        loss = curves["loss"]
        assert run["convergence"] == convergence(loss)
        assert [m["name"] for m in run["materials"]] == [m["name"] for m in metrics["materials"]]
        for m in run["materials"]:
            assert set(m["nonfinite"]) >= {"grazing", "wi_eq_wo", "wi_below"}
            assert m["albedo_max"] > 0 and m["reciprocity_error"] >= 0
    (analytic,) = [c for c in doc["configs"] if c["candidate"] == "analytic"]
    errors = [r["error"] for r in doc["runs"][:2]]
    assert analytic["n"] == 2 and analytic["worst"] == max(errors)
    assert analytic["std"] == pytest.approx(np.std(errors, ddof=1))
    assert {f["family"] for f in doc["families"]} == {"plastic", "blend"}
    # The heat table's ratio, recomputed from the two analytic runs' own metrics.json: the
    # family's mean SMAPE over runs over the runs' mean whole-set SMAPE.
    own = [read(settings, j, "metrics.json") for j in runs[:2]]
    plastic = [m["smape"] for d in own for m in d["materials"] if m["family"] == "plastic"]
    (cell,) = [f for f in doc["families"] if (f["candidate"], f["family"]) == ("analytic",
                                                                            "plastic")]  # fmt: skip
    whole = np.mean([d["mean"]["smape"] for d in own])
    assert cell["ratio"] == pytest.approx(np.mean(plastic) / whole, rel=1e-9)
    assert read(settings, job, "stability.png")[:8] == PNG
    from jobapi.kinds import registered

    summary = registered()["report.stability"].summary
    assert summary is not None
    table = summary(lambda name: read(settings, job, name))
    assert table is not None
    got = [row["second_half_drop"] for row in table.rows.values()]
    assert got == [r["convergence"]["second_half_drop"] for r in doc["runs"]]
    assert all(v is not None for v in got)
    # A score job is a render family of its own: one cell per candidate, its FLIP, ratio 1
    # (its mean over the one score run listed).
    flips = read(settings, jobs["score"], "metrics.json")["metrics"]
    both = run_in_process(
        {"kind": "report.stability",
         "params": {"runs": [f"job:{jobs['a0'].id}", f"job:{jobs['score'].id}"],
                    "labels": ["a0", "sphere"]}}, settings)  # fmt: skip
    assert both.state == "succeeded", both.error
    cells = [f for f in read(settings, both, "stability.json")["families"] if f["kind"] == "score"]
    assert {f["candidate"]: f["mean"] for f in cells} == {
        k: pytest.approx(v["flip"], rel=1e-12) for k, v in flips.items()
    }
    assert all(f["family"] == "sphere" and f["ratio"] == pytest.approx(1.0) for f in cells)
    failed = run_in_process(
        {"kind": "report.stability", "params": {"runs": [f"job:{jobs['gt'].id}"]}}, settings
    )
    assert failed.state == "failed" and "report.stability checks" in str(failed.error)
    from jobapi.errors import SpecError

    with pytest.raises(SpecError, match="labels: 1 labels for 2 runs"):
        run_in_process(
            {"kind": "report.stability",
             "params": {"runs": [f"job:{jobs['a0'].id}", f"job:{jobs['a1'].id}"],
                        "labels": ["x"]}}, settings)  # fmt: skip


def test05_select_the_cheapest_render_that_meets_a_target(
    study: tuple[Settings, dict[str, Job]],
) -> None:
    """``select`` over the scored renders: the rungs by render time, the cheapest that
    meets a FLIP target set between the two candidates' FLIP."""
    settings, jobs = study
    flips = read(settings, jobs["score"], "metrics.json")["metrics"]
    worse, better = sorted(flips, key=lambda k: flips[k]["flip"], reverse=True)
    target = (flips[worse]["flip"] + flips[better]["flip"]) / 2
    spec = {
        "kind": "select",
        "params": {
            "runs": [f"job:{jobs['score'].id}"],
            "metric": "flip",
            "target": target,
            "cost": "spp",
        },
    }
    job = run_in_process(spec, settings)
    assert job.state == "succeeded", job.error
    (lad,) = read(settings, job, "select.json")["ladders"]
    assert [(r["candidate"], r["cost"]) for r in lad["rungs"]] == [("spp1", 1), ("spp2", 2)]
    assert lad["chosen"] == better and [r["meets"] for r in lad["rungs"]] == [
        r["candidate"] == better for r in lad["rungs"]
    ]
    assert read(settings, job, "select.png")[:8] == PNG
    spec["params"]["target"] = min(f["flip"] for f in flips.values()) / 2
    (none,) = read(settings, run_in_process(spec, settings), "select.json")["ladders"]
    assert none["chosen"] is None and "no rung" in none["why"]


def test05_select_times_its_rungs_in_one_pass(study: tuple[Settings, dict[str, Job]]) -> None:
    settings, jobs = study
    runs = [f"job:{jobs[k].id}" for k in ("a0", "a1", "h0")]
    spec = {
        "kind": "select",
        "params": {
            "runs": runs,
            "metric": "smape",
            "target": 10.0,
            "cost": "ns_per_eval",
            "timing": {"repeats": 6, "batch": 2048},
        },  # fmt: skip
    }
    job = run_in_process(spec, settings)
    assert job.state == "succeeded", job.error
    doc = read(settings, job, "select.json")
    timing = doc["timing"]
    assert timing["repeats"] == 6 and timing["settings"]["batch"] == 2048
    assert set(timing["costs"]) == {"reference", "analytic", "hybrid 16x2"}
    (lad,) = doc["ladders"]
    for r in lad["rungs"]:  # each rung's cost is the pass's median, with its spread
        dist = timing["costs"][r["candidate"]]["distribution"]
        assert r["cost"] == dist["median"] and r["cost_n"] == 6
        assert (r["cost_min"], r["cost_max"]) == (dist["min"], dist["max"])
        assert r["relative"]["median"] > 0
    # every rung meets a target of 10: the cheapest is chosen, resolved only when no
    # other rung's timing range reaches its own
    first, second = lad["rungs"][0], lad["rungs"][1]
    assert lad["chosen"] == first["candidate"]
    assert lad["resolved"] == (second["cost_min"] > first["cost_max"])
    assert (lad["tie"] == []) == lad["resolved"]
    # the default timing is left out of the canonical spec: the hash is the one before
    from service.specs import validate_spec

    plain = {**spec, "params": {k: v for k, v in spec["params"].items() if k != "timing"}}
    assert "timing" not in validate_spec(plain).canonical
    assert '"timing"' in validate_spec(spec).canonical
