"""A real ``matforge serve`` on 127.0.0.1 for the server benchmarks (submissions, hostile
specs, upload attacks): a free port, a temporary data directory, no workers, the caller's
environment less its ``MATFORGE_*`` settings (plus ``env_extra``), and the process group
ended on exit. Not a benchmark itself; the ``bench_*`` scripts import it."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import httpx


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass(frozen=True)
class Served:
    """A running server: its base URL, process (the group leader) and data directory."""

    url: str
    proc: subprocess.Popen[bytes]
    data_dir: str


@contextmanager
def served(
    *,
    http_workers: int = 1,
    env_extra: dict[str, str] | None = None,
    timeout: float = 60.0,
    cpus: str | None = None,
    workers: int = 0,
    log_path: str | None = None,
) -> Iterator[Served]:
    """``matforge serve --workers N`` (default 0) until ``/api/health`` answers 200 (``SystemExit``
    after ``timeout`` seconds); SIGTERM to its process group on exit. ``cpus``: a
    ``taskset -c`` CPU list the server (and every process it starts) is pinned to;
    ``log_path``: where its output goes (default: discarded)."""
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    env = {k: v for k, v in os.environ.items() if not k.startswith("MATFORGE_")}
    env.update(env_extra or {})
    exe = os.path.join(os.path.dirname(sys.executable), "matforge")
    with tempfile.TemporaryDirectory(prefix="bench-serve-") as data:
        args = [exe, "serve", "--host", "127.0.0.1", "--port", str(port), "--workers", str(workers),
                "--http-workers", str(http_workers), "--data-dir", data]  # fmt: skip
        if cpus is not None:
            args = ["taskset", "-c", cpus, *args]  # taskset execs: the pid is the server's
        out = open(log_path, "wb") if log_path else subprocess.DEVNULL  # noqa: SIM115
        proc = subprocess.Popen(
            args, env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True
        )
        try:
            deadline = time.monotonic() + timeout
            while True:
                try:
                    if httpx.get(f"{url}/api/health", timeout=1).status_code == 200:
                        break
                except httpx.TransportError:
                    pass
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise SystemExit(f"matforge serve did not start in {timeout:g} s")
                time.sleep(0.2)
            yield Served(url, proc, data)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGTERM)
                try:
                    proc.wait(60)
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, signal.SIGKILL)
            if not isinstance(out, int):
                out.close()
