"""``/api/health`` latency while hostile job specs are being parsed (issue 21, item 5).

A real ``matforge serve --workers 0`` runs on a free loopback port. ``--attackers`` processes
(default 4) each POST one hostile spec to ``/api/jobs`` after another, for the whole run; the
main process meanwhile asks ``GET /api/health`` every ``--interval`` seconds over one
keep-alive connection and records each answer's latency. Two kinds of hostile spec, as the
issue's attack used:

- ``yaml``: about 6 KB of nested YAML flow sequences (``[[[[...``, thousands deep), which
  PyYAML parses recursively until Python's recursion limit;
- ``json``: a flat JSON array of about ``--json-kb`` KB (default 1024: just under the body
  limit, as in the issue; specs over 256 KiB are now refused before parsing, so
  ``--json-kb 250`` measures the largest that are parsed);
- ``none``: no attackers, the same probes: the floor the machine's load sets.

Prints one table row per kind and the command that reproduces it. The goal is a health p99
under 100 ms.

Run: ``.venv/bin/python benchmarks/bench_hostile_parse.py [--seconds 10] [--attackers 4]
[--kinds yaml,json]``
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import statistics
import time
from typing import Any

import httpx
from served import served

BODY_LIMIT = 1024 * 1024  # the server's default MATFORGE_MAX_BODY_KB


def hostile_body(kind: str, json_bytes: int = BODY_LIMIT) -> tuple[bytes, str]:
    """``(body, content type)`` of one hostile spec of ``kind`` (``yaml`` or ``json``, the
    latter of about ``json_bytes``)."""
    if kind == "yaml":
        depth = 3000  # 6 KB of brackets
        text = "kind: render\nparams: {x: " + "[" * depth + "]" * depth + "}\n"
        return text.encode(), "application/yaml"
    head = '{"kind": "render", "params": {"resolution": ['
    n = (json_bytes - len(head) - 8) // 2
    return (head + ",".join(["1"] * n) + "]}}").encode(), "application/json"


def _attack(url: str, kind: str, json_bytes: int, stop_at: float, counts: Any) -> None:
    body, ctype = hostile_body(kind, json_bytes)
    with httpx.Client(base_url=url, timeout=120.0) as client:
        while time.monotonic() < stop_at:
            r = client.post("/api/jobs", content=body, headers={"content-type": ctype})
            with counts.get_lock():
                counts.value += 1
            if r.status_code not in (413, 422):
                raise SystemExit(f"hostile {kind} spec answered {r.status_code}: {r.text[:200]}")


def measure(
    url: str, kind: str, seconds: float, attackers: int, interval: float, json_bytes: int
) -> dict[str, Any]:
    """Health latencies (ms) while ``attackers`` processes send hostile ``kind`` specs."""
    ctx = mp.get_context("spawn")
    counts = ctx.Value("i", 0)
    stop_at = time.monotonic() + seconds + 1.0
    procs = [ctx.Process(target=_attack, args=(url, kind, json_bytes, stop_at, counts))
             for _ in range(attackers if kind != "none" else 0)]  # fmt: skip
    for p in procs:
        p.start()
    lat: list[float] = []
    with httpx.Client(base_url=url, timeout=60.0) as client:
        client.get("/api/health")
        time.sleep(1.0)  # the attackers' first specs are in flight
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            t0 = time.perf_counter()
            r = client.get("/api/health")
            lat.append((time.perf_counter() - t0) * 1000)
            assert r.status_code == 200, r.text
            time.sleep(interval)
    for p in procs:
        p.join(180)
        if p.exitcode != 0:
            raise SystemExit(f"an attacker failed (exit {p.exitcode})")
    lat.sort()
    return {
        "kind": kind,
        "n": len(lat),
        "p50": statistics.median(lat),
        "p99": lat[min(len(lat) - 1, int(0.99 * len(lat)))],
        "max": lat[-1],
        "specs": counts.value,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--attackers", type=int, default=4)
    ap.add_argument("--interval", type=float, default=0.02, help="seconds between probes")
    ap.add_argument("--kinds", default="none,yaml,json")
    ap.add_argument("--json-kb", type=int, default=BODY_LIMIT // 1024,
                    help="size of the hostile JSON specs")  # fmt: skip
    args = ap.parse_args()
    with served() as server:
        rows = [
            measure(server.url, k, args.seconds, args.attackers, args.interval,
                    args.json_kb * 1024)
            for k in args.kinds.split(",")
        ]  # fmt: skip
    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"load {os.getloadavg()[0]:.1f}")  # fmt: skip
    print("| hostile specs | attackers | health probes | p50 | p99 | max | specs refused |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        n_att = args.attackers if r["kind"] != "none" else 0
        print(f"| {r['kind']} | {n_att} | {r['n']} | {r['p50']:.1f} ms | "
              f"{r['p99']:.1f} ms | {r['max']:.1f} ms | {r['specs']} |")  # fmt: skip
    print(json.dumps(rows))
    print("command: .venv/bin/python benchmarks/bench_hostile_parse.py "
          f"--seconds {args.seconds:g} --attackers {args.attackers} --kinds {args.kinds} "
          f"--json-kb {args.json_kb}")  # fmt: skip


if __name__ == "__main__":
    main()
