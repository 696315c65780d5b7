"""``scripts/select_brdf.yaml`` run through the job machinery at tiny sizes: the BRDF ladder
of issue 13 (analytic, hybrid 16x3 and 32x3 each with ``neural_max_depth`` 0 and at every
bounce, the measured table) rendered in its scene by ``select``.

The batch file is loaded and validated as ``matforge batch`` does, then every step runs in
process after shrinking: 40 training steps, no speed measurement, renders of 16x16 at 4 spp
(the reference at 64), and the ``table`` rung at the reference's own spp.

Oracles: the rungs in the recipe's order, each scored; the chosen rung recomputed from the
stored values and costs; the ``table`` rung (the truth rendered again with other seeds)
closer to the reference than any 40-step fit; each hybrid's ``neural_max_depth`` 0 rung
rendered differently from the full model (the network changes the image).
"""

from __future__ import annotations

import json
import types
from typing import Any

import numpy as np
import pytest

from service.settings import Settings
from storage.artifacts import ArtifactStore
from storage.formats.exr import read_exr
from storage.jobs import Job
from tests.helpers.recipes import artifact, run_recipe

RUNGS = ["analytic", "hybrid16_d0", "hybrid16", "hybrid32_d0", "hybrid32", "table"]
REF_SPP = 64


def shrink(spec: dict[str, Any]) -> dict[str, Any]:
    params = dict(spec["params"])
    if spec["kind"] == "train.brdf":
        params.update(steps=40, speed="off")
    if spec["kind"] == "select":
        params["scene"] = {**params["scene"], "resolution": [16, 16], "spp": 4}
        params["reference"] = {**params["reference"], "spp": REF_SPP}
        params["ladder"] = [
            {**r, "spp": REF_SPP} if r["name"] == "table" else r for r in params["ladder"]
        ]
    return {**spec, "params": params}


@pytest.fixture(scope="module")
def chain(
    tmp_path_factory: pytest.TempPathFactory, mi: types.ModuleType
) -> tuple[Settings, dict[str, Job]]:
    return run_recipe(tmp_path_factory, "select_brdf.yaml", shrink)


def image(settings: Settings, job: Job, name: str) -> np.ndarray:
    (digest,) = [a.digest for a in job.artifacts if a.name == name]
    return np.asarray(read_exr(ArtifactStore(settings.store_dir).path(digest), name), np.float32)


def test01_the_ladder_is_rendered_scored_and_chosen(chain: tuple[Settings, dict[str, Job]]) -> None:
    settings, jobs = chain
    doc = json.loads(artifact(settings, jobs["select"], "select.json"))
    (ladder,) = doc["ladders"]
    rungs = {r["candidate"]: r for r in ladder["rungs"]}
    assert set(rungs) == set(RUNGS)
    target = jobs["select"].spec["params"]["target"]
    for r in rungs.values():
        assert 0.0 <= r["value"] <= 1.0 and r["cost"] > 0 and r["meets"] == (r["value"] <= target)
    meets = [r for r in rungs.values() if r["meets"]]
    assert ladder["chosen"] == (min(meets, key=lambda r: r["cost"])["candidate"] if meets else None)
    # The table rung is the reference material itself (other seeds, same spp): only noise.
    fitted = [rungs[n]["value"] for n in RUNGS if n != "table"]
    # Measured FLIP (AMD EPYC): table 0.062, the best fit 0.31 (5x): the truth at the
    # reference's spp against 40-step fits at 4 spp, not a contest between close fits.
    assert rungs["table"]["value"] < min(fitted), rungs
    assert artifact(settings, jobs["select"], "select.png")[:4] == b"\x89PNG"


def test02_depth_zero_rungs_differ_from_the_full_hybrid(
    chain: tuple[Settings, dict[str, Job]],
) -> None:
    """``neural_max_depth`` 0 renders only the hybrid's analytic part: a different image from
    the same model at every bounce (the network's correction is visible even after 40
    steps), and a different score."""
    settings, jobs = chain
    doc = json.loads(artifact(settings, jobs["select"], "select.json"))
    rungs = {r["candidate"]: r for r in doc["ladders"][0]["rungs"]}
    for size in ("hybrid16", "hybrid32"):
        full = image(settings, jobs["select"], f"rung_{size}.exr")
        depth0 = image(settings, jobs["select"], f"rung_{size}_d0.exr")
        assert full.shape == depth0.shape == (16, 16, 3)
        assert np.abs(full - depth0).max() > 1e-3 * float(full.max()), size
        assert rungs[size]["value"] != rungs[f"{size}_d0"]["value"]
