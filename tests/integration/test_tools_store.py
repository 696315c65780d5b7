"""``tools/store.py``: the diagnostics find jobs and artifacts through ``JobStore`` (the
reference: the jobs the worker ran, and the bytes it stored)."""

from __future__ import annotations

import json

import pytest

from service.submission import submit
from service.workers.worker import run_worker
from tools.store import latest_artifact, open_data_dir, succeeded


def test01_succeeded_jobs_oldest_first_and_the_latest_artifact(
    toy_kind, settings, jobs, store
) -> None:
    ids = []
    for n in (2, 3):
        job, _ = submit({"kind": "toy", "params": {"n": n}}, jobs, store)
        ids.append(job.id)
    assert run_worker(settings, max_jobs=2) == 2
    queue, objects = open_data_dir(settings.data_dir)
    found = succeeded(queue, "toy")
    assert [j.id for j in found] == ids and all(j.artifacts for j in found)
    newest = json.loads(latest_artifact(queue, objects, "toy", "result.json"))
    assert newest["squares"] == [0, 1, 4]
    with pytest.raises(SystemExit, match="no finished toy job with nope.json"):
        latest_artifact(queue, objects, "toy", "nope.json")
    with pytest.raises(SystemExit, match="not a matforge data directory"):
        open_data_dir(settings.data_dir / "elsewhere")
