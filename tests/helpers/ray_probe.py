"""A test-only kind whose shards leave a trace: which shard ran, how often, on which node.

``probe`` stores one small artifact per shard through
:meth:`~jobapi.context.JobContext.map_artifact_shards`. Its bytes depend on the seed and the
shard's index only, so any executor must give the same digests. Each call of a shard first
writes a marker file ``<index>-<node>-<uuid>`` into ``log_dir``: counting them shows which
shards an executor ran again (a retry) and where.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import Field

from jobapi.context import JobContext
from jobapi.errors import TransientError
from jobapi.kinds import Kind
from jobapi.params import StrictModel
from service.settings import Settings
from storage.artifacts import ArtifactStore
from storage.jobs import Job


class ProbeParams(StrictModel):
    """Params of the test-only ``probe`` kind."""

    n: int = Field(default=4, ge=1, le=100, description="number of shards")
    sleep: float = Field(default=0.0, ge=0.0, le=10.0, description="seconds per shard")
    log_dir: str = Field(description="directory of the marker files")
    flaky: bool = Field(default=False, description="each shard's first call fails, transiently")
    bad: bool = Field(default=False, description="every shard raises a ValueError")
    crash: bool = Field(default=False, description="every shard kills its own process")


@dataclass(frozen=True)
class ProbeItem:
    index: int
    seed: int
    sleep: float
    log_dir: str
    flaky: bool
    bad: bool
    crash: bool = False


def node_id() -> str:
    """The Ray node this process runs on, or ``"local"`` outside Ray."""
    import ray

    return ray.get_runtime_context().get_node_id() if ray.is_initialized() else "local"


def calls(log_dir: Path) -> dict[int, list[str]]:
    """Shard index -> the nodes of its calls, from the marker files."""
    out: dict[int, list[str]] = {}
    for p in sorted(log_dir.iterdir()):
        index, node, _ = p.name.split("-", 2)
        out.setdefault(int(index), []).append(node)
    return out


def probe_shard(item: ProbeItem) -> bytes:
    """Shard function: mark the call, maybe fail, sleep, return 4 KiB of seeded bytes."""
    log_dir = Path(item.log_dir)
    before = len(list(log_dir.glob(f"{item.index}-*")))
    (log_dir / f"{item.index}-{node_id()}-{uuid.uuid4().hex}").touch()
    if item.crash:
        os._exit(17)  # a segfault or an OOM kill, as the executor sees it
    if item.bad:
        raise ValueError(f"probe shard {item.index} is bad")
    if item.flaky and before == 0:
        raise TransientError(f"probe shard {item.index}: first call fails")
    time.sleep(item.sleep)
    block = hashlib.sha256(f"{item.seed}/{item.index}".encode()).digest()
    return block * 128


def run_probe(params: ProbeParams, ctx: JobContext) -> None:
    items = [
        ProbeItem(i, ctx.seed, params.sleep, params.log_dir, params.flaky, params.bad, params.crash)
        for i in range(params.n)
    ]
    ctx.map_artifact_shards(
        probe_shard, items, [f"probe-{i:03d}.bin" for i in range(params.n)], label="probe"
    )


PROBE = Kind(name="probe", params=ProbeParams, runner=run_probe, description="test-only kind")


def probe_spec(log_dir: Path, **params: Any) -> dict[str, Any]:
    """A ``probe`` spec (seed 3) whose shards mark their calls in ``log_dir``."""
    return {"kind": "probe", "seed": 3, "params": {"log_dir": str(log_dir), **params}}


def digests(job: Job, skip: frozenset[str] = frozenset()) -> dict[str, str]:
    """Artifact name -> digest, less ``skip`` (a kind's declared timing artifacts)."""
    return {a.name: a.digest for a in job.artifacts if a.name not in skip}


def manifest(settings: Settings, job: Job) -> dict[str, Any]:
    """The job's manifest, read from the store."""
    assert job.manifest_digest is not None
    return json.loads(ArtifactStore(settings.store_dir).read(job.manifest_digest))
