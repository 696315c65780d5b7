"""Job and artifact records: the rows of the queue as plain, immutable values."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Literal

STATES = ("queued", "running", "succeeded", "failed", "cancelled")
FINAL_STATES = frozenset({"succeeded", "failed", "cancelled"})
HeartbeatStatus = Literal["ok", "cancelled", "lost"]


@dataclass(frozen=True)
class ArtifactRecord:
    """One artifact of a job: ``digest`` is 64 lowercase hex (no prefix)."""

    name: str
    digest: str
    size: int
    media_type: str

    def public(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "digest": self.digest,
            "size": self.size,
            "media_type": self.media_type,
        }


@dataclass(frozen=True)
class Job:
    """A row of the queue, with its artifacts when the job succeeded."""

    id: str
    kind: str
    name: str | None
    seed: int
    spec_hash: str
    spec: dict[str, Any]
    state: str
    progress: float
    message: str
    error: str | None
    worker: str | None
    attempts: int
    lease_token: str | None
    lease_expires: float | None
    created_at: float
    started_at: float | None
    finished_at: float | None
    updated_at: float
    manifest_digest: str | None
    artifacts: list[ArtifactRecord] = field(default_factory=list)
    tags: tuple[str, ...] = ()

    @property
    def finished(self) -> bool:
        return self.state in FINAL_STATES

    def document(self) -> dict[str, Any]:
        """The public job document (the body of ``GET /api/jobs/{id}``)."""
        run_s = None
        if self.started_at is not None:
            run_s = (self.finished_at or time.time()) - self.started_at
        return {
            "id": self.id,
            "kind": self.kind,
            "name": self.name,
            "batch": self.spec.get("batch") if isinstance(self.spec, dict) else None,
            "state": self.state,
            "progress": self.progress,
            "message": self.message,
            "error": self.error,
            "worker": self.worker,
            "attempts": self.attempts,
            "seed": self.seed,
            "spec_hash": self.spec_hash,
            "created_at": _iso(self.created_at),
            "started_at": _iso(self.started_at),
            "finished_at": _iso(self.finished_at),
            "timings": {
                "queued_seconds": (
                    (self.started_at or self.finished_at or time.time()) - self.created_at
                ),
                "run_seconds": run_s,
            },
            "spec": self.spec,
            "manifest": f"sha256:{self.manifest_digest}" if self.manifest_digest else None,
            "artifacts": [a.public() for a in self.artifacts],
            "tags": list(self.tags),
        }


def _iso(t: float | None) -> str | None:
    if t is None:
        return None
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(t)) + f".{int(t % 1 * 1000):03d}Z"
