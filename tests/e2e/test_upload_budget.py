"""Each upload is checked within a budget: time, and the bytes its archive members inflate
to (``MATFORGE_UPLOAD_BUDGET_SECONDS``, ``MATFORGE_UPLOAD_INFLATE_RATIO``); past either, 413
with an error naming what was over. The checkers have a memory limit of their own
(``MATFORGE_UPLOAD_CHECK_MB``), set by the kernel.

Against a real ``matforge serve`` (no job workers) with the default budget:

- a 64 KB ``.btf.zip`` whose one PNG slice carries 64 MB of zeros after its header (the
  attack: 1.5 MB inflating 1.5 GB to temporary disk) is refused from its zip directory,
  before anything is inflated; it used to be accepted (201);
- a 20 KB ``.btf.zip`` whose ``angles.csv`` holds 20 million blank lines (the attack that
  held a checker for 18 s) is refused the same way;
- ``/api/health`` answers within 1 s all the while, and an ordinary archive is still 201.

The time budget is checked on an :class:`~service.upload_check.UploadChecker` with a small
one: before, running past the time limit was a 422 (:class:`CheckFailed`), now it is an
:class:`OverBudget` (413).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from service.upload_check import OverBudget, UploadChecker
from storage.errors import TooLargeError
from tests.helpers import attack_files

from .harness import Server, start_server, stop_server

OCTETS = {"content-type": "application/octet-stream"}
CHECK_MB = 640


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    srv = start_server(
        tmp_path_factory.mktemp("upload-budget"),
        workers=0,
        extra_env={"MATFORGE_UPLOAD_CHECK_MB": str(CHECK_MB)},
    )
    try:
        yield srv
    finally:
        assert stop_server(srv) == [], "processes outlived the server"


class HealthWatch:
    """Asks ``/api/health`` every 0.1 s in a thread; ``worst`` is the slowest answer."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.worst = 0.0
        self.failures: list[str] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def _loop(self) -> None:
        with httpx.Client(timeout=5.0) as http:
            while not self._stop.wait(0.1):
                t0 = time.perf_counter()
                try:
                    code = http.get(f"{self.url}/api/health").status_code
                except httpx.HTTPError as exc:
                    self.failures.append(repr(exc))
                    continue
                self.worst = max(self.worst, time.perf_counter() - t0)
                if code != 200:
                    self.failures.append(f"status {code}")

    def __enter__(self) -> HealthWatch:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


@pytest.mark.parametrize(
    ("name", "build", "member"),
    [
        ("inflating.btf.zip", lambda: attack_files.inflating_slice_zip(64 << 20), "s0.png"),
        ("blanks.btf.zip", lambda: attack_files.blank_lines_zip(20_000_000), "angles.csv"),
    ],
    ids=["member-inflates-64MB", "angles-20M-blank-lines"],
)
def test_archive_over_its_inflate_budget_is_413(
    server: Server, name: str, build: object, member: str
) -> None:
    body = build()  # type: ignore[operator]
    assert len(body) < 100_000
    with HealthWatch(server.url) as watch, server.http() as http:
        t0 = time.perf_counter()
        r = http.post("/api/artifacts", params={"name": name}, content=body, headers=OCTETS)
        took = time.perf_counter() - t0
        time.sleep(0.3)  # a health answer after the upload too
    assert r.status_code == 413, r.text
    error = r.json()["error"]
    assert error.startswith(f"{name}: over its inflated-bytes budget"), error
    assert member in error and "MATFORGE_UPLOAD_INFLATE_RATIO" in error, error
    assert took < 5.0, f"refused only after {took:.1f} s: it was inflated first"
    assert watch.failures == [] and watch.worst < 1.0, (watch.worst, watch.failures)


def test_ordinary_archive_within_its_budget(server: Server) -> None:
    with server.http() as http:
        r = http.post(
            "/api/artifacts",
            params={"name": "ok.btf.zip"},
            content=attack_files.slices_zip(40),
            headers=OCTETS,
        )
    assert r.status_code == 201, r.text


def test_checkers_run_under_their_memory_limit(server: Server) -> None:
    """The server's checker children carry ``MATFORGE_UPLOAD_CHECK_MB`` as their kernel
    data limit (``/proc/PID/limits``), and the web process does not."""
    from .harness import descendants

    with server.http() as http:  # a check starts a child
        r = http.post(
            "/api/artifacts",
            params={"name": "one.btf.zip"},
            content=attack_files.slices_zip(1),
            headers=OCTETS,
        )
        assert r.status_code == 201, r.text
    kids = [
        p
        for p in descendants(server.proc.pid)
        if "service.upload_check"
        in Path(f"/proc/{p}/cmdline").read_bytes().decode(errors="replace")
    ]
    assert kids, "no checker process"

    def data_limit(pid: int) -> str:
        for line in Path(f"/proc/{pid}/limits").read_text().splitlines():
            if line.startswith("Max data size"):
                return line.split()[3]
        raise AssertionError(f"no data limit in /proc/{pid}/limits")

    assert {data_limit(p) for p in kids} == {str(CHECK_MB << 20)}
    assert data_limit(server.proc.pid) == "unlimited"


def test_time_budget_is_413_naming_it(tmp_path: Path) -> None:
    """An archive of 3,000 slices takes longer to check than a 0.2 s budget: 413 naming
    the time budget (it was a 422 "took longer than" before), the child is replaced, and
    the next file is checked."""
    slow = tmp_path / "slow.btf.zip"
    slow.write_bytes(attack_files.slices_zip(3000))
    good = tmp_path / "good.btf.zip"
    good.write_bytes(attack_files.slices_zip(1))
    checker = UploadChecker(max_bytes=512 << 20, timeout=0.2, budget_seconds=0.2)
    try:
        with pytest.raises(OverBudget) as info:
            checker.validate(slow, "slow.btf.zip")
        assert isinstance(info.value, TooLargeError) and info.value.what == "seconds"
        assert str(info.value).startswith("slow.btf.zip: over its time budget"), info.value
        assert "MATFORGE_UPLOAD_BUDGET_SECONDS" in str(info.value)
        checker.timeout = checker.budget_seconds = 60.0
        assert checker.validate(good, "good.btf.zip") == "application/zip"
    finally:
        checker.close()


def test_budget_grows_with_the_upload() -> None:
    checker = UploadChecker(max_bytes=1 << 30, timeout=120.0, budget_seconds=10.0)
    assert checker.budget_for(0) == (10.0, 16 << 20)
    seconds, inflated = checker.budget_for(50 << 20)
    assert seconds == pytest.approx(60.0)  # 10 s plus 1 s per MiB: exact in binary
    assert inflated == 20 * (50 << 20) + (16 << 20)
    assert checker.budget_for(1 << 30)[0] == 120.0  # capped at the checker's timeout


def test_a_new_checkers_start_up_is_outside_the_time_budget(tmp_path: Path) -> None:
    """A fresh child imports its readers (numpy, onnx: seconds on a loaded machine) before
    it says it is ready; a 0.3 s budget then holds the check of a one-slice archive alone.
    When the start-up was counted, this first check was over its budget (413 under load)."""
    good = tmp_path / "good.btf.zip"
    good.write_bytes(attack_files.slices_zip(1))
    checker = UploadChecker(max_bytes=512 << 20, timeout=0.3, budget_seconds=0.3)
    try:
        assert checker.validate(good, "good.btf.zip") == "application/zip"
    finally:
        checker.close()
