"""``matforge.Client``: the REST API of a matforge server in Python.

It is the CLI's own client (:class:`service.cli.client.Client`: the HTTP plumbing, typed
errors, digest-verified streaming downloads) with what a script wants on top: specs from
files, waiting (with the CLI's progress bar, or silently), artifacts by ``job:``/``sha256:``
ref, result rows, batches and job logs. ``matforge submit/wait/status/ls/cancel/artifacts/
fetch/results/batch/logs`` call the same code.

Errors (all :class:`ClientError`, ``str(err)`` one line):

- :class:`SpecError`: the server rejected a spec (422); ``err.errors`` lists ``(field,
  message)``, ``err.field`` the first field;
- :class:`JobFailed`: a job waited for failed or was cancelled (``err.job`` its document);
- :class:`ServerUnreachable`: no connection, a timeout, refused credentials
  (:class:`ServerRefused`) or a 5xx;
- :class:`BadInput`: any other request the server refused (404 for an unknown job, ...).
"""

from __future__ import annotations

import builtins
import os
import time
from pathlib import Path
from typing import Any, overload

from service.cli.client import (
    BadInput,
    ClientError,
    JobFailed,
    ServerRefused,
    ServerUnreachable,
    SpecError,
)
from service.cli.client import Client as _RestClient

__all__ = [
    "BadInput",
    "Client",
    "ClientError",
    "JobFailed",
    "ServerRefused",
    "ServerUnreachable",
    "SpecError",
]

FINAL_STATES = frozenset({"succeeded", "failed", "cancelled"})


def load_spec(spec: Any) -> Any:
    """A spec as a dict: a dict is returned as it is; a path (``str`` or ``Path``) to a JSON
    or YAML file is read (:func:`service.specs.load_spec_file`)."""
    if isinstance(spec, dict):
        return spec
    if isinstance(spec, str | os.PathLike):
        from service.specs import load_spec_file

        return load_spec_file(str(spec))
    raise BadInput(f"a spec is a dict or the path of a JSON/YAML file, not {type(spec).__name__}")


def _job_id(job: str | dict[str, Any]) -> str:
    return str(job["id"]) if isinstance(job, dict) else str(job).removeprefix("job:")


_FULL_ID = 32


