"""Job submission latency at 20 concurrent clients against a real ``matforge serve``.

The server runs on a free loopback port with ``--workers 0`` (only the web process: the
measurement is of validation, dedupe and the queue write, not of rendering). Each client
thread submits distinct ``render`` specs (different seeds) over its own HTTP connection.

``--warmup N``: each client first sends N untimed submissions over its connection (the TCP
connect, the server's thread pool and its per-thread SQLite connections then exist before
the timed burst); the default 0 times everything from a cold server.

``--pin``: the server is pinned to one core and this client (all its threads) to the other
(``taskset``; ``--server-cpus``/``--client-cpus`` choose them), so that the 20-thread load
generator, which costs about as much CPU per submission as the server, no longer takes the
server's core. The server's CPU per submission is read from /proc over the timed burst only
(warm-up excluded), so it is the server's own cost whatever the client costs.

``--baseline REV``: the same measurement, alternated round by round, against the server of
git revision ``REV`` (its source exported to a temporary folder and put first on
``PYTHONPATH``; same virtual environment), so that before and after come from one run.
``--rounds N``: rounds of (baseline, this tree). ``--history N``: the store holds N earlier
jobs (half succeeded, the rest failed or cancelled) before the burst, as a server that has
run for a while does; the default 0 starts from an empty store. ``--profile FILE``: a
``py-spy`` profile (speedscope JSON) of this tree's server during its first timed burst
(``pip install py-spy``).

Run: ``.venv/bin/python benchmarks/bench_submit.py [--clients 20] [--per-client 50]
[--warmup 0] [--pin] [--baseline REV --rounds 3]``
"""

from __future__ import annotations

import argparse
import hashlib
import os
import platform
import shutil
import sqlite3
import statistics
import subprocess
import sys
import tarfile
import tempfile
import threading
import time
import uuid
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from typing import Any

import httpx
from served import served

ROOT = Path(__file__).resolve().parents[1]


def _spec(seed: int) -> dict[str, Any]:
    """A distinct small ``render`` spec per seed."""
    return {
        "kind": "render",
        "seed": seed,
        "params": {
            "scene": "sphere_env",
            "material": {"mitsuba": {"type": "diffuse"}},
            "resolution": [64, 64],
            "spp": 4,
        },
    }


