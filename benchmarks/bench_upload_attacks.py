"""Memory of the web process under the upload and preview attacks of issue 21.

Starts ``matforge serve --workers 0`` on a free loopback port (no job workers: the web
process and its upload checkers only) and runs, one phase at a time:

1. ``idle``: nothing, for the baseline;
2. ``exr previews``: a flat 8192x4096 EXR (a ~0.4 MB file) is uploaded, then its
   ``preview.png`` is asked at 9 exposures, 3 requests at once (the issue's attack: ~700 MB
   and 29 s per request in the web process, 2.5 GB for three at once);
3. ``1-bit png zip``: a ``.btf.zip`` of three 1-bit 8192x4096 PNGs (a ~13 KB file) is
   uploaded (decoding its slices is ``import.btf``'s business, in a job worker; the upload
   reads the headers);
4. ``good uploads``: 24 uploads of a 256x256 EXR, 8 at once;
5. ``slow + small``: a 10,000-slice ``.btf.zip`` and, while it is checked, a 3.4 KB EXR
   (the issue's 29 s wait).

A thread samples every 50 ms the RSS of the web process(es) (``serve`` and, with
``--http-workers N``, its extra web processes) and, separately, of everything below them
(the checker children). Each phase starts by resetting the web processes' peak RSS
(``/proc/PID/clear_refs``), so ``VmHWM`` is the exact peak of that phase. The whole run is
done twice: with the default ``MATFORGE_PREVIEW_MAX_PIXELS`` (2**24: the 8192x4096 preview is
refused from its header, 422) and with 2**25 (it is decoded, once, in a checker).

Run: ``.venv/bin/python benchmarks/bench_upload_attacks.py [--http-workers 1] [--runs both]``
"""

from __future__ import annotations

import argparse
import io
import os
import platform
import statistics
import struct
import sys
import threading
import time
import zipfile
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np
import OpenEXR
from served import served

SAMPLE_S = 0.05


def flat_exr(h: int, w: int, value: float = 0.5) -> bytes:
    """A half-float ZIP EXR of one grey value: a small file for a large image."""
    buf = io.BytesIO()
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {"RGB": np.full((h, w, 3), value, np.float16)}) as f:
        f.write(buf)
    return buf.getvalue()