class Client(_RestClient):
    """A matforge server: ``Client(server=None, token=None)`` reads ``MATFORGE_SERVER`` and
    ``MATFORGE_TOKEN`` as the CLI does. Use it as a context manager, or call
    :meth:`close`. Wherever a job is expected, a job id, a unique prefix of one,
    ``job:<id>`` or a job document works.

    Examples
    --------
    >>> with matforge.Client() as mf:  # doctest: +SKIP
    ...     job = mf.submit({"kind": "generate.merl", "seed": 0, "params": {...}})
    ...     job = mf.wait(job, progress=True)
    ...     table = mf.fetch(f"job:{job['id']}/materials.json")  # bytes
    """

    def submit(self, spec: Any) -> dict[str, Any]:
        """``POST /api/jobs``: queue ``spec`` (a dict, or the path of a JSON/YAML file);
        returns the job document (an identical spec already queued or done returns that
        job unless ``"force": true``). :class:`SpecError` names the bad field."""
        return self.submit_created(load_spec(spec))[0]

    def status(self, job: str | dict[str, Any]) -> dict[str, Any]:
        """``GET /api/jobs/{id}``: the job document (state, progress, message, error, ...)."""
        return self.get(_job_id(job))

    def ls(
        self,
        state: str | None = None,
        kind: str | None = None,
        *,
        name: str | None = None,
        limit: int | None = None,
    ) -> builtins.list[dict[str, Any]]:
        """``GET /api/jobs``: job documents, newest first, optionally filtered."""
        return self.list_page(state=state, kind=kind, name=name, limit=limit)[0]

    def wait(
        self,
        job: str | dict[str, Any],
        progress: bool = False,
        *,
        poll: float = 0.5,
        timeout: float | None = None,
        check: bool = True,
    ) -> dict[str, Any]:
        """Wait until the job is finished and return its final document.

        ``progress=True`` shows the CLI's progress bar on stderr (not with a ``timeout``:
        that wait is silent). ``check`` (default):
        raise :class:`JobFailed` unless it succeeded. ``timeout`` (seconds): raise
        ``TimeoutError`` when it is still running then (the job keeps running). A server
        that restarts meanwhile is waited out for a while, as ``matforge wait`` does.
        """
        from service.cli.follow import Poller, wait_with_bar

        job_id = _job_id(job)
        if progress and timeout is None:
            from service.cli.state import err_console

            doc = wait_with_bar(self, job_id, err_console, poll_seconds=poll)
        else:
            poller = Poller(self)
            deadline = None if timeout is None else time.monotonic() + timeout
            while True:
                got = poller.poll(job_id)
                if got is not None and got.get("state") in FINAL_STATES:
                    doc = got
                    break
                if deadline is not None and time.monotonic() > deadline:
                    raise TimeoutError(f"job {job_id} still not finished after {timeout} s")
                time.sleep(poll)
        if check and doc.get("state") != "succeeded":
            raise JobFailed(doc)
        return doc

    def manifest(self, job: str | dict[str, Any]) -> dict[str, Any]:
        """``GET /api/jobs/{id}/manifest``: a succeeded job's provenance (spec, artifacts,
        ``matforge_version``, code and package versions, executor, timings)."""
        result: dict[str, Any] = self._json("GET", f"/api/jobs/{self._full_id(job)}/manifest")
        return result

    def cancel(self, job: str | dict[str, Any]) -> dict[str, Any]:
        """``POST /api/jobs/{id}/cancel``: the job, now cancelled (or already finished)."""
        return super().cancel(_job_id(job))

    def logs(self, job: str | dict[str, Any], tail: int | None = None) -> str:
        """``GET /api/jobs/{id}/logs``: the job's log as text: each attempt's start and end,
        its progress lines and the worker's log records (``""`` before a worker started
        it); ``tail`` keeps the last lines. ``matforge logs ID`` prints the same."""
        return super().logs(_job_id(job), tail)

    def artifacts(self, job: str | dict[str, Any]) -> builtins.list[dict[str, Any]]:
        """``GET /api/jobs/{id}/artifacts``: ``[{"name", "digest", "size", "media_type"}]``."""
        return super().artifacts(self._full_id(job))

    def _full_id(self, job: str | dict[str, Any]) -> str:
        """The full id of a job given by id, unique prefix, ``job:<id>`` or document."""
        job_id = _job_id(job)
        return job_id if len(job_id) == _FULL_ID else str(self.get(job_id)["id"])

    @overload
    def fetch(self, ref: str, dest: None = None, mode: int = 0o644) -> bytes: ...

    @overload
    def fetch(self, ref: str, dest: str | os.PathLike[str], mode: int = 0o644) -> int: ...

    def fetch(self, ref: str, dest: str | os.PathLike[str] | None = None, mode: int = 0o644) -> Any:
        """An artifact, by ``job:<id>/<name>`` or ``sha256:<hex>``: its bytes (``dest``
        ``None``), or written to the file ``dest`` atomically, only once its bytes matched
        the digest (returns the size). A mismatch raises :class:`ServerUnreachable`. A
        symbolic link at ``dest`` is never written through nor replaced (one to a FIFO or
        a terminal is written in place): :class:`BadInput`, with nothing written."""
        digest = self.resolve(ref)
        if dest is None:
            return self.read_bytes(digest, max_bytes=1 << 62)
        return super().fetch(digest, Path(dest), mode)

    def results(  # type: ignore[override]
        self, jobs: Any = None, **filters: Any
    ) -> builtins.list[dict[str, Any]]:
        """Result rows (``GET /api/results``), one per measured value: of ``jobs`` (a job,
        a list of jobs, or the path of a batch file, whose steps' rows come in step order),
        or with ``None`` of every succeeded job. ``filters``: ``kind``, ``dataset``,
        ``metric`` (list), ``candidate``, ``scene``."""
        from service.cli.results_command import _batch_steps, is_batch_file

        if isinstance(jobs, dict) and "id" not in jobs:  # the REST client's results(params)
            return super().results({**jobs, **filters})
        if jobs is None:
            return super().results(filters)
        items = [jobs] if isinstance(jobs, str | dict | os.PathLike) else list(jobs)
        rows: builtins.list[dict[str, Any]] = []
        for item in items:
            if isinstance(item, os.PathLike) or (isinstance(item, str) and is_batch_file(item)):
                doc = self.batch_results(_batch_steps(Path(item)), filters)
                rows += builtins.list(doc.get("rows") or [])
            else:
                rows += super().results({**filters, "job": [self._full_id(item)]})
        return rows

    def batch(
        self,
        file: str | os.PathLike[str],
        progress: bool = False,
        *,
        parallel: int = 1,
        continue_on_error: bool = False,
        poll: float = 0.5,
    ) -> builtins.list[dict[str, Any]]:
        """Run a batch file (``matforge batch``) on the server: one row per step
        (``step``, ``kind``, ``job_id``, ``state``, ``seconds``, ``error`` and the step's
        metrics). ``progress=True`` shows the bars on stderr. Raises :class:`JobFailed`
        (the first failed step's document) when a step failed or was cancelled."""
        import io

        from rich.console import Console

        from service.cli.batch import load_batch
        from service.cli.batch_run import run_batch
        from service.cli.results import result_rows
        from service.cli.state import err_console

        console = err_console if progress else Console(file=io.StringIO())
        outcome = run_batch(
            load_batch(Path(file)),
            self,
            console,
            poll_seconds=poll,
            parallel=parallel,
            continue_on_error=continue_on_error,
        )
        _, rows = result_rows(outcome.results)
        for r in outcome.results:
            if r.state in ("failed", "cancelled"):
                raise JobFailed({"id": r.job_id, "state": r.state, "error": r.error, "rows": rows})
            if r.state == "error":
                raise BadInput(f"batch {file}: step {r.step!r}: {r.error}")
        return rows