def _group_cpu_seconds(pgid: int) -> float:
    """User + system CPU seconds of the processes in process group ``pgid`` (the server and
    its extra web processes), from /proc."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid:  # fields after the name: state, ppid, pgrp, ...
            total += int(fields[11]) + int(fields[12])  # utime, stime
    return total / tick


@dataclass
class Result:
    """One timed burst."""

    arm: str
    p50_ms: float
    p99_ms: float
    rate: float
    server_ms: float
    client_ms: float
    server_cores: float
    client_cores: float
    load: tuple[float, float]


def _export(rev: str) -> Path:
    """The source tree of git revision ``rev`` in a new temporary folder."""
    data = subprocess.run(
        ["git", "-C", str(ROOT), "archive", "--format=tar", rev],
        check=True,
        capture_output=True,
    ).stdout
    out = Path(tempfile.mkdtemp(prefix="bench-submit-rev-"))
    with tarfile.open(fileobj=BytesIO(data)) as tar:
        tar.extractall(out, filter="data")
    return out


def _fill_history(db: Path, n: int) -> None:
    """``n`` finished jobs of distinct specs in the job table, written by SQLite directly
    (seconds, not the minutes ``n`` submissions would take)."""
    states = ("succeeded", "failed", "succeeded", "cancelled")
    with sqlite3.connect(db, timeout=60) as conn:
        start = conn.execute("SELECT COALESCE(MAX(seq), 0) FROM jobs").fetchone()[0]
        conn.executemany(
            "INSERT INTO jobs (id, seq, kind, seed, spec_hash, spec, state, created_at, "
            "updated_at) VALUES (?, ?, 'render', ?, ?, '{}', ?, 0, 0)",
            (
                (uuid.uuid4().hex, start + i + 1, i, hashlib.sha256(b"%d" % i).hexdigest(),
                 states[i % 4])
                for i in range(n)
            ),
        )  # fmt: skip


def burst(
    a: argparse.Namespace,
    arm: str,
    env_extra: dict[str, str] | None = None,
    profile: str | None = None,
) -> Result:
    """One server, ``a.clients`` client threads, ``a.per_client`` timed submissions each."""
    load0 = os.getloadavg()[0]
    cpus = a.server_cpus if a.pin else None
    with served(http_workers=a.http_workers, env_extra=env_extra, cpus=cpus) as server:
        url, proc = server.url, server.proc
        if a.history:
            _fill_history(Path(server.data_dir) / "jobs.sqlite3", a.history)
        latencies: list[float] = []
        lock = threading.Lock()
        start: dict[str, float] = {}

        def mark() -> None:  # run by one thread once every client has warmed up
            start.update(t=time.perf_counter(), cpu=time.process_time())
            start["server"] = _group_cpu_seconds(proc.pid)

        barrier = threading.Barrier(a.clients, action=mark)

        def client(c: int) -> None:
            mine = []
            with httpx.Client(base_url=url, timeout=60) as http:
                for i in range(a.per_client, a.per_client + a.warmup):
                    r = http.post("/api/jobs", json=_spec(c * 100000 + i))
                    assert r.status_code == 201, r.text
                barrier.wait()
                for i in range(a.per_client):
                    spec = _spec(c * 100000 + i)
                    t0 = time.perf_counter()
                    r = http.post("/api/jobs", json=spec)
                    mine.append(time.perf_counter() - t0)
                    assert r.status_code == 201, r.text
            with lock:
                latencies.extend(mine)

        spy = None
        if profile is not None:
            spy = subprocess.Popen(
                [a.py_spy, "record", "--pid", str(proc.pid), "--format", "speedscope",
                 "--output", profile, "--rate", "250", "--gil", "--nonblocking"],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            )  # fmt: skip
            time.sleep(1.0)
        threads = [threading.Thread(target=client, args=(c,)) for c in range(a.clients)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        wall = time.perf_counter() - start["t"]
        client_cpu = time.process_time() - start["cpu"]
        server_cpu = _group_cpu_seconds(proc.pid) - start["server"]
        if spy is not None:
            spy.send_signal(2)  # SIGINT: py-spy writes its file and exits
            spy.wait(60)
    lat = sorted(latencies)
    n = len(lat)
    return Result(
        arm=arm,
        p50_ms=statistics.median(lat) * 1e3,
        p99_ms=lat[min(n - 1, int(0.99 * n))] * 1e3,
        rate=n / wall,
        server_ms=server_cpu / n * 1e3,
        client_ms=client_cpu / n * 1e3,
        server_cores=server_cpu / wall,
        client_cores=client_cpu / wall,
        load=(load0, os.getloadavg()[0]),
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--clients", type=int, default=20)
    ap.add_argument("--per-client", type=int, default=50)
    ap.add_argument("--warmup", type=int, default=0, help="untimed submissions per client")
    ap.add_argument("--http-workers", type=int, default=1, help="matforge serve --http-workers")
    ap.add_argument("--pin", action="store_true", help="server and client on separate cores")
    ap.add_argument("--server-cpus", default="1", help="taskset CPU list of the server")
    ap.add_argument("--client-cpus", default="0", help="CPU list of this client")
    ap.add_argument("--baseline", metavar="REV", help="also measure git revision REV's server")
    ap.add_argument("--rounds", type=int, default=1, help="rounds of (baseline, this tree)")
    ap.add_argument("--history", type=int, default=0, help="earlier jobs in the store")
    ap.add_argument("--profile", metavar="FILE", help="py-spy profile of this tree's server")
    a = ap.parse_args()
    if a.pin:
        if shutil.which("taskset") is None:
            raise SystemExit("--pin needs taskset (util-linux)")
        os.sched_setaffinity(0, {int(c) for c in a.client_cpus.split(",")})
    bins = f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"
    spy = shutil.which("py-spy", path=bins)
    if a.profile and spy is None:
        raise SystemExit("--profile needs py-spy (pip install py-spy)")
    a.py_spy = spy
    old = _export(a.baseline) if a.baseline else None
    results: list[Result] = []
    try:
        for r in range(a.rounds):
            if old is not None:
                env = {"PYTHONPATH": str(old)}
                results.append(burst(a, f"baseline {a.baseline}", env))
            results.append(burst(a, "this tree", profile=a.profile if r == 0 else None))
    finally:
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    print(
        f"{a.clients} clients x {a.per_client} timed submissions, warmup {a.warmup}, "
        f"http workers {a.http_workers}, {a.history} earlier jobs in the store, "
        + (f"server on CPU {a.server_cpus}, client on CPU {a.client_cpus}" if a.pin else "unpinned")
        + f", {platform.node()}, {os.cpu_count()} CPUs"
    )
    print(
        "| arm | p50 | p99 | submissions/s | server CPU per submission | client CPU per "
        "submission | cores busy: server / client | load average (start, end) |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for x in results:
        print(
            f"| {x.arm} | {x.p50_ms:.1f} ms | {x.p99_ms:.1f} ms | {x.rate:.0f} | "
            f"{x.server_ms:.2f} ms | {x.client_ms:.2f} ms | {x.server_cores:.2f} / "
            f"{x.client_cores:.2f} | {x.load[0]:.1f}, {x.load[1]:.1f} |"
        )
    arms = dict.fromkeys(x.arm for x in results)
    if len(arms) > 1:
        for arm in arms:
            xs = [x for x in results if x.arm == arm]
            print(
                f"median over {len(xs)} rounds, {arm}: p99 "
                f"{statistics.median(x.p99_ms for x in xs):.1f} ms, server CPU "
                f"{statistics.median(x.server_ms for x in xs):.2f} ms per submission"
            )
    print("command: .venv/bin/python benchmarks/bench_submit.py " + " ".join(sys.argv[1:]))


if __name__ == "__main__":
    sys.exit(main())