def one_bit_png(h: int, w: int) -> bytes:
    """A 1-bit greyscale PNG of zeros, written by hand (rows compress to almost nothing)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
        )

    raw = (b"\0" * (1 + (w + 7) // 8)) * h
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 1, 0, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(raw, 9))
        + chunk(b"IEND", b"")
    )


def slices_zip(images: list[bytes], suffix: str) -> bytes:
    """A ``.btf.zip``: the images as slices, each with its own light direction."""
    rows = ["file,theta_i,phi_i,theta_o,phi_o"]
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for i, img in enumerate(images):
            rows.append(f"s{i}{suffix},{1 + i % 88},{i // 88},10,0")
            zf.writestr(f"s{i}{suffix}", img)
        zf.writestr("angles.csv", "\n".join(rows))
    return buf.getvalue()


# -- processes and their memory ------------------------------------------------------------
def _stat(pid: int) -> list[str] | None:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None


def _cmd(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


def descendants(pid: int) -> list[int]:
    kids: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit() and (f := _stat(int(d.name))) is not None and f[0] != "Z":
            kids.setdefault(int(f[1]), []).append(int(d.name))
    out, todo = [], list(kids.get(pid, []))
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(kids.get(p, []))
    return out


def status_kb(pid: int, key: str) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def web_pids(server_pid: int) -> list[int]:
    extra = [
        p
        for p in descendants(server_pid)
        if b"spawn_main" in _cmd(p) and b"resource_tracker" not in _cmd(p)
    ]
    return [server_pid, *extra]


@dataclass
class Phase:
    name: str
    web_mb: list[float] = field(default_factory=list)  # summed over web processes
    children_mb: list[float] = field(default_factory=list)  # summed over the rest
    hwm_mb: float = 0.0  # largest VmHWM of one web process
    wall_s: float = 0.0
    codes: dict[int, int] = field(default_factory=dict)
    note: str = ""


class Sampler:
    """Samples RSS every :data:`SAMPLE_S` seconds into the current phase."""

    def __init__(self, server_pid: int) -> None:
        self.server_pid = server_pid
        self.phase: Phase | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while not self._stop.wait(SAMPLE_S):
            phase = self.phase
            if phase is None:
                continue
            web = web_pids(self.server_pid)
            rest = [p for p in descendants(self.server_pid) if p not in web]
            phase.web_mb.append(sum(status_kb(p, "VmRSS") for p in web) / 1024)
            phase.children_mb.append(sum(status_kb(p, "VmRSS") for p in rest) / 1024)

    def run(self, name: str, body: Callable[[Phase], None]) -> Phase:
        phase = Phase(name)
        for p in web_pids(self.server_pid):
            Path(f"/proc/{p}/clear_refs").write_text("5")  # peak RSS := RSS now
        self.phase = phase
        t0 = time.perf_counter()
        body(phase)
        phase.wall_s = time.perf_counter() - t0
        time.sleep(2 * SAMPLE_S)
        self.phase = None
        phase.hwm_mb = max(status_kb(p, "VmHWM") for p in web_pids(self.server_pid)) / 1024
        return phase

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


# -- the attacks -------------------------------------------------------------------------
def _post(url: str, name: str, body: bytes) -> httpx.Response:
    return httpx.post(
        f"{url}/api/artifacts",
        params={"name": name},
        content=body,
        headers={"content-type": "application/octet-stream"},
        timeout=600,
    )


def _count(phase: Phase, code: int) -> None:
    phase.codes[code] = phase.codes.get(code, 0) + 1


def _at_once(n: int, jobs: list[Callable[[], None]]) -> None:
    """Run ``jobs``, ``n`` at a time."""
    for i in range(0, len(jobs), n):
        threads = [threading.Thread(target=j) for j in jobs[i : i + n]]
        for t in threads:
            t.start()
        for t in threads:
            t.join()


def attacks(url: str, sampler: Sampler, files: dict[str, bytes]) -> list[Phase]:
    phases = [sampler.run("idle", lambda ph: time.sleep(2))]

    def previews(ph: Phase) -> None:
        r = _post(url, "hostile.exr", files["exr"])
        _count(ph, r.status_code)
        digest = r.json()["digest"]

        def get(e: float) -> Callable[[], None]:
            def go() -> None:
                g = httpx.get(f"{url}/api/artifacts/{digest}/preview.png?exposure={e}", timeout=600)
                _count(ph, g.status_code)

            return go

        _at_once(3, [get(e) for e in (-4, -2, 0, 1, 2, 3, 4, 5, 6)])

    phases.append(sampler.run("exr previews", previews))
    phases.append(
        sampler.run(
            "1-bit png zip",
            lambda ph: _count(ph, _post(url, "bits.btf.zip", files["pngzip"]).status_code),
        )
    )

    def good(ph: Phase) -> None:
        lat: list[float] = []

        def one(i: int) -> Callable[[], None]:
            def go() -> None:
                t0 = time.perf_counter()
                _count(ph, _post(url, f"good{i}.exr", files["good"]).status_code)
                lat.append(time.perf_counter() - t0)

            return go

        _at_once(8, [one(i) for i in range(24)])
        ph.note = f"latency p50 {statistics.median(lat):.2f} s, max {max(lat):.2f} s"

    phases.append(sampler.run("good uploads", good))

    def slow_small(ph: Phase) -> None:
        out: dict[str, float] = {}

        def slow() -> None:
            t0 = time.perf_counter()
            _count(ph, _post(url, "many.btf.zip", files["many"]).status_code)
            out["slow"] = time.perf_counter() - t0

        t = threading.Thread(target=slow)
        t.start()
        time.sleep(1.0)  # the archive is being checked
        t0 = time.perf_counter()
        _count(ph, _post(url, "small.exr", files["small"]).status_code)
        out["small"] = time.perf_counter() - t0
        t.join()
        ph.note = (
            f"{len(files['small']) / 1024:.1f} KB upload {out['small']:.2f} s; "
            f"the archive {out['slow']:.1f} s"
        )

    phases.append(sampler.run("slow + small", slow_small))
    return phases


def serve_and_attack(
    files: dict[str, bytes], http_workers: int, env_extra: dict[str, str]
) -> list[Phase]:
    with served(http_workers=http_workers, env_extra=env_extra, timeout=90) as server:
        url, proc = server.url, server.proc
        time.sleep(1.0)  # the extra web processes finish starting
        sampler = Sampler(proc.pid)
        try:
            return attacks(url, sampler, files)
        finally:
            sampler.stop()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--http-workers", type=int, default=1, help="matforge serve --http-workers")
    ap.add_argument(
        "--runs",
        choices=("both", "default", "raised"),
        default="both",
        help="the default preview cap, 2**25, or both",
    )
    a = ap.parse_args()
    one = flat_exr(1, 1)
    files = {
        "exr": flat_exr(4096, 8192),
        "pngzip": slices_zip([one_bit_png(4096, 8192)] * 3, ".png"),
        "good": flat_exr(256, 256),
        "small": flat_exr(16, 16),
        "many": slices_zip([one] * 10_000, ".exr"),
    }
    sizes = ", ".join(f"{k} {len(v) / 1024:.1f} KB" for k, v in files.items())
    print(f"files: {sizes}")
    runs: dict[str, dict[str, str]] = {}
    if a.runs in ("both", "default"):
        runs["default (preview cap 2**24)"] = {}
    if a.runs in ("both", "raised"):
        runs["preview cap 2**25"] = {"MATFORGE_PREVIEW_MAX_PIXELS": str(1 << 25)}
    print(
        "| settings | phase | answers | wall s | web RSS median / peak MB (sampled) | "
        "web peak MB (VmHWM) | checkers peak MB | note |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for label, extra in runs.items():
        for ph in serve_and_attack(files, a.http_workers, extra):
            web = ph.web_mb or [0.0]
            kids = ph.children_mb or [0.0]
            codes = " ".join(f"{n}x{c}" for c, n in sorted(ph.codes.items())) or "-"
            print(
                f"| {label} | {ph.name} | {codes} | {ph.wall_s:.1f} | "
                f"{statistics.median(web):.0f} / {max(web):.0f} | {ph.hwm_mb:.0f} | "
                f"{max(kids):.0f} | {ph.note} |"
            )
    print(
        f"machine: {platform.node()}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}"
    )
    cmd = "command: .venv/bin/python benchmarks/bench_upload_attacks.py"
    print(f"{cmd} --http-workers {a.http_workers} --runs {a.runs}")


if __name__ == "__main__":
    sys.exit(main())
