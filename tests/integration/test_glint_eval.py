"""``scripts/glint_eval.yaml`` run through the job machinery at tiny sizes.

The batch file is loaded and validated as ``matforge batch`` does, then two of its example
types (scratches, structured) and the brushed-metal glint ladder (smooth GGX, tiny examples
8 / 16 / 32, Yan; its ``report.pareto`` and ``select``) run through
:func:`service.submission.run_in_process` with their ``step:`` refs resolved, after
shrinking: NDF images of 16 cells, renders of 32x24 at 4 (rungs) and 16 (reference) spp, 128
texels per uv.

Oracles: every metric is finite and in its range, the documented artifacts exist, and the
tiny-example render is closer to its own reference than to the other type's reference
(PSNR and SSIM), i.e. the scores see the microstructure. For the ladder: each rung's memory
in the result rows against the generate jobs' own ``stats.json`` and the export's size
(2 x 2 32-byte lobes per texel), the Pareto front by brute force over the score's own
``metrics.json`` and those bytes, and ``select``'s choice recomputed from the same numbers
(the cheapest rung within the target), at the recipe's target and at one between the rungs.
"""

from __future__ import annotations

import dataclasses
import json
import math
import types
from collections.abc import Iterable
from typing import Any

import pytest

from service.cli.batch import Step
from service.results import RowFilter, select_rows
from service.settings import Settings
from service.submission import run_in_process
from storage.artifacts import ArtifactStore
from storage.jobs import Job, JobStore
from tests.helpers.recipes import run_recipe
from tests.helpers.renders import own_render_seconds

TYPES = ("scratches", "structured")
#: The ladder's steps all start with this; its rungs (score candidates) and their renders.
LADDER = "brushed_metal"
RUNGS = {
    "smooth_ggx": "brushed_metal_smooth",
    "tiny8": "brushed_metal_tiny8",
    "tiny16": "brushed_metal_tiny16",
    "tiny32": "brushed_metal_tiny",
    "yan": "brushed_metal_yan64",
}
#: The glint data job behind each tiny rung.
DATA = {"tiny8": "brushed_metal_8", "tiny16": "brushed_metal_16", "tiny32": "brushed_metal"}
#: Texels per uv of the shrunk renders; Yan exports one texel per example texel.
TEXELS = 128
LOBE_BYTES = 32
#: ``yan_rate`` of the recipe's Yan reference (2 x 2 lobes per texel, as fine as the model).
YAN_RATE = 2


def shrink(spec: dict[str, Any]) -> dict[str, Any]:
    params = dict(spec["params"])
    if spec["kind"] == "generate.glint":
        params["ndf_resolution"] = 16
    if spec["kind"] == "render":
        params.update(resolution=[32, 24], spp=4 if params["spp"] <= 64 else 16)
        material = dict(params["material"]["glint"])
        material["texels_per_uv"] = TEXELS
        params["material"] = {"glint": material}
    return {**spec, "params": params}


@pytest.fixture(scope="module")
def chain(
    tmp_path_factory: pytest.TempPathFactory, mi: types.ModuleType
) -> tuple[Settings, dict[str, Job]]:

    def keep(steps: Iterable[Step]) -> list[Step]:
        steps = list(steps)
        assert [s.name for s in steps][:4] == [
            "scratches", "scratches_tiny", "scratches_yan", "scratches_score",
        ]  # fmt: skip
        kept = [s for s in steps if s.name.startswith((*TYPES, LADDER))]
        # the recipe's stability step over the kept types' scores only
        (stab,) = [s for s in steps if s.name == "stability"]
        params = {**stab.spec["params"], "runs": [f"step:{t}_score" for t in TYPES],
                  "labels": list(TYPES)}  # fmt: skip
        return [*kept, dataclasses.replace(stab, spec={**stab.spec, "params": params})]

    return run_recipe(tmp_path_factory, "glint_eval.yaml", shrink, keep)


def _read(settings: Settings, job: Job, name: str) -> Any:
    (digest,) = [a.digest for a in job.artifacts if a.name == name]
    return json.loads(ArtifactStore(settings.store_dir).read(digest))


def _metrics(settings: Settings, job: Job) -> dict[str, float]:
    return _read(settings, job, "metrics.json")["metrics"]["tiny"]


