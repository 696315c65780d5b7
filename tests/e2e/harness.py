"""End-to-end harness: a real ``matforge serve`` on a free loopback port, driven through the
``matforge`` console script (subprocesses) and REST (httpx).

The server runs in its own session (process group). Workers are started by the supervisor
in sessions of their own, so stopping the server group alone could leave one behind:
:func:`stop_server` sends SIGTERM, waits, escalates to SIGKILL, and then kills (by pid) any
``service.workers.worker`` process still running on this server's data directory, reporting them.
"""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest

REPO = Path(__file__).resolve().parents[2]
START_TIMEOUT_S = 60.0

#: The smoke render of the contract's examples: tiny and quick.
SMOKE_RENDER: dict[str, Any] = {
    "kind": "render",
    "params": {
        "scene": "sphere_env",
        "material": {"mitsuba": {"type": "diffuse"}},
        "resolution": [32, 32],
        "spp": 4,
    },
}


def matforge_exe() -> str:
    """The ``matforge`` console script of the venv running the tests."""
    beside = Path(sys.executable).parent / "matforge"
    return str(beside if beside.exists() else REPO / ".venv" / "bin" / "matforge")


def base_env(**extra: str) -> dict[str, str]:
    """The test process's environment without any MATFORGE_* variable, plus ``extra``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("MATFORGE_")}
    env.update(extra)
    return env


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def closed_port_url() -> str:
    """The URL of a loopback port nothing listens on (connection refused)."""
    return f"http://127.0.0.1:{free_port()}"


def worker_pids(data_dir: Path) -> list[int]:
    """Pids of ``python -m service.workers.worker`` processes working on ``data_dir``."""
    pids = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            args = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"service.workers.worker" in args and str(data_dir).encode() in args:
            pids.append(int(entry.name))
    return sorted(pids)


def _stat_fields(pid: int) -> list[str] | None:
    """Fields of ``/proc/<pid>/stat`` after the command name (state first), or ``None``."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return stat.rsplit(")", 1)[1].split()


def pid_alive(pid: int) -> bool:
    """Whether ``pid`` is a live process (zombies count as dead)."""
    fields = _stat_fields(pid)
    return fields is not None and fields[0] != "Z"


def session_members(sids: set[int]) -> list[int]:
    """Live processes whose session id is in ``sids``. Workers lead sessions of their own,
    so this finds a worker's pool processes even after the worker itself died."""
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            fields = _stat_fields(int(entry.name))
            # fields: state, ppid, pgrp, session, ...
            if fields is not None and fields[0] != "Z" and int(fields[3]) in sids:
                out.append(int(entry.name))
    return sorted(out)


