"""Uploads are validated in bounded child processes, never in the web process, and refused
with a message over the caps (issue 15, B3).

The REST tests run twice: in-process, and against ``matforge serve --http-workers 2`` (issue
21, item 2: the extra web processes were daemonic and could not start the checker). A pool
of checkers keeps a slow upload from holding up the others, and a full pool answers 503
with ``Retry-After`` (item 10).
"""

from __future__ import annotations

import io
import os
import signal
import threading
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from fastapi.testclient import TestClient

from service.api import create_app
from service.settings import Settings
from service.upload_check import CheckerBusy, CheckFailed, UploadChecker
from storage.errors import FormatError, TooLargeError
from storage.formats.exr import exr_bytes

from .harness import Server, cmdline, descendants, pid_alive, start_server, stop_server

OCTETS = {"content-type": "application/octet-stream"}


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """``matforge serve`` with 2 web processes (no job workers: only uploads are tested)."""
    srv = start_server(tmp_path_factory.mktemp("uploads"), workers=0, http_workers=2)
    try:
        yield srv
    finally:
        assert stop_server(srv) == []


@pytest.fixture(params=["in-process", "2 web processes"])
def client(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Any]:
    """The REST API in-process (``TestClient``), or of :func:`served` over HTTP."""
    if request.param == "in-process":
        settings = Settings.from_env({}).with_(data_dir=tmp_path)
        with TestClient(create_app(settings), raise_server_exceptions=False) as c:
            yield c
    else:
        srv: Server = request.getfixturevalue("served")
        with httpx.Client(base_url=srv.url, timeout=60) as c:
            yield c


def slices_zip(n: int) -> bytes:
    """A ``.btf.zip`` of ``n`` 1x1 EXR slices: a small file whose check reads ``n`` headers
    (~3 ms each on 2 shared cores; 10,000 took 29 s in the issue's attack)."""
    one = exr_bytes(np.ones((1, 1, 3), np.float32))
    rows = ["file,theta_i,phi_i,theta_o,phi_o"]
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for i in range(n):
            rows.append(f"s{i}.exr,{1 + i % 88},{i // 88},10,0")
            zf.writestr(f"s{i}.exr", one)
        zf.writestr("angles.csv", "\n".join(rows))
    return buf.getvalue()


def _wait_for(cond: Any, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(0.05)


def _zeros_npz(n: int) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        entry = io.BytesIO()
        np.lib.format.write_array(entry, np.zeros(n, np.float64))
        zf.writestr("z.npy", entry.getvalue())
    return buf.getvalue()


def test01_lying_npz_header_is_422_not_500(client: TestClient) -> None:
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "<f8", "fortran_order": False, "shape": (2**40,)}
    )
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("x.npy", header.getvalue() + b"\0" * 64)
    r = client.post("/api/artifacts?name=claims.npz", content=buf.getvalue(), headers=OCTETS)
    assert r.status_code == 422, r.text
    assert r.json()["error"].startswith("claims.npz: array 'x.npy': its header claims")


def test02_valid_upload_still_works(client: TestClient) -> None:
    r = client.post(
        "/api/artifacts?name=ok.exr", content=exr_bytes(np.ones((4, 4, 3))), headers=OCTETS
    )
    assert r.status_code == 201, r.text
    bad = client.post("/api/artifacts?name=bad.exr", content=b"v/1\x01" + b"\0" * 64)
    assert bad.status_code == 422 and bad.json()["error"].startswith("bad.exr: ")


def test03_decoding_runs_in_a_bounded_child(tmp_path: Path) -> None:
    """A deflated npz of zeros (a few hundred KB) that decodes to 240 MB: out of memory in
    the child (capped at 200 MB here) is a 413-type error; the next file gets a fresh child,
    and the caller's process never decodes."""
    bomb = tmp_path / "bomb.npz"
    bomb.write_bytes(_zeros_npz(30_000_000))
    assert bomb.stat().st_size < 1_000_000
    good = tmp_path / "good.exr"
    good.write_bytes(exr_bytes(np.ones((4, 4, 3))))
    checker = UploadChecker(max_bytes=200 * 1024 * 1024)
    try:
        with pytest.raises((TooLargeError, FormatError)) as info:
            checker.validate(bomb, "bomb.npz")
        assert str(info.value).startswith("bomb.npz: ")
        assert checker.validate(good, "good.exr") == "image/x-exr"
        pids = checker.child_pids()
        assert len(pids) == 1 and os.getpid() not in pids
    finally:
        checker.close()


def test04_uploads_with_two_web_processes(served: Server) -> None:
    """Ten uploads, each on a new connection (the kernel spreads them over both web
    processes): all 201. Before the fix most answered 500 ("daemonic processes are not
    allowed to have children")."""
    codes = []
    for i in range(10):
        body = exr_bytes(np.full((4, 4, 3), float(i), np.float32))
        r = httpx.post(f"{served.url}/api/artifacts?name=g{i}.exr", content=body, headers=OCTETS)
        codes.append(r.status_code)
    assert codes == [201] * 10, served.log_tail()