def _rung_costs(settings: Settings, jobs: dict[str, Job]) -> dict[str, tuple[float, float]]:
    """Per rung: (FLIP from the score's metrics.json, bytes from first principles)."""
    flips = _read(settings, jobs["brushed_metal_ladder"], "metrics.json")["metrics"]
    rate = YAN_RATE  # the recipe's Yan: rate x rate lobes per exported texel
    nbytes = {"smooth_ggx": 8.0, "yan": float(TEXELS * TEXELS * rate * rate * LOBE_BYTES)}
    for rung, step in DATA.items():
        stats = _read(settings, jobs[step], "stats.json")
        nbytes[rung] = float(stats["bytes"]["total"])
    return {r: (float(flips[r]["flip"]), nbytes[r]) for r in RUNGS}


def test01_recipe_runs_and_scores(chain: tuple[Settings, dict[str, Job]]) -> None:
    settings, jobs = chain
    for kind in TYPES:
        m = _metrics(settings, jobs[f"{kind}_score"])
        assert 0.0 <= m["flip"] <= 1.0 and -1.0 <= m["ssim"] <= 1.0
        assert math.isfinite(m["psnr"]) and m["psnr"] > 0.0
        names = {a.name for a in jobs[f"{kind}_score"].artifacts}
        assert names == {"metrics.json", "flip_tiny.png"}


def test02_scores_see_the_microstructure(chain: tuple[Settings, dict[str, Job]]) -> None:
    """Each tiny render against the other type's reference scores worse than against its
    own."""
    settings, jobs = chain
    own = {k: _metrics(settings, jobs[f"{k}_score"]) for k in TYPES}
    a, b = TYPES
    cross = run_in_process(
        {
            "kind": "score",
            "params": {
                "reference": f"job:{jobs[f'{b}_yan'].id}/image.exr",
                "candidates": {"tiny": f"job:{jobs[f'{a}_tiny'].id}/image.exr"},
                "metrics": ["psnr", "ssim"],
            },
        },
        settings,
    )
    assert cross.state == "succeeded", cross.error
    c = _metrics(settings, cross)
    # PSNR and SSIM; HDR-FLIP on 32x24 frames of 4 spp is dominated by noise and
    # the reference's exposure range, so it is only range-checked here.
    assert c["psnr"] < own[a]["psnr"] - 3.0 and c["ssim"] < own[a]["ssim"], (c, own[a])


def test03_ladder_rows_carry_memory(chain: tuple[Settings, dict[str, Job]]) -> None:
    """The ladder score's rows: each rung's render seconds, spp, method and bytes."""
    settings, jobs = chain
    # The crops are the 32x32 example's own texels: same seed, same procedural bytes.
    sizes = {s: _read(settings, jobs[s], "stats.json")["example"] for s in DATA.values()}
    assert [sizes[DATA[r]]["size"] for r in ("tiny8", "tiny16", "tiny32")] == [8, 16, 32]
    assert sizes["brushed_metal_8"]["cropped_from"] == 32
    rows = select_rows(
        JobStore(settings.db_path),
        ArtifactStore(settings.store_dir),
        job_ids=[jobs["brushed_metal_ladder"].id],
        where=RowFilter(metric=["flip"]),
    )
    costs = _rung_costs(settings, jobs)
    assert sorted(str(r.candidate) for r in rows) == sorted(RUNGS)  # stored order: sorted
    for row in rows:
        render = jobs[RUNGS[str(row.candidate)]]
        assert row.value == pytest.approx(costs[str(row.candidate)][0])
        assert row.bytes_per_material == costs[str(row.candidate)][1]
        assert render.started_at is not None and render.finished_at is not None
        own = own_render_seconds(ArtifactStore(settings.store_dir), render)
        assert row.render_seconds == pytest.approx(own)  # the render's own time
        assert 0 < own < render.finished_at - render.started_at
        assert row.spp == 4 and row.scene == "bent_quad"
        assert row.config["method"] == render.spec["params"]["material"]["glint"]["method"]
    by = {r.candidate: r for r in rows}
    assert [by[r].config["example"] for r in ("tiny8", "tiny16", "tiny32")] == [8, 16, 32]


def _front(points: dict[str, tuple[float, float]]) -> set[str]:
    """Brute force: points (cost, error) that no other point beats on both, strictly on
    one."""
    return {
        a
        for a, (ca, ea) in points.items()
        if not any(
            cb <= ca and eb <= ea and (cb < ca or eb < ea)
            for b, (cb, eb) in points.items()
            if b != a
        )
    }


