"""Job submission latency at 20 concurrent clients against a real ``matforge serve``.

The server runs on a free loopback port with ``--workers 0`` (only the web process: the
measurement is of validation, dedupe and the queue write, not of rendering). Each client
thread submits distinct ``render`` specs (different seeds) over its own HTTP connection.

``--warmup N``: each client first sends N untimed submissions over its connection (the TCP
connect, the server's thread pool and its per-thread SQLite connections then exist before
the timed burst); the default 0 times everything from a cold server.

Run: ``.venv/bin/python benchmarks/bench_submit.py [--clients 20] [--per-client 50]
[--warmup 0]``
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import threading
import time
from pathlib import Path
from typing import Any

import httpx
from served import served


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


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--clients", type=int, default=20)
    ap.add_argument("--per-client", type=int, default=50)
    ap.add_argument("--warmup", type=int, default=0, help="untimed submissions per client")
    ap.add_argument("--http-workers", type=int, default=1, help="matforge serve --http-workers")
    a = ap.parse_args()
    with served(http_workers=a.http_workers) as server:
        url, proc = server.url, server.proc
        latencies: list[float] = []
        lock = threading.Lock()
        barrier = threading.Barrier(a.clients)

        def client(c: int) -> None:
            mine = []
            with httpx.Client(base_url=url, timeout=30) as http:
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

        threads = [threading.Thread(target=client, args=(c,)) for c in range(a.clients)]
        t0, cpu0, server0 = (
            time.perf_counter(),
            time.process_time(),
            _group_cpu_seconds(proc.pid),
        )
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        wall = time.perf_counter() - t0
        client_cpu = time.process_time() - cpu0
        server_cpu = _group_cpu_seconds(proc.pid) - server0
    lat = sorted(latencies)
    n = len(lat)
    p50 = statistics.median(lat) * 1e3
    p99 = lat[min(n - 1, int(0.99 * n))] * 1e3
    print(
        f"| submit latency | {a.clients} clients x {a.per_client} | p50 {p50:.1f} ms | "
        f"p99 {p99:.1f} ms | {n / wall:.0f} submissions/s | {platform.node()} |"
    )
    sent = n + a.clients * a.warmup
    print(
        f"CPU per submission: server {server_cpu / sent * 1e3:.2f} ms, this client "
        f"{client_cpu / sent * 1e3:.2f} ms; cores busy: server {server_cpu / wall:.2f}, "
        f"client {client_cpu / wall:.2f}; load average {os.getloadavg()[0]:.1f}"
    )
    print(
        f"command: .venv/bin/python benchmarks/bench_submit.py --clients {a.clients} "
        f"--per-client {a.per_client} --warmup {a.warmup} --http-workers {a.http_workers}"
    )


if __name__ == "__main__":
    sys.exit(main())
