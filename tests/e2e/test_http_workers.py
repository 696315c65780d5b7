"""``matforge serve --http-workers N`` (issue 15, B8): several web processes on one port.

- every submission of a concurrent burst is answered and queued exactly once (the writers
  of both processes serialise on the store's cross-process write lock);
- the extra process really serves: with the first one stopped (SIGSTOP), a new connection
  is still answered;
- it ends when the server is SIGKILLed, like the job workers (B2).
"""

from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest

from .harness import SMOKE_RENDER, pid_alive, start_server, stop_server

pytestmark = pytest.mark.slow


def _wait_for(cond: Callable[[], bool], timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(0.1)


def _children(pid: int) -> list[int]:
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            cmd = (d / "cmdline").read_bytes()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        if ppid == pid and b"spawn_main" in cmd and b"resource_tracker" not in cmd:
            out.append(int(d.name))
    return out


def test01_two_web_processes_serve_one_port(tmp_path: Path) -> None:
    server = start_server(tmp_path, workers=0, http_workers=2)
    extra: list[int] = []
    try:
        _wait_for(lambda: len(_children(server.proc.pid)) == 1, 30, "the second web process")
        extra = _children(server.proc.pid)
        codes: list[int] = []
        lock = threading.Lock()

        def client(c: int) -> None:
            with httpx.Client(base_url=server.url, timeout=60) as http:
                for i in range(5):
                    spec = {**SMOKE_RENDER, "seed": 1000 * c + i}
                    r = http.post("/api/jobs", json=spec)
                    with lock:
                        codes.append(r.status_code)

        threads = [threading.Thread(target=client, args=(c,)) for c in range(8)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert codes == [201] * 40
        r = httpx.get(f"{server.url}/api/jobs", params={"limit": 100})
        assert r.headers["X-Total-Count"] == "40"
        assert len({j["id"] for j in r.json()}) == 40

        # The first process stopped: a fresh connection is answered by the other one.
        os.kill(server.proc.pid, signal.SIGSTOP)
        try:
            r = httpx.get(f"{server.url}/api/health", timeout=20)
            assert r.status_code == 200
        finally:
            os.kill(server.proc.pid, signal.SIGCONT)

        os.kill(server.proc.pid, signal.SIGKILL)
        server.proc.wait(timeout=10)
        _wait_for(lambda: not any(pid_alive(p) for p in extra), 10, f"web process {extra} to end")
    finally:
        leftovers = stop_server(server, sessions={server.proc.pid})
        for p in extra:
            if pid_alive(p):
                os.kill(p, signal.SIGKILL)
    assert leftovers == []
