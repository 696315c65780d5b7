"""Workers and their supervisor notice each other's death or stall (issue 15, B2).

- ``kill -9`` of ``matforge serve``: its workers end too (they used to go on running queued
  jobs with no server, and to compete with the next server's workers);
- a stopped (SIGSTOP) worker stalls the queue no longer: the supervisor kills it once its beat
  is older than the lease and starts another, which runs the queued job.
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from .harness import SMOKE_RENDER, pid_alive, start_server, stop_server, worker_pids

pytestmark = pytest.mark.slow

LEASE_SECONDS = 2.0


def _wait_for(cond: Callable[[], bool], timeout: float, what: str, log: str = "") -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout:.0f} s waiting for {what}\n{log}")
        time.sleep(0.1)


def test01_workers_end_when_the_server_is_sigkilled(tmp_path: Path) -> None:
    server = start_server(tmp_path, workers=2)
    pids: list[int] = []
    try:
        _wait_for(lambda: len(worker_pids(server.data_dir)) == 2, 30, "two workers")
        pids = worker_pids(server.data_dir)
        os.kill(server.proc.pid, signal.SIGKILL)
        server.proc.wait(timeout=10)
        _wait_for(
            lambda: not any(pid_alive(p) for p in pids),
            10,
            f"workers {pids} to end after their server was killed",
            server.log_tail(),
        )
        assert "its supervisor" in server.log_path.read_text(errors="replace")
    finally:
        leftovers = stop_server(server, sessions=set(pids))
    assert leftovers == []


def test02_a_stopped_worker_is_killed_and_replaced(tmp_path: Path) -> None:
    server = start_server(tmp_path, workers=1, lease_seconds=LEASE_SECONDS)
    stopped: set[int] = set()
    try:
        _wait_for(lambda: len(worker_pids(server.data_dir)) == 1, 30, "a worker")
        pid = worker_pids(server.data_dir)[0]
        beats = server.data_dir / "workers"
        _wait_for(lambda: any(beats.glob(f"*-{pid}.beat")), 30, "the worker's first beat")
        os.kill(pid, signal.SIGSTOP)
        stopped.add(pid)
        with server.http() as http:
            created = http.post("/api/jobs", json=SMOKE_RENDER)
            assert created.status_code == 201, created.text
            job_id = created.json()["id"]
            _wait_for(
                lambda: not pid_alive(pid), 20, "the stopped worker to be killed", server.log_tail()
            )
            _wait_for(
                lambda: http.get(f"/api/jobs/{job_id}").json()["state"] == "succeeded",
                120,
                "the queued job to run on a new worker",
                server.log_tail(),
            )
        assert "has not beaten" in server.log_path.read_text(errors="replace")
    finally:
        for p in stopped:
            if pid_alive(p):
                os.kill(p, signal.SIGCONT)
        leftovers = stop_server(server, sessions=stopped)
    assert leftovers == []
