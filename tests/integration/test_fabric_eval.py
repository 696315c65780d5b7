"""``scripts/fabric_eval.yaml`` (Sec. 6 of the woven-fabric paper) run through the job machinery.

The batch file is loaded and validated as ``matforge batch`` does (:func:`load_batch`), then
each step runs through :func:`service.submission.run_in_process` with its ``step:`` refs
resolved by :func:`service.cli.batch.substitute_refs`, after shrinking the costly params: the
dataset of ``tests/integration/test_train_fabric.py`` (640 queries per material, 64
samples), a 300-step fit of its tiny network, renders at 64x64 (ground truth 64 spp instead
of 256, network 4 spp instead of 16; the 1- and 6-spp baselines as they are).

References: each material's Monte Carlo render at 64 spp (the shrunk ground truth), scored
by the ``score`` steps; for the interpolation endpoints, the plain ``{"model", "fabric"}``
renders of the two materials. Oracles: every metric is finite and in its range and the
documented artifacts exist; the Monte Carlo estimator converges (6 spp scores a better
PSNR, MSE and FLIP than 1 spp against the 64-spp reference, for the seen and the unseen
material); the interpolated latent at ``t = 0`` and ``t = 1`` renders the same bytes as the
materials themselves, and ``t = 0.5`` differs from both. The tiny network's quality is not
asserted (300 steps); ``benchmarks/bench_fabric_eval.py`` measures the real one.
"""

from __future__ import annotations

import json
import math
import types
from typing import Any

import pytest

from service.settings import Settings
from service.submission import run_in_process
from storage.jobs import Job
from tests.helpers.fabric_recipes import DATASET, TINY
from tests.helpers.recipes import artifact, run_recipe

SHRINK: dict[str, dict[str, Any]] = {
    "generate.fabric": DATASET,
    "train.fabric": {**TINY, "steps": 300},
    "render": {"resolution": [64, 64]},
}
#: The recipe's spp -> the test's (1 and 6 spp stay as they are).
SPP = {256: 64, 16: 4}
RENDER_ARTIFACTS = {"image.exr", "preview.png", "render.json"}
RANGES = {"flip": (0.0, 1.0), "psnr": (0.0, 200.0), "ssim": (-1.0, 1.0), "mse": (0.0, 10.0)}


@pytest.fixture(scope="module")
def chain(
    tmp_path_factory: pytest.TempPathFactory, mi: types.ModuleType
) -> tuple[Settings, dict[str, Job]]:
    """Every step of the shrunk recipe, run in order (``mi``: LLVM Mitsuba checked first)."""

    def shrink(spec: dict[str, Any]) -> dict[str, Any]:
        params = spec["params"]
        params.update(SHRINK.get(spec["kind"], {}))
        if spec["kind"] == "render":
            params["spp"] = SPP.get(params["spp"], params["spp"])
        return spec

    return run_recipe(tmp_path_factory, "fabric_eval.yaml", shrink, lease_seconds=30.0)


def scores(settings: Settings, job: Job) -> dict[str, dict[str, float]]:
    return json.loads(artifact(settings, job, "metrics.json"))["metrics"]


def test01_scores_are_finite_and_monte_carlo_converges(
    chain: tuple[Settings, dict[str, Job]], mitsuba_llvm: None
) -> None:
    settings, jobs = chain
    for name, job in jobs.items():
        if job.kind == "render":
            assert RENDER_ARTIFACTS <= {a.name for a in job.artifacts}, name
    expected = {
        "seen_scores": {"net16", "net1", "mc1", "mc_eq"},
        "unseen_scores": {"net16", "net1", "mc1", "mc_eq"},
        "interp_scores": {"interpolated", "direct"},
        "interp_vs_direct": {"interpolated", "beta_0_2", "beta_0_8"},
        "interp_gt_scale": {"beta_0_2", "beta_0_8"},
    }
    for step, labels in expected.items():
        table = scores(settings, jobs[step])
        print(f"\n{step}: {table}")
        assert set(table) == labels
        names = {a.name for a in jobs[step].artifacts}
        assert {f"flip_{label}.png" for label in labels} <= names
        for label, row in table.items():
            assert set(row) == set(RANGES), (step, label)
            for metric, (low, high) in RANGES.items():
                value = row[metric]
                assert math.isfinite(value) and low <= value <= high, (step, label, metric)
    for material in ("seen", "unseen"):
        table = scores(settings, jobs[f"{material}_scores"])
        # Reference: the 64-spp Monte Carlo render; 6 samples converge further than 1.
        assert table["mc_eq"]["psnr"] > table["mc1"]["psnr"] + 3.0, material
        assert table["mc_eq"]["mse"] < table["mc1"]["mse"], material
        assert table["mc_eq"]["flip"] < table["mc1"]["flip"], material


