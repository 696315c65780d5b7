"""A worker killed mid-job: the supervisor replaces it, the lease runs out, the job is
queued again and the next attempt succeeds with intact artifacts; and ``matforge serve``
leaves no process behind when stopped."""

from __future__ import annotations

import hashlib
import os
import signal
import time
from pathlib import Path
from typing import Any

import httpx
import pytest

from .harness import (
    SMOKE_RENDER,
    Server,
    base_env,
    pid_alive,
    run_cli,
    start_server,
    stop_server,
    worker_pids,
)

pytestmark = pytest.mark.slow

LEASE_SECONDS = 2.0
#: A render of 8 passes of 2^22 paths (256 x 256 x 512 spp), so that after its first pass
#: has reported progress the worker can be killed with passes still to run.
SLOW_RENDER: dict[str, Any] = {
    "kind": "render",
    "seed": 7,
    "name": "crash-test",
    "params": {**SMOKE_RENDER["params"], "resolution": [256, 256], "spp": 512},
}


def poll(
    http: httpx.Client,
    job_id: str,
    until: Any,
    timeout: float,
    what: str,
    seen: list[dict[str, Any]],
) -> dict[str, Any]:
    """Poll a job every 0.1 s until ``until(doc)``; every document seen is appended."""
    deadline = time.monotonic() + timeout
    while True:
        doc: dict[str, Any] = http.get(f"/api/jobs/{job_id}").json()
        seen.append(doc)
        if until(doc):
            return doc
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout:.0f} s waiting for {what}; last: {doc}")
        time.sleep(0.1)


def test01_sigkilled_worker_job_is_requeued_and_succeeds(tmp_path: Path) -> None:
    server: Server = start_server(tmp_path, lease_seconds=LEASE_SECONDS, workers=1)
    killed: set[int] = set()
    leftovers: list[int] = []
    try:
        with server.http() as http:
            created = http.post("/api/jobs", json=SLOW_RENDER)
            assert created.status_code == 201, created.text
            job_id = created.json()["id"]
            seen: list[dict[str, Any]] = []

            # the real signal that the render is under way and not about to end: a pass has
            # reported its progress ("pass i/n: done/spp spp") and passes remain
            running = poll(
                http,
                job_id,
                lambda d: (
                    d["state"] == "running"
                    and d["worker"]
                    and (d["message"] or "").startswith("pass ")
                    and 0.02 < d["progress"] < 0.9
                ),
                120,
                "the render's first pass",
                seen,
            )
            assert running["attempts"] == 1
            host, _, pid_text = running["worker"].rpartition(":")
            pid = int(pid_text)
            # only ever kill a worker of this server
            assert pid in worker_pids(server.data_dir), (running, server.log_tail())
            os.kill(pid, signal.SIGKILL)  # mid-render: passes remain
            killed.add(pid)
            after_kill = http.get(f"/api/jobs/{job_id}").json()
            assert after_kill["state"] == "running", (
                f"the job finished before its worker was killed (make SLOW_RENDER slower): "
                f"{after_kill}"
            )

            # the supervisor starts a replacement worker
            deadline = time.monotonic() + 30
            while not (set(worker_pids(server.data_dir)) - killed):
                assert time.monotonic() < deadline, f"no new worker:\n{server.log_tail()}"
                time.sleep(0.1)
            assert not pid_alive(pid)

            # the lease runs out, the job is queued again and a second attempt succeeds
            final = poll(
                http,
                job_id,
                lambda d: d["state"] in ("succeeded", "failed", "cancelled"),
                180,
                "the second attempt to finish",
                seen,
            )
            assert final["state"] == "succeeded", (final, server.log_tail())
            assert final["attempts"] == 2, "the job was not re-queued after the kill"
            assert final["worker"] != running["worker"]
            second = next(d for d in seen if d["attempts"] == 2)
            assert second["state"] in ("running", "succeeded")

            # the artifacts verify: REST bytes hash to their digests, the store is intact
            assert {"image.exr", "preview.png"} <= {a["name"] for a in final["artifacts"]}
            for art in final["artifacts"]:
                data = http.get(f"/api/artifacts/{art['digest']}").content
                assert hashlib.sha256(data).hexdigest() == art["digest"]
                assert len(data) == art["size"]
        verify = run_cli(
            "store", "verify", "--data-dir", str(server.data_dir), "--json", env=base_env()
        )
        assert verify.returncode == 0, verify
        assert verify.json()["ok"] is True
    finally:
        leftovers = stop_server(server, sessions=killed)
    # a clean shutdown: no worker (or a worker's pool process) outlives the server
    assert leftovers == [], f"left behind: {leftovers}\n{server.log_tail()}"
