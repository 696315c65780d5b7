"""The hardening attacks replayed against a local ``matforge serve``: one row per finding.

Starts ``matforge serve --workers 1`` on a free port of 127.0.0.1 (loopback only) with a
temporary data directory, and replays, one at a time:

1. an ONNX constant-folding bomb (initialisers ``[K,1]`` and ``[1,K]`` -> Add -> ReduceSum
   -> Mul(wi)) at K = 16384 (131 KB) and K = 65536 (524 KB): uploaded, then rendered;
2. an ONNX run-time quadratic (Slice(wi) -> Transpose -> Add gives ``[N,N]``): rendered at
   256 x 256, 1 spp (batches of up to 65,536 rows: 16 GiB);
3. a 60 MB JSON that is no model (``{"format": "other", "x": [[], ...]}``): uploaded, then
   named as a render's model by three submissions at once;
4. a valid PNG with a ``.btf.zip`` appended, uploaded as ``.png`` and given to
   ``import.btf`` as its archive; the same with an ``angles.csv`` of 20 million blank lines;
5. uploads: a ``.btf.zip`` whose member's IHDR claims 100000 x 100000 pixels; an ``.npz``
   with a member that is not ``.npy``; the 20 KB zip whose ``angles.csv`` holds 20 million
   blank lines (it held a checker for 18 s); a 1.5 MB zip inflating 1.5 GB;
6. ``matforge fetch -o`` onto a symlink to a file, and onto a dangling symlink (both in a
   temporary folder).

A thread samples every 0.2 s the RSS of the web process, of the job workers (with their
shard processes) and of the upload checkers, from ``/proc``; another asks ``/api/health``
every 0.2 s. A small render warms the worker up first. Each row gives the outcome (HTTP
status, job state and error), the peaks of those RSS sums during the finding, the slowest
``/api/health`` answer, and the wall time.
Every request and every job wait is bounded (a job still running after ``--job-timeout``
seconds is cancelled and reported as such), so the script never hangs; a finding that
raises is reported as such and the next one runs.

Run: ``nice -n 10 .venv/bin/python benchmarks/bench_attack.py [--job-memory-mb 2048]
[--only NAME ...]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
from served import Served, served

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.helpers import attack_files  # noqa: E402

SAMPLE_S = 0.2
WARM_UP: dict[str, Any] = {
    "kind": "render",
    "params": {
        "scene": "sphere_env",
        "material": {"mitsuba": {"type": "diffuse"}},
        "resolution": [16, 16],
        "spp": 1,
    },
}
OCTETS = {"content-type": "application/octet-stream"}


# -- /proc ----------------------------------------------------------------------------------
def _stat(pid: int) -> list[str] | None:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None


def _cmd(pid: int) -> str:
    try:
        return (
            Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        )
    except OSError:
        return ""


def _rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def _children() -> dict[int, list[int]]:
    kids: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit() and (f := _stat(int(d.name))) is not None and f[0] != "Z":
            kids.setdefault(int(f[1]), []).append(int(d.name))
    return kids


def _tree(pid: int, kids: dict[int, list[int]]) -> list[int]:
    out, todo = [], list(kids.get(pid, []))
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(kids.get(p, []))
    return out


def groups(server_pid: int) -> dict[str, list[int]]:
    """The server's processes: ``web`` (it), ``workers`` (job workers and all below them),
    ``checkers`` (upload checkers)."""
    kids = _children()
    out: dict[str, list[int]] = {"web": [server_pid], "workers": [], "checkers": []}
    for p in _tree(server_pid, kids):
        cmd = _cmd(p)
        if "service.workers.worker" in cmd:
            out["workers"] += [p, *_tree(p, kids)]
        elif "service.upload_check" in cmd:
            out["checkers"].append(p)
    return out


# -- sampling -------------------------------------------------------------------------------
@dataclass
class Row:
    name: str
    size: str = ""
    outcome: str = ""
    peak_mb: dict[str, float] = field(
        default_factory=lambda: dict.fromkeys(("web", "workers", "checkers"), 0.0)
    )
    health_max_s: float = 0.0
    health_fail: int = 0
    wall_s: float = 0.0


class Watch:
    """RSS of the server's process groups and ``/api/health`` latency, every
    :data:`SAMPLE_S`, into the current row."""

    def __init__(self, srv: Served) -> None:
        self.srv = srv
        self.row: Row | None = None
        self._stop = threading.Event()
        self._threads = [
            threading.Thread(target=self._rss, daemon=True),
            threading.Thread(target=self._health, daemon=True),
        ]
        for t in self._threads:
            t.start()

    def _rss(self) -> None:
        while not self._stop.wait(SAMPLE_S):
            row = self.row
            if row is None:
                continue
            for name, pids in groups(self.srv.proc.pid).items():
                row.peak_mb[name] = max(row.peak_mb[name], sum(_rss_mb(p) for p in pids))

    def _health(self) -> None:
        with httpx.Client(timeout=10.0) as http:
            while not self._stop.wait(SAMPLE_S):
                row = self.row
                t0 = time.perf_counter()
                try:
                    ok = http.get(f"{self.srv.url}/api/health").status_code == 200
                except httpx.HTTPError:
                    ok = False
                took = time.perf_counter() - t0
                if row is not None:
                    row.health_max_s = max(row.health_max_s, took)
                    row.health_fail += 0 if ok else 1

    def stop(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=15)


# -- the attacks ----------------------------------------------------------------------------
@dataclass
class Ctx:
    srv: Served
    http: httpx.Client
    job_timeout: float
    tmp: Path


def _short(text: str, n: int = 150) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= n else text[: n - 3] + "..."


def upload(ctx: Ctx, name: str, body: bytes) -> tuple[int, dict[str, Any]]:
    """``POST /api/artifacts`` on a connection of its own (a server that fails a request
    may close the connection under the next one): ``(status, body)``, status 0 with the
    client's error when no answer came."""
    try:
        r = httpx.post(
            f"{ctx.srv.url}/api/artifacts",
            params={"name": name},
            content=body,
            headers={**OCTETS, "connection": "close"},
            timeout=300,
        )
    except httpx.HTTPError as exc:
        return 0, {"error": f"no answer: {type(exc).__name__}: {exc}"}
    try:
        doc = r.json()
    except ValueError:
        doc = {"error": r.text[:200]}
    return r.status_code, doc