def test02_interpolation_endpoints_render_the_materials(
    chain: tuple[Settings, dict[str, Job]], mitsuba_llvm: None
) -> None:
    settings, jobs = chain
    lerp = jobs["interp_lerp"].spec
    material = lerp["params"]["material"]
    a, b = material["fabric"], material["interpolate"]["fabric"]
    assert a["beta"] != b["beta"]

    def render(value: dict[str, Any]) -> bytes:
        spec = {**lerp, "params": {**lerp["params"], "material": value}}
        job = run_in_process(spec, settings)
        assert job.state == "succeeded", job.error
        return artifact(settings, job, "image.exr")

    model = material["model"]
    # Reference: the plain renders of A and B (same seed, spp and scene).
    image_a, image_b = render({"model": model, "fabric": a}), render({"model": model, "fabric": b})
    assert image_a != image_b
    at0 = render({**material, "interpolate": {"fabric": b, "t": 0.0}})
    at1 = render({**material, "interpolate": {"fabric": b, "t": 1.0}})
    assert at0 == image_a and at1 == image_b
    mid = artifact(settings, jobs["interp_lerp"], "image.exr")
    assert mid not in (image_a, image_b)


def test03_pareto_and_select_of_network_against_monte_carlo(
    chain: tuple[Settings, dict[str, Job]], mitsuba_llvm: None
) -> None:
    """The recipe's ``report.pareto``: FLIP against render seconds and spp per material,
    each point the score's own FLIP at its render's spp, and the Sec. 6 claims checked."""
    settings, jobs = chain
    doc = json.loads(artifact(settings, jobs["pareto"], "pareto.json"))
    assert {(p["metric"], p["cost"]) for p in doc["panels"]} == {
        ("image.flip", "render_seconds"),
        ("image.flip", "spp"),
    }
    for material in ("seen", "unseen"):
        table = scores(settings, jobs[f"{material}_scores"])
        ref = jobs[f"{material}_scores"].spec["params"]["reference"]
        (panel,) = [p for p in doc["panels"] if p["dataset"] == ref and p["cost"] == "spp"]
        got = {p["candidate"]: (p["mean"], p["cost"]) for p in panel["points"]}
        assert got == {
            "net16": (table["net16"]["flip"], 4),
            "net1": (table["net1"]["flip"], 1),
            "mc1": (table["mc1"]["flip"], 1),
            "mc_eq": (table["mc_eq"]["flip"], 6),
        }
        claims = [c for c in doc["claims"] if c["claim"].endswith(ref)]
        assert len(claims) == 2
        for c in claims:
            assert c["holds"] == (table["net16"]["flip"] < table[c["b"]]["flip"]), c
    ladders = json.loads(artifact(settings, jobs["select"], "select.json"))["ladders"]
    assert len(ladders) == 2
    for lad in ladders:  # the chosen rung: the cheapest by render time that meets the target
        meets = [r for r in lad["rungs"] if r["value"] <= 0.15]
        assert [r["meets"] for r in lad["rungs"]] == [r["value"] <= 0.15 for r in lad["rungs"]]
        assert lad["chosen"] == (
            min(meets, key=lambda r: r["cost"])["candidate"] if meets else None
        )


def test04_stability_of_the_network_by_pattern_and_footprint(
    chain: tuple[Settings, dict[str, Job]],
) -> None:
    """The recipe's report.stability over its one network: a cell per weave pattern and
    per footprint-size case, each from the model's own metrics.json; and a cell per method
    and material (seen, unseen) from the score steps."""
    settings, jobs = chain
    doc = json.loads(artifact(settings, jobs["stability"], "stability.json"))
    metrics = json.loads(artifact(settings, jobs["model"], "metrics.json"))
    cells = {(f["candidate"], f["family"]): f for f in doc["families"]}
    for case in metrics["footprints"]:
        cell = cells[("network", case["case"])]
        assert cell["mean"] == pytest.approx(case["rgb_rel"], rel=1e-9)
        assert cell["ratio"] == pytest.approx(case["rgb_rel"] / metrics["mean"]["rgb"]["rel"])
    for row in metrics["materials"]:
        assert cells[("network", row["pattern"])]["mean"] == pytest.approx(row["rgb"]["rel"])
    assert artifact(settings, jobs["stability"], "stability.png")[:4] == b"\x89PNG"
    # The seen and unseen scores: each method's FLIP on each, ratioed to its mean of the two.
    seen, unseen = scores(settings, jobs["seen_scores"]), scores(settings, jobs["unseen_scores"])
    for method in seen:
        pair = (seen[method]["flip"], unseen[method]["flip"])
        for label, value in zip(("seen", "unseen"), pair, strict=True):
            cell = cells[(method, label)]
            assert cell["kind"] == "score" and cell["mean"] == pytest.approx(value, rel=1e-9)
            assert cell["ratio"] == pytest.approx(2 * value / sum(pair), rel=1e-9)
