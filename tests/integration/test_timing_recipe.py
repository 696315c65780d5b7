"""``scripts/timing_pass.yaml`` at tiny sizes: the recipe's report.pareto and select each
time the four trained models and the reference kernel in one pass of their own.

Oracles: the pass's record against the documents (every point's cost is its pass median,
its bars the pass's min and max, its ratio the pass's), the training jobs' own timings
switched off (``speed: off``) so that a cost can only come from the pass, the round-robin
order, and the front's resolution recomputed from the boxes by brute force."""

from __future__ import annotations

from typing import Any

import pytest

from service.settings import Settings
from storage.jobs import Job
from tests.helpers.manifests import measured
from tests.helpers.recipes import artifact, run_recipe

MODELS = {"analytic", "hybrid 16x2", "hybrid 32x3", "neural 32x3"}


def shrink(spec: dict[str, Any]) -> dict[str, Any]:
    params = dict(spec["params"])
    if spec["kind"] == "train.brdf":
        params.update(steps=12, batch_pairs=64, eval_pairs=2048, speed="off")
    if "timing" in params:
        params["timing"] = {**params["timing"], "repeats": 5, "batch": 2048}
    return {**spec, "params": params}


@pytest.fixture(scope="module")
def chain(tmp_path_factory: pytest.TempPathFactory) -> tuple[Settings, dict[str, Job]]:
    settings, jobs = run_recipe(tmp_path_factory, "timing_pass.yaml", shrink)
    failed = {n: j.error for n, j in jobs.items() if j.state != "succeeded"}
    assert not failed, failed
    return settings, jobs


def test01_pareto_times_every_model_in_one_pass(chain: tuple[Settings, dict[str, Job]]) -> None:
    import json

    settings, jobs = chain
    for name in ("analytic", "hybrid16"):  # the training jobs did not time themselves
        assert "speed" not in measured(settings, jobs[name])
    doc = json.loads(artifact(settings, jobs["pareto"], "pareto.json"))
    timing = doc["timing"]
    assert set(timing["costs"]) == MODELS | {"reference"}
    assert timing["reference"] == "reference" and timing["settings"]["batch"] == 2048
    assert timing["settings"]["reference_bsdf"]["type"] == "roughconductor"
    assert (
        len(timing["order"]) == 5 and [r[0] for r in timing["order"]] != [timing["order"][0][0]] * 5
    )  # the first kernel rotates
    (panel,) = doc["panels"]
    assert panel["timing_pass"] is True and {p["candidate"] for p in panel["points"]} == MODELS
    for p in panel["points"]:
        c = timing["costs"][p["candidate"]]
        assert p["cost"] == c["distribution"]["median"] and p["cost_n"] == 5
        assert (p["cost_min"], p["cost_max"]) == (
            c["distribution"]["min"],
            c["distribution"]["max"],
        )
        assert p["relative"] == {k: c["relative"][k] for k in ("median", "min", "max", "iqr", "n")}
        assert p["runtime"] == "drjit-fused"
    # resolution by brute force over the boxes (one seed each: no error spread)
    pts = panel["points"]
    for p in pts:
        others = [q for q in pts if q is not p]
        maybe = [q["candidate"] for q in others
                 if q["cost_min"] <= p["cost_max"] and q["mean"] <= p["mean"]]  # fmt: skip
        sure = [q for q in others if q["cost_max"] <= p["cost_min"] and q["mean"] <= p["mean"]
                and (q["cost_max"] < p["cost_min"] or q["mean"] < p["mean"])]  # fmt: skip
        expect = maybe if p["front"] or not sure else []
        assert p["tied_with"] == expect and p["resolved"] == (not expect)
    assert panel["resolved"] == all(p["resolved"] for p in pts)


def test02_select_times_its_rungs(chain: tuple[Settings, dict[str, Job]]) -> None:
    import json

    settings, jobs = chain
    doc = json.loads(artifact(settings, jobs["select"], "select.json"))
    assert set(doc["timing"]["costs"]) == MODELS | {"reference"}
    (lad,) = doc["ladders"]
    assert [r["cost"] for r in lad["rungs"]] == sorted(r["cost"] for r in lad["rungs"])
    assert isinstance(lad["resolved"], bool) and (lad["tie"] == []) == lad["resolved"]
    if not lad["resolved"]:
        assert "not resolved" in lad["why"]