def _said(code: int, doc: dict[str, Any]) -> str:
    shown = code >= 400 or code == 0
    return f"{code}" + (f" {_short(doc['error'])}" if shown and "error" in doc else "")


def run_job(ctx: Ctx, spec: dict[str, Any]) -> str:
    """Submit ``spec`` and wait (bounded) for it: ``"submit 201; job failed: <error>"``."""
    r = ctx.http.post("/api/jobs", json=spec, timeout=120)
    if r.status_code not in (200, 201):
        return f"submit {_said(r.status_code, r.json())}"
    job_id = r.json()["id"]
    deadline = time.monotonic() + ctx.job_timeout
    while time.monotonic() < deadline:
        try:
            doc = ctx.http.get(f"/api/jobs/{job_id}", timeout=30).json()
        except httpx.HTTPError:
            time.sleep(0.5)
            continue
        if doc["state"] in ("succeeded", "failed", "cancelled"):
            said = f"; {_short(doc['error'])}" if doc.get("error") else ""
            return f"submit {r.status_code}; job {doc['state']} (attempt {doc['attempts']}){said}"
        time.sleep(0.5)
    ctx.http.post(f"/api/jobs/{job_id}/cancel", timeout=30)
    return f"submit {r.status_code}; job still running after {ctx.job_timeout:g} s: cancelled"


def render_spec(ref: str, resolution: int = 32, spp: int = 1, seed: int = 0) -> dict[str, Any]:
    return {
        "kind": "render",
        "seed": seed,
        "params": {
            "scene": "sphere_env",
            "material": {"external": {"model": ref, "kind": "brdf"}},
            "resolution": [resolution, resolution],
            "spp": spp,
        },
    }


def upload_then_render(ctx: Ctx, name: str, body: bytes, resolution: int, seed: int) -> str:
    code, doc = upload(ctx, name, body)
    if code != 201:
        return f"upload {_said(code, doc)}"
    return f"upload 201; {run_job(ctx, render_spec(doc['ref'], resolution, 1, seed))}"


def onnx_bomb(k: int) -> Callable[[Ctx], str]:
    def go(ctx: Ctx) -> str:
        body = attack_files.constant_folding_bomb(k).SerializeToString()
        return upload_then_render(ctx, f"fold{k}.onnx", body, 32, k)

    return go


