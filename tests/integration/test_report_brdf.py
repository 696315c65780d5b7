"""``report.brdf`` through the registry over tiny ``train.brdf`` runs.

Runs: analytic (2 seeds, timed: ``speed: trained``), hybrid 16x2 (2 seeds, timed)
and neural 16x2 (1 seed, ``speed: off``: the report times it itself), 12 steps each on a
3-material collection. References: each run's own ``metrics.json`` (the per-seed values and
their numpy mean / std / min / max), each run's speed timings' trained row (its manifest's
``timings.measured.speed``: the cost), and the claims recomputed here from those numbers.
Errors: a job that is not train.brdf, runs on different datasets, a duplicate.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from jobapi.errors import SpecError
from service.settings import Settings
from service.submission import run_in_process
from storage.artifacts import ArtifactStore
from storage.jobs import Job
from tests.helpers.manifests import speed_of

TINY = {"steps": 12, "batch_pairs": 64, "eval_pairs": 2048, "speed_batch": 4096}
NET = {"width": 16, "depth": 2}
PNG = b"\x89PNG\r\n\x1a\n"


def generate(settings: Settings, seed: int, families: dict[str, int]) -> Job:
    spec = {"kind": "generate.merl", "seed": seed, "params": {"collection": {"families": families}}}
    job = run_in_process(spec, settings)
    assert job.state == "succeeded", job.error
    return job


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Settings, Job, list[Job]]]:
    data = tmp_path_factory.mktemp("report_brdf")
    settings = Settings.from_env({}).with_(data_dir=Path(data) / "data", pool_processes=1)
    gen = generate(settings, 1, {"plastic": 1, "blend": 1, "iridescent": 1})
    specs = [({"model": "analytic"}, s) for s in (0, 1)]
    specs += [({"model": "hybrid", **NET}, s) for s in (0, 1)]
    specs += [({"model": "neural", **NET, "speed": "off"}, 0)]
    jobs = []
    for params, seed in specs:
        spec = {"kind": "train.brdf", "seed": seed,
                "params": {**TINY, **params, "dataset": f"job:{gen.id}"}}  # fmt: skip
        job = run_in_process(spec, settings)
        assert job.state == "succeeded", job.error
        jobs.append(job)
    yield settings, gen, jobs


def read(settings: Settings, job: Job, name: str) -> Any:
    (digest,) = [a.digest for a in job.artifacts if a.name == name]
    data = ArtifactStore(settings.store_dir).read(digest)
    return data if name.endswith(".png") else json.loads(data)


def report(settings: Settings, jobs: list[Job]) -> Job:
    spec = {"kind": "report.brdf", "params": {"runs": [f"job:{j.id}" for j in jobs]}}
    return run_in_process(spec, settings)


def test01_report_over_runs(runs: tuple[Settings, Job, list[Job]]) -> None:
    settings, _, jobs = runs
    job = report(settings, jobs)
    assert job.state == "succeeded", job.error
    pareto = read(settings, job, "pareto.json")
    points = {p["config"]: p for p in pareto["points"]}
    assert list(points) == ["analytic", "hybrid 16x2", "neural 16x2"]
    labels = ["analytic", "analytic", "hybrid 16x2", "hybrid 16x2", "neural 16x2"]
    per_seed: dict[str, list[float]] = {}
    for label, run in zip(labels, jobs, strict=True):
        per_seed.setdefault(label, []).append(read(settings, run, "metrics.json")["mean"]["smape"])
    spread = read(settings, job, "spread.json")["configs"]
    for label, vals in per_seed.items():
        p = points[label]
        assert p["smape_mean"] == pytest.approx(np.mean(vals)) and p["n"] == len(vals)
        assert p["smape_std"] == pytest.approx(np.std(vals, ddof=1) if len(vals) > 1 else 0.0)
        # The report reads each run's stored mean (never recomputes it), so these are the
        # very values metrics.json holds.
        assert (p["smape_min"], p["smape_max"]) == (min(vals), max(vals))
        assert [s["smape"] for s in spread[label]["per_seed"]] == vals
    # Cost: the runs' speed timings, trained rows (median over runs); neural was timed here.
    kernel = [speed_of(settings, j)["rows"][0]["fused_kernel_ns"] for j in jobs[2:4]]
    assert points["hybrid 16x2"]["ns_per_eval"] == pytest.approx(np.median(kernel))
    assert points["hybrid 16x2"]["ns_source"] == ["speed timings of the runs"]
    assert points["neural 16x2"]["ns_source"] == ["timed by this job"]
    assert all(p["ns_per_eval"] > 0 for p in points.values())
    assert points["analytic"]["bytes_per_material"] == 28
    by_cost = sorted(points.items(), key=lambda kv: kv[1]["ns_per_eval"])
    assert pareto["front"] == [c for c, p in by_cost if p["pareto"]]
    assert "analytic" in pareto["front"] or points["analytic"]["ns_per_eval"] > min(
        p["ns_per_eval"] for p in points.values()
    )
    # Claims, recomputed from the per-seed numbers, whichever way they come out.
    claims = {c["claim"]: c for c in pareto["claims"]}
    a, h, n = (np.mean(per_seed[k]) for k in ("analytic", "hybrid 16x2", "neural 16x2"))
    assert claims["hybrid 16x2 mean SMAPE < analytic"]["holds"] == bool(h < a)
    eq = claims["hybrid 16x2 mean SMAPE <= neural 16x2 at equal per-material parameters"]
    assert eq["holds"] == bool(h <= n) and eq["per_material_params"] == [11, 11]
    assert claims["hybrid 16x3 mean SMAPE <= neural 16x3 at equal per-material parameters"][
        "holds"
    ] is None  # fmt: skip
    fams = read(settings, job, "families.json")
    assert fams["families"][:2] == ["iridescent", "blend"]
    assert fams["configs"]["hybrid 16x2"]["blend"]["n"] == 2
    for name in ("pareto.png", "families.png"):
        assert read(settings, job, name)[:8] == PNG


def test02_bad_runs(runs: tuple[Settings, Job, list[Job]]) -> None:
    settings, gen, jobs = runs
    failed = report(settings, [gen])
    assert failed.state == "failed" and "is a generate.merl job, not train.brdf" in str(
        failed.error
    )
    other = generate(settings, 2, {"plastic": 1})
    params = {**TINY, "model": "analytic", "speed": "off", "dataset": f"job:{other.id}"}
    spec = {"kind": "train.brdf", "seed": 0, "params": params}
    elsewhere = run_in_process(spec, settings)
    failed = report(settings, [jobs[0], elsewhere])
    assert failed.state == "failed" and "different sets of materials" in str(failed.error)
    failed = report(settings, [jobs[0], jobs[0]])
    assert failed.state == "failed" and "listed twice" in str(failed.error)
    with pytest.raises(SpecError, match="runs"):
        run_in_process({"kind": "report.brdf", "params": {"runs": [f"job:{gen.id}/x"]}}, settings)


def test03_study_batch_file_validates() -> None:
    """``scripts/brdf_study.yaml``: 15 runs (5 configurations x 3 seeds) and the report over
    all of them, valid as ``matforge batch`` checks it before submitting anything."""
    from service.cli.batch import load_batch

    batch = load_batch(Path(__file__).resolve().parents[2] / "scripts" / "brdf_study.yaml")
    steps = {s.name: s for s in batch.steps}
    runs = steps["report"].spec["params"]["runs"]
    assert [s.kind for s in batch.steps].count("train.brdf") == len(runs) == 15
    for name in ("pareto", "stability", "select"):  # the other reports over the same runs
        assert steps[name].spec["params"]["runs"] == runs
    seeds = sorted(steps[r.removeprefix("step:")].spec["seed"] for r in runs)
    assert seeds == [0] * 5 + [1] * 5 + [2] * 5
