"""A submission answered 201 is in the job store, whatever happens to the server next.

The web process queues a spec in one committed SQLite transaction (WAL) before it answers,
so a job whose 201 a client received survives the server being killed (SIGKILL, no
shutdown) the moment the last answer arrives. Reference: the store read back by a fresh
process after the kill, against the ids the clients were given. Both submission paths are
sent: small specs (parsed, validated and queued in one worker thread) and a spec over
``SMALL_BYTES`` (parsed in the parse thread, queued in the pool).
"""

from __future__ import annotations

import json
import os
import signal
import threading
from pathlib import Path

import httpx
import pytest

from service.parse_threads import SMALL_BYTES
from storage.jobs import JobStore

from .harness import SMOKE_RENDER, start_server, stop_server

pytestmark = pytest.mark.slow


def test01_answered_jobs_survive_a_killed_server(tmp_path: Path) -> None:
    server = start_server(tmp_path, workers=0)
    answered: list[str] = []
    codes: list[int] = []
    lock = threading.Lock()
    try:

        def client(c: int) -> None:
            with httpx.Client(base_url=server.url, timeout=60) as http:
                for i in range(6):
                    r = http.post("/api/jobs", json={**SMOKE_RENDER, "seed": 100 * c + i})
                    with lock:
                        codes.append(r.status_code)
                        if r.status_code == 201:
                            answered.append(r.json()["id"])

        threads = [threading.Thread(target=client, args=(c,)) for c in range(6)]
        for t in threads:
            t.start()
        # A large spec (padded past SMALL_BYTES with JSON whitespace) takes the other path.
        body = json.dumps({**SMOKE_RENDER, "seed": 99999}) + " " * (SMALL_BYTES + 1)
        r = httpx.post(
            f"{server.url}/api/jobs",
            content=body,
            headers={"content-type": "application/json"},
            timeout=60,
        )
        assert r.status_code == 201, r.text
        for t in threads:
            t.join()
        os.killpg(server.proc.pid, signal.SIGKILL)  # no shutdown, no checkpoint
        server.proc.wait(timeout=10)
        large = r.json()["id"]
    finally:
        leftovers = stop_server(server)
    assert codes == [201] * 36
    jobs = JobStore(server.data_dir / "jobs.sqlite3")  # this process: reads the WAL back
    for job_id in [*answered, large]:
        job = jobs.get(job_id)
        assert job.state == "queued", job
    assert jobs.counts()["queued"] == 37
    assert jobs.get(large).seed == 99999
    assert leftovers == []