def onnx_quadratic(ctx: Ctx) -> str:
    body = attack_files.runtime_quadratic().SerializeToString()
    return upload_then_render(ctx, "quadratic.onnx", body, 256, 1)


def big_json(ctx: Ctx) -> str:
    code, doc = upload(ctx, "other.json", attack_files.non_mlp_json(60_000_000))
    if code != 201:
        return f"upload {_said(code, doc)}"
    spec = render_spec(doc["ref"])
    results: list[str] = []

    def submit(i: int) -> None:
        t0 = time.perf_counter()
        try:
            r = ctx.http.post("/api/jobs", json={**spec, "seed": 100 + i}, timeout=120)
            results.append(f"{r.status_code} in {time.perf_counter() - t0:.1f} s")
            if r.status_code in (200, 201):
                ctx.http.post(f"/api/jobs/{r.json()['id']}/cancel", timeout=30)
        except httpx.HTTPError as exc:
            results.append(f"{type(exc).__name__} after {time.perf_counter() - t0:.1f} s")

    threads = [threading.Thread(target=submit, args=(i,)) for i in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=180)
    return f"upload 201; 3 submissions at once: {', '.join(sorted(results))}"


def png_archive(zip_body: bytes, label: str) -> Callable[[Ctx], str]:
    def go(ctx: Ctx) -> str:
        code, doc = upload(ctx, f"{label}.png", attack_files.png() + zip_body)
        if code != 201:
            return f"upload {_said(code, doc)}"
        spec = {"kind": "import.btf", "seed": len(label), "params": {"archive": doc["ref"]}}
        return f"upload 201; {run_job(ctx, spec)}"

    return go


def upload_only(name: str, build: Callable[[], bytes]) -> Callable[[Ctx], str]:
    def go(ctx: Ctx) -> str:
        body = build()
        t0 = time.perf_counter()
        code, doc = upload(ctx, name, body)
        return f"upload {_said(code, doc)} ({time.perf_counter() - t0:.1f} s)"

    return go


