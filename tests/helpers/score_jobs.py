"""A ``score`` job run in this process, and its ``metrics.json``."""

from __future__ import annotations

import json
from typing import Any

from service.settings import Settings
from service.submission import run_in_process
from storage.artifacts import ArtifactStore
from storage.jobs import Job


def run_score(params: dict[str, Any], settings: Settings) -> Job:
    """A ``score`` job of ``params`` (seed 0), run in this process."""
    return run_in_process({"kind": "score", "seed": 0, "params": params}, settings)


def metrics_json(job: Job, store: ArtifactStore) -> Any:
    """The ``metrics.json`` of a job that must have succeeded."""
    assert job.state == "succeeded", job.error
    art = next(a for a in job.artifacts if a.name == "metrics.json")
    return json.loads(store.read(art.digest))
