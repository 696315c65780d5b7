"""What a job's manifest says beyond its artifacts (for tests)."""

from __future__ import annotations

import json
from typing import Any

from service.settings import Settings
from storage.artifacts import ArtifactStore
from storage.jobs import Job


def measured(settings: Settings, job: Job) -> dict[str, Any]:
    """The manifest's ``timings.measured``: what the kind timed itself (not artifacts)."""
    manifest = json.loads(ArtifactStore(settings.store_dir).read(job.manifest_digest))
    return dict(manifest["timings"]["measured"])


def speed_of(settings: Settings, job: Job) -> dict[str, Any]:
    """A ``train.brdf`` job's speed document (``timings.measured.speed``)."""
    return dict(measured(settings, job)["speed"])
