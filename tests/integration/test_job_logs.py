"""A job's log through the runs that write it and the three ways to read it.

Oracles: the job documents (attempt, state, error) the log must agree with; the log file
read directly; ``GET /api/jobs/{id}/logs`` against the CLI's ``matforge logs --data-dir``."""

from __future__ import annotations

import logging
import subprocess
import sys

from fastapi.testclient import TestClient

from jobapi.context import JobContext
from service.api import create_app
from service.submission import run_in_process
from storage.job_logs import JobLog, log_dir


def test01_a_run_logs_its_attempt_progress_records_and_end(toy_kind, settings) -> None:
    runner = toy_kind.runner

    def noisy(params, ctx: JobContext) -> None:
        logging.getLogger("generators.toy").warning("a warning from the runner")
        runner(params, ctx)

    object.__setattr__(toy_kind, "runner", noisy)
    job = run_in_process({"kind": "toy", "params": {"n": 3}}, settings)
    assert job.state == "succeeded"
    text = JobLog(log_dir(settings.data_dir), job.id).read()
    lines = [ln.split(" ", 1)[1] for ln in text.splitlines()]
    assert lines[0].startswith(f"attempt {job.attempts}: toy on worker ")
    assert "WARNING generators.toy: a warning from the runner" in lines
    assert any(ln.startswith("progress ") and "toy" in ln for ln in lines), lines
    assert lines[-1] == f"attempt {job.attempts}: succeeded"

    failed = run_in_process({"kind": "toy", "params": {"fail": True}}, settings)
    assert failed.state == "failed"
    last = JobLog(log_dir(settings.data_dir), failed.id).read(1)
    assert last.rstrip().endswith(f"attempt 1: failed: {failed.error}")


def test02_rest_and_cli_read_the_same_log(toy_kind, settings) -> None:
    job = run_in_process({"kind": "toy", "params": {"n": 2}}, settings)
    whole = JobLog(log_dir(settings.data_dir), job.id).read()
    assert whole
    with TestClient(create_app(settings)) as client:
        r = client.get(f"/api/jobs/{job.id[:8]}/logs")
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain")
        assert r.text == whole
        assert client.get(f"/api/jobs/{job.id}/log").text == whole  # the singular spelling
        assert (
            client.get(f"/api/jobs/{job.id}/logs", params={"tail": 1}).text
            == (whole.splitlines(keepends=True)[-1])
        )
        assert client.get(f"/api/jobs/{job.id}/logs", params={"tail": -1}).status_code == 422
        assert client.get(f"/api/jobs/{'e' * 32}/logs").status_code == 404
    out = subprocess.run(
        [sys.executable, "-m", "service.cli.main", "logs", job.id[:8], "--tail", "1",
         "--data-dir", str(settings.data_dir)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert out.stdout == whole.splitlines(keepends=True)[-1]


def test03_a_crash_leaves_its_full_traceback_in_the_log(toy_kind, settings) -> None:
    """The job's ``error`` is one line; its log has the whole traceback (as ``ray job
    logs`` would), from the crash record the executor logs."""

    def crash(params, ctx: JobContext) -> None:
        raise RuntimeError("boom in the runner")

    object.__setattr__(toy_kind, "runner", crash)
    job = run_in_process({"kind": "toy", "params": {"n": 1}}, settings)
    assert job.state == "failed" and "\n" not in (job.error or "")
    text = JobLog(log_dir(settings.data_dir), job.id).read()
    assert "Traceback (most recent call last):" in text
    assert "RuntimeError: boom in the runner" in text and "in crash" in text
    assert text.rstrip().endswith(f"attempt 1: failed: {job.error}")


def test04_a_traceback_names_files_without_the_servers_folders(toy_kind, settings) -> None:
    """Frames are named relative to the package root (``service/workers/execution.py``),
    the standard library's or ``site-packages``' folder; a path in the data directory
    reads ``<data-dir>``. The log used to carry the server's absolute paths; the traceback
    itself stays (the contract: a crash's traceback is in the log)."""
    from storage.job_logs import PACKAGE_ROOT

    where = settings.data_dir / "store" / "objects" / "ab"

    def crash(params, ctx: JobContext) -> None:
        import json

        try:
            json.loads("{")  # a frame in the standard library
        except ValueError as exc:
            raise RuntimeError(f"boom reading {where}") from exc

    object.__setattr__(toy_kind, "runner", crash)
    job = run_in_process({"kind": "toy", "params": {"n": 1}}, settings)
    assert job.state == "failed"
    with TestClient(create_app(settings)) as client:
        text = client.get(f"/api/jobs/{job.id}/logs").text
    assert "Traceback (most recent call last):" in text
    assert 'File "service/workers/execution.py", line ' in text, text
    assert 'File "tests/integration/test_job_logs.py", line ' in text, text
    assert 'File "json/decoder.py", line ' in text, text
    assert "RuntimeError: boom reading <data-dir>/store/objects/ab" in text, text
    for folder in (PACKAGE_ROOT, settings.data_dir.resolve(), sys.prefix, sys.base_prefix):
        assert f"{folder}/" not in text, (folder, text)