def descendants(pid: int) -> list[int]:
    """Live children, grandchildren, ... of ``pid`` (read from ``/proc`` now: take them
    before killing ``pid``, whose orphans are then re-parented)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            fields = _stat_fields(int(entry.name))
            if fields is not None and fields[0] != "Z":
                children.setdefault(int(fields[1]), []).append(int(entry.name))
    out, todo = [], list(children.get(pid, []))
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(children.get(p, []))
    return sorted(out)


def cmdline(pid: int) -> str:
    """The command line of ``pid``, arguments joined by spaces ('' once it is gone)."""
    try:
        return (
            Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        )
    except OSError:
        return ""


@dataclass
class Server:
    """A running ``matforge serve``: its URL, data directory, token and process."""

    url: str
    port: int
    data_dir: Path
    token: str | None
    proc: subprocess.Popen[bytes]
    log_path: Path

    def env(self, **extra: str) -> dict[str, str]:
        """Environment for CLI calls against this server (with its token, if any)."""
        env = base_env(MATFORGE_SERVER=self.url)
        if self.token:
            env["MATFORGE_TOKEN"] = self.token
        env.update(extra)
        return env

    def http(self) -> httpx.Client:
        """An httpx client of the REST API (with the bearer token, if any)."""
        headers = {"Authorization": f"Bearer {self.token}"} if self.token else {}
        return httpx.Client(base_url=self.url, headers=headers, timeout=30.0)

    def log_tail(self, n: int = 60) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-n:])
        except OSError:
            return "(no log)"


def start_server(
    root: Path,
    *,
    token: str | None = None,
    lease_seconds: float | None = None,
    workers: int = 1,
    http_workers: int = 1,
    extra_env: dict[str, str] | None = None,
) -> Server:
    """Start ``matforge serve`` on a free port with its data under ``root``; returns once
    ``/api/health`` answers (fails the test, with the server log, after 60 s)."""
    root.mkdir(parents=True, exist_ok=True)
    data_dir = (root / "data").resolve()
    port = free_port()
    env = base_env(**(extra_env or {}))
    if token:
        env["MATFORGE_TOKEN"] = token
    if lease_seconds is not None:
        env["MATFORGE_LEASE_SECONDS"] = str(lease_seconds)
    log_path = root / "server.log"
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(
            [
                matforge_exe(),
                "serve",
                "--host",
                "127.0.0.1",
                "--port",
                str(port),
                "--data-dir",
                str(data_dir),
                "--workers",
                str(workers),
                "--http-workers",
                str(http_workers),
            ],
            env=env,
            cwd=root,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    server = Server(f"http://127.0.0.1:{port}", port, data_dir, token, proc, log_path)
    deadline = time.monotonic() + START_TIMEOUT_S
    while True:
        if proc.poll() is not None:
            pytest.fail(f"matforge serve exited with {proc.returncode}:\n{server.log_tail()}")
        try:
            if httpx.get(f"{server.url}/api/health", timeout=2.0).status_code == 200:
                return server
        except httpx.TransportError:
            pass
        if time.monotonic() > deadline:
            stop_server(server)
            pytest.fail(
                f"matforge serve did not answer /api/health in {START_TIMEOUT_S:.0f} "
                f"s:\n{server.log_tail()}"
            )
        time.sleep(0.2)


def stop_server(
    server: Server, timeout: float = 20.0, sessions: set[int] | frozenset[int] = frozenset()
) -> list[int]:
    """Stop the server (SIGTERM to its group, SIGKILL after ``timeout``).

    Returns the pids that outlived it and had to be killed here: workers on its data
    directory, and processes left in the sessions of its workers (those alive now, and the
    extra ``sessions``, e.g. of a worker a test killed). Empty when shutdown was clean.
    """
    known = set(worker_pids(server.data_dir)) | set(sessions)
    if server.proc.poll() is None:
        try:
            os.killpg(server.proc.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
        try:
            server.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            try:
                os.killpg(server.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            server.proc.wait(timeout=10)
    leftovers: list[int] = []
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:  # workers given SIGTERM may need a moment to exit
        leftovers = sorted(set(worker_pids(server.data_dir)) | set(session_members(known)))
        if not leftovers:
            break
        time.sleep(0.2)
    for pid in leftovers:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    return leftovers


@dataclass
class CliResult:
    """A finished ``matforge`` call."""

    args: tuple[str, ...]
    returncode: int
    stdout: str
    stderr: str

    def json(self) -> Any:
        """stdout parsed as exactly one JSON document."""
        return json.loads(self.stdout)

    def __str__(self) -> str:
        return (
            f"matforge {' '.join(self.args)} -> {self.returncode}\n"
            f"--- stdout ---\n{self.stdout}\n--- stderr ---\n{self.stderr}"
        )


def run_cli(
    *args: str,
    env: dict[str, str],
    cwd: Path | None = None,
    input: str | None = None,
    timeout: float = 180.0,
) -> CliResult:
    """Run ``matforge ARGS`` and capture its exit code, stdout and stderr."""
    proc = subprocess.run(
        [matforge_exe(), *args],
        env=env,
        cwd=cwd,
        input=input,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    return CliResult(tuple(args), proc.returncode, proc.stdout, proc.stderr)


#: The repository root (the dashboard server subprocess imports the test kinds from it).
ROOT = Path(__file__).resolve().parents[2]


@contextmanager
def serve_in_subprocess(
    data_dir: Path, token: str, log_path: Path, setup: str = ""
) -> Iterator[tuple[str, subprocess.Popen[bytes]]]:
    """``serve()`` in a subprocess on a free port (port 0), with ``token`` and no workers,
    its output in ``log_path``, after the Python statements ``setup`` (``;``-separated);
    yields its URL and the process. A ``RuntimeError`` if it does not start in 60 s.

    Stops it with SIGTERM, and kills it if it ignores that for 20 s."""
    code = (
        "import sys; from pathlib import Path; sys.path.insert(0, sys.argv[2]); "
        "from service.server import serve; from service.settings import Settings; "
        f"{setup}"
        "serve(Settings.from_env().with_(data_dir=Path(sys.argv[1])), "
        "host='127.0.0.1', port=0, workers=0)"
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith("MATFORGE_")}
    env["MATFORGE_TOKEN"] = token
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(
            [sys.executable, "-c", code, str(data_dir), str(ROOT)],
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    try:
        url = None
        deadline = time.monotonic() + 60
        while url is None and time.monotonic() < deadline and proc.poll() is None:
            m = re.search(r"matforge dashboard: (http://\S+)", log_path.read_text())
            url = m.group(1).rstrip("/") if m else None
            time.sleep(0.1)
        if url is None:
            raise RuntimeError(f"the server did not start:\n{log_path.read_text()}")
        yield url, proc
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@contextmanager
def dashboard_server(data_dir: Path, kind_factory: str, token: str, log_dir: Path) -> Iterator[str]:
    """:func:`serve_in_subprocess` after registering the test kind ``kind_factory``
    (``"module:function"``, a function returning a :class:`jobapi.kinds.Kind`) beside the
    built-in ones; yields the URL.

    Fails the test if the server ignores SIGTERM or exits non-zero."""
    module, func = kind_factory.split(":")
    log_path = log_dir / "server.log"
    setup = (
        "from service import kinds; from jobapi.kinds import register; "
        f"from {module} import {func}; "
        f"kinds.load_builtin(); register({func}()); "
    )
    with serve_in_subprocess(data_dir, token, log_path, setup) as (url, proc):
        yield url
    if proc.returncode == -signal.SIGKILL:
        pytest.fail(f"server ignored SIGTERM:\n{log_path.read_text()}")
    assert proc.returncode == 0, log_path.read_text()