def test04_pareto_against_time_and_memory(chain: tuple[Settings, dict[str, Job]]) -> None:
    settings, jobs = chain
    doc = _read(settings, jobs["brushed_metal_pareto"], "pareto.json")
    panels = {p["cost"]: p for p in doc["panels"]}
    assert set(panels) == {"render_seconds", "bytes_per_material"}
    costs = _rung_costs(settings, jobs)
    objects = ArtifactStore(settings.store_dir)
    seconds = {r: own_render_seconds(objects, jobs[s]) for r, s in RUNGS.items()}
    for cost, of in (
        ("bytes_per_material", {r: (b, f) for r, (f, b) in costs.items()}),
        ("render_seconds", {r: (seconds[r], f) for r, (f, _) in costs.items()}),
    ):
        points = {p["candidate"]: p for p in panels[cost]["points"]}
        assert set(points) == set(RUNGS)
        for rung, (c, e) in of.items():
            assert points[rung]["cost"] == pytest.approx(c)
            assert points[rung]["mean"] == pytest.approx(e)
        assert set(panels[cost]["front"]) == _front(of), cost
    claims = {c["a"] + "<" + c["b"]: c for c in doc["claims"]}
    for key in ("tiny32<tiny8", "tiny32<smooth_ggx"):
        a, b = key.split("<")
        assert claims[key]["holds"] == (costs[a][0] < costs[b][0])
    names = {a.name for a in jobs["brushed_metal_pareto"].artifacts}
    assert {"pareto.json", "pareto.png", "rows.json"} <= names


def _cheapest(costs: dict[str, tuple[float, float]], target: float) -> str | None:
    meeting = [(b, r) for r, (f, b) in costs.items() if f <= target]
    return min(meeting)[1] if meeting else None


def test05_select_the_cheapest_rung_within_the_target(
    chain: tuple[Settings, dict[str, Job]],
) -> None:
    settings, jobs = chain
    costs = _rung_costs(settings, jobs)
    doc = _read(settings, jobs["brushed_metal_select"], "select.json")
    (ladder,) = doc["ladders"]
    assert (doc["metric"], doc["cost"]) == ("flip", "bytes_per_material")
    assert ladder["chosen"] == _cheapest(costs, doc["target"])
    assert [r["candidate"] for r in ladder["rungs"]] == sorted(RUNGS, key=lambda r: costs[r][1])
    # A target between the rungs' errors: met by some rungs and not by others, so the choice
    # is neither the cheapest rung nor none (unless the tiny renders' noise orders them so).
    flips = sorted(f for f, _ in costs.values())
    target = 0.5 * (flips[1] + flips[2])
    job = run_in_process(
        {
            "kind": "select",
            "params": {
                "runs": [f"job:{jobs['brushed_metal_ladder'].id}"],
                "metric": "flip",
                "target": target,
                "cost": "bytes_per_material",
            },
        },
        settings,
    )
    assert job.state == "succeeded", job.error
    (ladder,) = _read(settings, job, "select.json")["ladders"]
    assert ladder["chosen"] == _cheapest(costs, target) is not None
    assert [r["meets"] for r in ladder["rungs"]].count(True) == 2


def test06_stability_per_example_type(chain: tuple[Settings, dict[str, Job]]) -> None:
    """The recipe's report.stability over the per-type scores: the tiny model's FLIP per
    example type (a family each), ratioed to its mean over the types, from the scores' own
    metrics.json."""
    settings, jobs = chain
    doc = _read(settings, jobs["stability"], "stability.json")
    flips = {t: _metrics(settings, jobs[f"{t}_score"])["flip"] for t in TYPES}
    mean = sum(flips.values()) / len(flips)
    cells = {f["family"]: f for f in doc["families"]}
    assert set(cells) == set(TYPES)
    for t, cell in cells.items():
        assert (
            cell["kind"] == "score"
            and cell["candidate"] == "tiny"
            and cell["metric"] == "image.flip"
        )
        assert cell["mean"] == pytest.approx(flips[t], rel=1e-9)
        assert cell["ratio"] == pytest.approx(flips[t] / mean, rel=1e-9)
    assert [r["label"] for r in doc["runs"]] == list(TYPES)
    assert all(r["convergence"]["flattened"] is None for r in doc["runs"])