def fetch_onto_link(dangling: bool) -> Callable[[Ctx], str]:
    def go(ctx: Ctx) -> str:
        code, doc = upload(ctx, "fetched.png", attack_files.png(value=7))
        if code != 201:
            return f"upload {_said(code, doc)}"
        folder = Path(tempfile.mkdtemp(dir=ctx.tmp, prefix="fetch-"))
        target = folder / ("absent.txt" if dangling else "precious.txt")
        if not dangling:
            target.write_text("precious\n")
        link = folder / "x.png"
        link.symlink_to(target)
        env = {k: v for k, v in os.environ.items() if not k.startswith("MATFORGE_")}
        env["MATFORGE_SERVER"] = ctx.srv.url
        exe = os.path.join(os.path.dirname(sys.executable), "matforge")
        proc = subprocess.run(
            [exe, "fetch", doc["ref"], "-o", str(link)],
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
        if dangling:
            what = "dangling target created" if target.exists() else "no target created"
        else:
            what = "target intact" if target.read_bytes() == b"precious\n" else "TARGET REPLACED"
        kind = "still a link" if link.is_symlink() else "link replaced by a file"
        said = (
            f": {_short(proc.stderr.strip().splitlines()[-1], 90)}" if proc.stderr.strip() else ""
        )
        return f"fetch exit {proc.returncode}{said}; {what}; {kind}"

    return go


def findings() -> list[tuple[str, str, Callable[[Ctx], str]]]:
    """``(name, size on the wire, attack)`` of every finding, in order."""
    blanks = attack_files.blank_lines_zip(20_000_000)
    pngzip = attack_files.slices_zip(1)
    ihdr, npz = attack_files.ihdr_bomb_zip(), attack_files.npz_with_text_member()

    def bomb() -> bytes:
        return attack_files.inflating_slice_zip(1_500_000_000)

    kb = f"{len(blanks) / 1000:.0f} KB"
    return [
        ("onnx-fold-16384", "131 KB", onnx_bomb(16384)),
        ("onnx-fold-65536", "524 KB", onnx_bomb(65536)),
        ("onnx-quadratic", "1 KB", onnx_quadratic),
        ("json-60MB-x3", "60 MB", big_json),
        ("png+zip-import", f"{len(pngzip) + 100} B", png_archive(pngzip, "pngzip")),
        ("blank-angles-import", kb, png_archive(blanks, "blanks")),
        ("ihdr-100000", f"{len(ihdr)} B", upload_only("ihdr.btf.zip", lambda: ihdr)),
        ("npz-non-npy", f"{len(npz)} B", upload_only("text.npz", lambda: npz)),
        ("slow-zip-20KB", kb, upload_only("slow.btf.zip", lambda: blanks)),
        ("zip-bomb-1.5GB", "1.5 MB", upload_only("bomb.btf.zip", bomb)),
        ("fetch-symlink", "-", fetch_onto_link(False)),
        ("fetch-dangling", "-", fetch_onto_link(True)),
    ]


def settle(ctx: Ctx, timeout: float = 60.0) -> None:
    """Wait (bounded) until no job runs and a worker is alive."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            running = httpx.get(f"{ctx.srv.url}/api/jobs", params={"state": "running"}, timeout=30)
            busy = running.status_code != 200 or bool(running.json())
        except httpx.HTTPError:
            busy = True
        if not busy and groups(ctx.srv.proc.pid)["workers"]:
            return
        time.sleep(0.5)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument(
        "--job-memory-mb",
        default=None,
        help="MATFORGE_JOB_MEMORY_MB of the server (default: the server's own default)",
    )
    ap.add_argument("--job-timeout", type=float, default=180.0, help="seconds a job may run")
    ap.add_argument("--only", nargs="*", default=None, help="run only these findings")
    ap.add_argument("--log", default=None, help="write the server's log here")
    a = ap.parse_args()
    env: dict[str, str] = {}
    if a.job_memory_mb is not None:
        env["MATFORGE_JOB_MEMORY_MB"] = str(a.job_memory_mb)
    every = findings()
    unknown = sorted(set(a.only or ()) - {f[0] for f in every})
    if unknown:
        ap.error(f"unknown findings {unknown}; known: {', '.join(f[0] for f in every)}")
    todo = [f for f in every if a.only is None or f[0] in a.only]
    rows: list[Row] = []
    t_all = time.perf_counter()
    with (
        tempfile.TemporaryDirectory(prefix="bench-attack-") as tmp,
        served(workers=1, env_extra=env, timeout=180, log_path=a.log) as srv,
        httpx.Client(base_url=srv.url, timeout=60) as http,
    ):
        ctx = Ctx(srv, http, a.job_timeout, Path(tmp))
        watch = Watch(srv)
        try:
            settle(ctx, 120)
            # a small render first: the worker has loaded Mitsuba, the web process its
            # modules, before the first finding is measured
            print(f"# warm-up: {run_job(ctx, WARM_UP)}", file=sys.stderr, flush=True)
            settle(ctx)
            for name, size, attack in todo:
                row = Row(name, size)
                watch.row = row
                t0 = time.perf_counter()
                try:
                    row.outcome = attack(ctx)
                except Exception as exc:  # report it, run the next one
                    row.outcome = f"the attack raised {type(exc).__name__}: {_short(str(exc), 100)}"
                    traceback.print_exc(file=sys.stderr)
                settle(ctx)
                time.sleep(2 * SAMPLE_S)
                row.wall_s = time.perf_counter() - t0
                watch.row = None
                rows.append(row)
                print(f"# {name}: {row.outcome}", file=sys.stderr, flush=True)
        finally:
            watch.stop()
    print(
        "| finding | sent | outcome | web peak MB | workers peak MB | checkers peak MB | "
        "max /api/health s | wall s |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        fails = f" ({r.health_fail} failed)" if r.health_fail else ""
        print(
            f"| {r.name} | {r.size} | {r.outcome.replace('|', '/')} | {r.peak_mb['web']:.0f} | "
            f"{r.peak_mb['workers']:.0f} | {r.peak_mb['checkers']:.0f} | "
            f"{r.health_max_s:.2f}{fails} | {r.wall_s:.1f} |"
        )
    load = os.getloadavg()
    print(
        f"machine: {platform.node()}, {os.cpu_count()} cores; load average "
        f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; total {time.perf_counter() - t_all:.0f} s"
    )
    extra = f" --job-memory-mb {a.job_memory_mb}" if a.job_memory_mb is not None else ""
    print(f"command: nice -n 10 .venv/bin/python benchmarks/bench_attack.py{extra}")
    print(json.dumps({"rows": len(rows)}), file=sys.stderr)


if __name__ == "__main__":
    main()