def test05_a_slow_check_does_not_hold_up_the_others(tmp_path: Path) -> None:
    """Pool of 2: a small file is checked while an archive of 10,000 slices still is; with
    both children busy, the next call waits ``queue_wait`` and gets ``CheckerBusy``."""
    slow = tmp_path / "slow.btf.zip"
    slow.write_bytes(slices_zip(10_000))
    good = tmp_path / "good.exr"
    good.write_bytes(exr_bytes(np.ones((4, 4, 3))))
    checker = UploadChecker(200 * 1024 * 1024, timeout=60, processes=2, queue_wait=0.5)
    errors: list[BaseException] = []

    def check_slow() -> None:
        try:
            checker.validate(slow, "slow.btf.zip")
        except BaseException as exc:  # CheckFailed once close() kills it
            errors.append(exc)

    threads = [threading.Thread(target=check_slow) for _ in range(2)]
    try:
        assert checker.validate(good, "warm.exr") == "image/x-exr"  # the first child is up
        threads[0].start()
        _wait_for(lambda: checker.in_flight == 1, 30, "the slow check to start")
        t0 = time.monotonic()
        assert checker.validate(good, "good.exr") == "image/x-exr"
        # Timing bound: the small check needs a child start (~1-2 s here) and a few ms of
        # work; behind the slow one it would wait the ~30 s that takes.
        assert time.monotonic() - t0 < 15
        assert threads[0].is_alive() and checker.in_flight == 1

        threads[1].start()
        _wait_for(lambda: checker.in_flight == 2, 30, "the second slow check to start")
        t0 = time.monotonic()
        with pytest.raises(CheckerBusy) as info:
            checker.validate(good, "late.exr")
        assert time.monotonic() - t0 >= 0.5
        assert info.value.retry_after >= 1 and str(info.value).startswith("late.exr: ")
    finally:
        checker.close()
        for t in threads:
            t.join(timeout=30)
    assert all(isinstance(e, CheckFailed) for e in errors), errors


def test06_busy_checker_is_503_with_retry_after_and_time_limit(tmp_path: Path) -> None:
    """One checker, a queue wait of 0.5 s and a time limit of 2 s: an upload behind a slow
    one gets 503 with ``Retry-After`` at once, and the slow one 413 naming its time budget
    when its time is up (a 422 before uploads had a budget). Before the fix the small
    upload waited for the slow one to finish."""
    settings = Settings.from_env({}).with_(
        data_dir=tmp_path,
        upload_checkers=1,
        upload_queue_seconds=0.5,
        upload_check_seconds=2.0,
    )
    slow_body = slices_zip(10_000)
    results: dict[str, httpx.Response] = {}
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        checker: UploadChecker = client.app.state.upload_checker  # type: ignore[attr-defined]

        def post_slow() -> None:
            results["slow"] = client.post(
                "/api/artifacts?name=slow.btf.zip", content=slow_body, headers=OCTETS
            )

        thread = threading.Thread(target=post_slow)
        thread.start()
        try:
            _wait_for(lambda: checker.in_flight == 1, 30, "the slow check to start")
            r = client.post(
                "/api/artifacts?name=small.exr",
                content=exr_bytes(np.ones((4, 4, 3))),
                headers=OCTETS,
            )
        finally:
            thread.join(timeout=60)
        assert r.status_code == 503, r.text
        assert r.headers["retry-after"] == "1"
        assert r.json()["error"].startswith("small.exr: every file checker is busy")
        slow = results["slow"]
        assert slow.status_code == 413, slow.text
        assert slow.json()["error"].startswith(
            "slow.btf.zip: over its time budget: checking it took longer than 2 s ("
        ), slow.text
        # The pool recovers: a fresh child checks the next upload.
        r = client.post(
            "/api/artifacts?name=small.exr", content=exr_bytes(np.ones((4, 4, 3))), headers=OCTETS
        )
        assert r.status_code == 201, r.text


@pytest.mark.parametrize("http_workers", [1, 2])
def test07_sigkill_of_serve_leaves_no_checker(tmp_path: Path, http_workers: int) -> None:
    """Issue 21, item 9: after uploads, SIGKILL of ``serve`` took down neither the checker
    nor multiprocessing's resource tracker (~83 MB, under PID 1 for good). Every process
    below ``serve`` (found before the kill) must be gone within a few seconds."""
    server = start_server(tmp_path, workers=0, http_workers=http_workers)
    tree: list[int] = []
    try:
        if http_workers > 1:
            _wait_for(
                lambda: any("spawn_main" in cmdline(p) for p in descendants(server.proc.pid)),
                30,
                "the second web process",
            )
        for i in range(6):  # new connections: both web processes start checkers
            body = exr_bytes(np.full((4, 4, 3), float(i), np.float32))
            r = httpx.post(f"{server.url}/api/artifacts?name=k{i}.exr", content=body, timeout=60)
            assert r.status_code == 201, r.text
        # A checker busy with a long check (~30 s here) when serve dies: only the
        # parent-death signal ends it at once (an idle one also sees its pipe close).
        body = slices_zip(10_000)

        def post_slow() -> None:
            try:
                httpx.post(f"{server.url}/api/artifacts?name=slow.btf.zip", content=body)
            except httpx.HTTPError:  # the server is killed under it
                pass

        threading.Thread(target=post_slow, daemon=True).start()
        time.sleep(2.0)
        tree = descendants(server.proc.pid)
        # At least a checker, and the extra web process when there is one.
        assert len(tree) >= http_workers, {p: cmdline(p) for p in tree}
        os.kill(server.proc.pid, signal.SIGKILL)
        server.proc.wait(timeout=10)
        # A few seconds: the extra web process polls for its parent every 0.5 s; the rest
        # die at once (parent-death signal, closed pipes).
        _wait_for(lambda: not any(pid_alive(p) for p in tree), 5, f"{tree} to end")
    finally:
        left = [p for p in tree if pid_alive(p)]
        shown = {p: cmdline(p) for p in left}
        for p in left:
            os.kill(p, signal.SIGKILL)
        stop_server(server)
    assert shown == {}
