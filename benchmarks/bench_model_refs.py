"""Submissions naming a large stored JSON as a model: their latency, ``/api/health``'s, and
the web process's memory.

A real ``matforge serve --workers 0`` runs on a free loopback port. One object is put
straight into its store (as a job's artifact or a file stored before uploads were
checked would be): ``{"format": "other", "x": [[], [], ...]}`` of about ``--mb`` MB, which
decoded whole is tens of millions of Python lists. ``--attackers`` threads (default 3) each
POST a ``render`` spec naming it as an ``external`` model, one after another, for
``--seconds``; the main thread asks ``GET /api/health`` every 0.2 s. The submission check
reads the object's first 256 KiB only (its ``format``), so each submission is a quick 422.

Prints the submissions' count, statuses and median latency, the health probes' median and
maximum, the web process's RSS at the end, and the command that reproduces it.

Run: ``.venv/bin/python benchmarks/bench_model_refs.py [--mb 60] [--seconds 10]
[--attackers 3]``
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import threading
import time
from pathlib import Path

import httpx
from served import served

ROOT = Path(__file__).resolve().parents[1]


def _rss_mib(pid: int) -> float:
    with open(f"/proc/{pid}/status") as fh:
        line = next(x for x in fh if x.startswith("VmRSS:"))
    return int(line.split()[1]) / 1024


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mb", type=float, default=60.0, help="size of the stored JSON, MB")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--attackers", type=int, default=3)
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT))
    from storage.artifacts import ArtifactStore

    lists = max(1, int(args.mb * 1e6) // 3)
    data = b'{"format": "other", "x": [' + b"[]," * lists + b"[]]}"
    with served() as server:
        ref = "sha256:" + ArtifactStore(Path(server.data_dir) / "store").put_bytes(data).digest
        external = {"external": {"model": ref, "kind": "brdf"}}
        spec = {"kind": "render", "params": {"scene": "sphere_env", "spp": 1,
                "resolution": [8, 8], "material": external}}  # fmt: skip
        stop = time.monotonic() + args.seconds
        subs: list[tuple[float, int]] = []

        def attack() -> None:
            with httpx.Client(base_url=server.url, timeout=120.0) as c:
                while time.monotonic() < stop:
                    t = time.perf_counter()
                    r = c.post("/api/jobs", json=spec)
                    subs.append((time.perf_counter() - t, r.status_code))

        threads = [threading.Thread(target=attack) for _ in range(args.attackers)]
        for t in threads:
            t.start()
        health: list[float] = []
        with httpx.Client(base_url=server.url, timeout=60.0) as c:
            while time.monotonic() < stop:
                t0 = time.perf_counter()
                c.get("/api/health").raise_for_status()
                health.append(time.perf_counter() - t0)
                time.sleep(0.2)
        for t in threads:
            t.join()
        rss = _rss_mib(server.proc.pid)
    codes = sorted({s for _, s in subs})
    print(f"# {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}")
    print("| stored JSON | submissions | statuses | submission median ms | health median / max ms "
          "| web RSS MiB |")  # fmt: skip
    print("| --- | --- | --- | --- | --- | --- |")
    sub_ms = statistics.median(d for d, _ in subs) * 1000
    health_ms = f"{statistics.median(health) * 1000:.1f} / {max(health) * 1000:.1f}"
    print(f"| {len(data) / 1e6:.0f} MB | {len(subs)} | {codes} | {sub_ms:.0f} | {health_ms} "
          f"| {rss:.0f} |")  # fmt: skip
    print(f"# command: .venv/bin/python benchmarks/bench_model_refs.py --mb {args.mb:g} "
          f"--seconds {args.seconds:g} --attackers {args.attackers}")  # fmt: skip


if __name__ == "__main__":
    main()
