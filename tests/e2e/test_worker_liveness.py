"""Workers and their supervisor notice each other's death or stall (issue 15, B2).

- ``kill -9`` of ``matforge serve``: its workers end too (they used to go on running queued
  jobs with no server, and to compete with the next server's workers);
- a stopped (SIGSTOP) worker stalls the queue no longer: the supervisor kills it once its beat
  is older than the lease and starts another, which runs the queued job;
- stopped *pool* processes (the worker itself beats on) stall it no longer either (issue 21,
  item 6): cancelling the job blocked on them frees the worker, and a job that makes no
  progress for the stall limit is failed as stuck; either way the same worker runs the next
  job.
"""

from __future__ import annotations

import io
import os
import signal
import time
import zipfile
from collections.abc import Callable
from pathlib import Path

import httpx
import numpy as np
import pytest

from storage.formats.png import write_png

from .harness import (
    SMOKE_RENDER,
    Server,
    pid_alive,
    start_server,
    stop_server,
    worker_pids,
)

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


#: Seconds without progress before a job is stuck, in test03's server: above the first
#: shard's wait for two fresh spawned pool processes to import the importer (about 4 s on
#: a busy 2-core machine), so that only a stopped pool trips it.
STALL_SECONDS = 10.0


def _archive() -> bytes:
    """A ``.btf.zip`` of two 8 x 8 PNG slices: with ``shard_slices`` 1, two shards, so the
    worker's process pool runs them."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for k in range(2):
            zf.writestr(f"s{k}.png", write_png(None, np.full((8, 8, 3), 40 * k, np.uint8)))
        zf.writestr("angles.csv", "file,theta_i,phi_i,theta_o,phi_o\ns0.png,0,0,0,0\n"
                    "s1.png,30,0,20,90\n")  # fmt: skip
    return buf.getvalue()


def _pool_processes(worker: int) -> list[int]:
    """The worker's spawned pool processes (not its resource tracker)."""
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            args = (entry / "cmdline").read_bytes()
        except (OSError, IndexError, ValueError):
            continue
        if ppid == worker and b"spawn_main" in args:
            out.append(int(entry.name))
    return sorted(out)


def _run(http: httpx.Client, server: Server, spec: dict, want: str, timeout: float) -> dict:
    """Submit ``spec`` and poll its job until it is ``want``; its last document."""
    created = http.post("/api/jobs", json=spec)
    assert created.status_code == 201, created.text
    job_id = created.json()["id"]
    deadline = time.monotonic() + timeout
    while (doc := http.get(f"/api/jobs/{job_id}").json())["state"] != want:
        if time.monotonic() > deadline:
            pytest.fail(
                f"timed out after {timeout:.0f} s waiting for job {job_id} to be {want}; "
                f"last: {doc}\n{server.log_tail()}"
            )
        time.sleep(0.1)
    return dict(doc)


def test03_stopped_pool_processes_do_not_hold_the_worker(tmp_path: Path) -> None:
    server = start_server(
        tmp_path, workers=1, lease_seconds=LEASE_SECONDS,
        extra_env={"MATFORGE_STALL_SECONDS": str(STALL_SECONDS), "MATFORGE_POOL_PROCESSES": "2"},
    )  # fmt: skip
    stopped: set[int] = set()
    try:
        with server.http() as http:
            up = http.post("/api/artifacts?name=two.btf.zip", content=_archive())
            assert up.status_code == 201, up.text

            def spec(scale: float) -> dict:
                params = {"archive": up.json()["ref"], "shard_slices": 1, "scale": scale}
                return {"kind": "import.btf", "params": params}

            first = _run(http, server, spec(1.0), "succeeded", 90)
            worker = int(first["worker"].rpartition(":")[2])

            # 1. Cancel a job blocked on stopped pool processes: the worker is free at once.
            pool = _pool_processes(worker)
            assert pool, "the worker has no pool processes"
            for pid in pool:
                os.kill(pid, signal.SIGSTOP)
            stopped |= set(pool)
            blocked = http.post("/api/jobs", json=spec(2.0)).json()["id"]
            _wait_for(
                lambda: http.get(f"/api/jobs/{blocked}").json()["state"] == "running", 30,
                "the blocked job to start", server.log_tail(),
            )  # fmt: skip
            time.sleep(1.0)
            assert http.post(f"/api/jobs/{blocked}/cancel").json()["state"] == "cancelled"
            after = _run(http, server, spec(3.0), "succeeded", 30)
            assert after["worker"] == first["worker"], "the worker was replaced, not freed"

            # 2. No progress for STALL_SECONDS: the job fails as stuck, the worker goes on.
            pool = _pool_processes(worker)
            assert pool, "the worker has no pool processes"
            for pid in pool:
                os.kill(pid, signal.SIGSTOP)
            stopped |= set(pool)
            t0 = time.monotonic()
            stuck = _run(http, server, spec(4.0), "failed", STALL_SECONDS + 30)
            assert time.monotonic() - t0 >= STALL_SECONDS - 1
            assert stuck["error"].startswith("stuck: no progress for"), stuck["error"]
            assert "import.btf" in stuck["error"], stuck["error"]
            again = _run(http, server, spec(5.0), "succeeded", 30)
            assert again["worker"] == first["worker"]
        assert not any(pid_alive(p) for p in stopped), "stopped pool processes were left"
    finally:
        for p in stopped:
            if pid_alive(p):
                os.kill(p, signal.SIGKILL)
        leftovers = stop_server(server)
    assert leftovers == []
