"""``matforge.Client``: the REST API of a matforge server in Python, with typed answers.

It is built on the REST client the CLI uses (:class:`service.cli.client.Client`: the HTTP
plumbing, typed errors, digest-verified streaming downloads), holding one and answering
with typed objects (:mod:`matforge.objects`: :class:`~matforge.objects.Job`,
:class:`~matforge.objects.Artifact`, :class:`~matforge.objects.ResultRow`,
:class:`~matforge.objects.Kind`, each with ``.raw``, the whole document). ``matforge
submit/wait/status/ls/cancel/artifacts/fetch/results/batch/logs`` run on the same REST
client, waiting loop and batch runner.

The surface: jobs (:meth:`~Client.submit`, :meth:`~Client.get`, :meth:`~Client.list`,
:meth:`~Client.wait`, :meth:`~Client.cancel`, :meth:`~Client.logs`,
:meth:`~Client.manifest`, :meth:`~Client.batch`), artifacts (:meth:`~Client.artifacts`,
:meth:`~Client.read`, :meth:`~Client.fetch`, :meth:`~Client.upload`),
:meth:`~Client.results` and :meth:`~Client.kinds`.

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
import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any, overload

from typing_extensions import deprecated

from matforge.objects import Artifact, Job, Kind, ResultRow, Upload
from service.cli.client import (
    BadInput,
    ClientError,
    JobFailed,
    ServerRefused,
    ServerUnreachable,
    SpecError,
)
from service.cli.client import Client as RestClient

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

#: A job, wherever the client expects one: its id, a unique prefix of it, ``job:<id>``, a
#: :class:`~matforge.objects.Job` or a job document.
JobRef = str | Job | dict[str, Any]


def load_spec(spec: Any) -> dict[str, Any]:
    """A spec as a dict: a dict is returned as it is; a path (``str`` or ``Path``) to a JSON
    or YAML file is read (:func:`service.specs.load_spec_file`)."""
    if isinstance(spec, dict):
        return spec
    if isinstance(spec, str | os.PathLike):
        from service.specs import load_spec_file

        loaded: dict[str, Any] = load_spec_file(str(spec))
        return loaded
    raise BadInput(f"a spec is a dict or the path of a JSON/YAML file, not {type(spec).__name__}")


def _job_id(job: JobRef) -> str:
    if isinstance(job, Job):
        return job.id
    return str(job["id"]) if isinstance(job, dict) else str(job).removeprefix("job:")


_FULL_ID = 32

#: The names of the previous release's client, kept for one release: each warns
#: (:class:`DeprecationWarning`) and answers as before, with the plain documents. A name
#: mapped to ``None`` is the REST client's own method; another to this client's successor.
_DEPRECATED: dict[str, str | None] = {
    "status": "get",
    "ls": "list",
    "list_page": None,
    "health": None,
    "submit_created": None,
    "rename": None,
    "tag": None,
    "summary": None,
    "batch_results": None,
    "artifact": None,
    "resolve": None,
    "read_bytes": None,
    "fetch_to": None,
}


class Client:
    """A matforge server: ``Client(server=None, token=None)`` reads ``MATFORGE_SERVER`` and
    ``MATFORGE_TOKEN`` as the CLI does. Use it as a context manager, or call
    :meth:`close`. Wherever a job is expected, a job id, a unique prefix of one,
    ``job:<id>``, a :class:`~matforge.objects.Job` or a job document works.

    Examples
    --------
    >>> with matforge.Client() as mf:  # doctest: +SKIP
    ...     job = mf.wait(mf.submit({"kind": "generate.merl", "seed": 0, "params": {...}}))
    ...     table = mf.read(f"{job.ref}/materials.json")  # bytes
    ...     rows = mf.results(job)  # [ResultRow(metric=..., value=...), ...]
    """

    def __init__(
        self, server: str | None = None, token: str | None = None, timeout: float = 30.0
    ) -> None:
        self._rest = RestClient(server, token, timeout)

    @property
    def server(self) -> str:
        """The server's base URL."""
        return self._rest.server

    def close(self) -> None:
        """Close the connection pool."""
        self._rest.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- jobs ----------------------------------------------------------------------------
    def submit(self, spec: dict[str, Any] | str | os.PathLike[str]) -> Job:
        """``POST /api/jobs``: queue ``spec`` (a dict, or the path of a JSON/YAML file);
        returns the job (an identical spec already queued or done returns that job unless
        ``"force": true``). :class:`SpecError` names the bad field."""
        return Job.of(self._rest.submit_created(load_spec(spec))[0])

    def get(self, job: JobRef) -> Job:
        """``GET /api/jobs/{id}``: the job (state, progress, message, error, ...)."""
        return Job.of(self._rest.get(_job_id(job)))

    def list(
        self,
        state: str | None = None,
        kind: str | None = None,
        *,
        name: str | None = None,
        tag: str | None = None,
        batch: str | None = None,
        limit: int | None = None,
    ) -> builtins.list[Job]:
        """``GET /api/jobs``: jobs, newest first, optionally filtered by state, kind, name
        (a substring), tag or batch label; ``limit`` the most to return."""
        docs, _ = self._rest.list_page(
            state=state, kind=kind, name=name, tag=tag, batch=batch, limit=limit
        )
        return [Job.of(d) for d in docs]

    def wait(
        self,
        job: JobRef,
        progress: bool = False,
        *,
        poll: float = 0.5,
        timeout: float | None = None,
        check: bool = True,
    ) -> Job:
        """Wait until the job is finished and return it.

        ``progress=True`` shows the CLI's progress bar on stderr (not with a ``timeout``:
        that wait is silent). ``check`` (default): raise :class:`JobFailed` unless it
        succeeded. ``timeout`` (seconds): raise ``TimeoutError`` when it is still running
        then (the job keeps running). A server that restarts meanwhile is waited out for a
        while, as ``matforge wait`` does.
        """
        from service.cli.follow import Poller, wait_with_bar

        job_id = _job_id(job)
        if progress and timeout is None:
            from service.cli.state import err_console

            doc = wait_with_bar(self._rest, job_id, err_console, poll_seconds=poll)
        else:
            poller = Poller(self._rest)
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
        return Job.of(doc)

    def cancel(self, job: JobRef) -> Job:
        """``POST /api/jobs/{id}/cancel``: the job, now cancelled (or already finished)."""
        return Job.of(self._rest.cancel(_job_id(job)))

    def logs(self, job: JobRef, tail: int | None = None) -> str:
        """``GET /api/jobs/{id}/logs``: the job's log as text: each attempt's start and end,
        its progress lines and the worker's log records (``""`` before a worker started
        it); ``tail`` keeps the last lines. ``matforge logs ID`` prints the same."""
        return self._rest.logs(_job_id(job), tail)

    def manifest(self, job: JobRef) -> dict[str, Any]:
        """``GET /api/jobs/{id}/manifest``: a succeeded job's provenance (spec, artifacts,
        ``matforge_version``, code and package versions, executor, timings)."""
        result: dict[str, Any] = self._rest._json("GET", f"/api/jobs/{self._full_id(job)}/manifest")
        return result

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
            self._rest,
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

    # -- artifacts -----------------------------------------------------------------------
    def artifacts(self, job: JobRef) -> builtins.list[Artifact]:
        """``GET /api/jobs/{id}/artifacts``: the job's artifacts (name, digest, size, media
        type)."""
        return [Artifact.of(a) for a in self._rest.artifacts(self._full_id(job))]

    def read(self, ref: str | Artifact, *, max_bytes: int | None = None) -> bytes:
        """An artifact's bytes, by ``job:<id>/<name>``, ``sha256:<hex>`` or
        :class:`~matforge.objects.Artifact`, verified against its digest (a mismatch
        raises :class:`ServerUnreachable`); more than ``max_bytes`` (default: no limit):
        :class:`BadInput`."""
        limit = 1 << 62 if max_bytes is None else max_bytes
        return self._rest.read_bytes(self._digest(ref), max_bytes=limit)

    @overload
    @deprecated("Client.fetch(ref) without a destination: use Client.read(ref)")
    def fetch(self, ref: str | Artifact, dest: None = None, mode: int = 0o644) -> bytes: ...

    @overload
    def fetch(
        self, ref: str | Artifact, dest: str | os.PathLike[str], mode: int = 0o644
    ) -> int: ...

    def fetch(
        self,
        ref: str | Artifact,
        dest: str | os.PathLike[str] | None = None,
        mode: int = 0o644,
    ) -> int | bytes:
        """An artifact (by ``job:<id>/<name>``, ``sha256:<hex>`` or
        :class:`~matforge.objects.Artifact`) written to the file ``dest`` atomically, only
        once its bytes matched the digest; returns the size. A mismatch raises
        :class:`ServerUnreachable`. A symbolic link at ``dest`` is never written through nor
        replaced (one to a FIFO or a terminal is written in place): :class:`BadInput`, with
        nothing written. Without ``dest`` (deprecated: use :meth:`read`) the bytes."""
        if dest is None:
            warnings.warn(
                "Client.fetch(ref) without a destination is deprecated and goes in the next "
                "release: use Client.read(ref) for the bytes",
                DeprecationWarning,
                stacklevel=2,
            )
            return self.read(ref)
        return self._rest.fetch(self._digest(ref), Path(dest), mode)

    def upload(self, path: str | os.PathLike[str], name: str | None = None) -> Upload:
        """``POST /api/artifacts``: stream a file (a model file, an ONNX model, an EXR, a
        MERL ``.binary``, ...) to the server, which validates and stores it; its ``ref``
        (``sha256:<digest>``) is usable in job specs."""
        return Upload.of(self._rest.upload(Path(path), name))

    # -- results and kinds ---------------------------------------------------------------
    def results(
        self,
        jobs: JobRef | os.PathLike[str] | Iterable[JobRef | os.PathLike[str]] | None = None,
        **filters: Any,
    ) -> builtins.list[ResultRow]:
        """Result rows (``GET /api/results``), one per measured value: of ``jobs`` (a job,
        a list of jobs, or the path of a batch file, whose steps' rows come in step order,
        each naming its ``step``), or with ``None`` of every succeeded job. ``filters``:
        ``kind``, ``dataset``, ``metric`` (list), ``candidate``, ``scene``."""
        from service.cli.results_command import _batch_steps, is_batch_file

        if jobs is None:
            return [ResultRow.of(r) for r in self._rest.results(filters)]
        items: builtins.list[Any] = (
            [jobs] if isinstance(jobs, str | dict | Job | os.PathLike) else builtins.list(jobs)
        )
        rows: builtins.list[ResultRow] = []
        for item in items:
            if isinstance(item, os.PathLike) or (isinstance(item, str) and is_batch_file(item)):
                doc = self._rest.batch_results(_batch_steps(Path(item)), filters)
                rows += [ResultRow.of(r) for r in doc.get("rows") or []]
            else:
                got = self._rest.results({**filters, "job": [self._full_id(item)]})
                rows += [ResultRow.of(r) for r in got]
        return rows

    def kinds(self) -> builtins.list[Kind]:
        """``GET /api/kinds``: every registered kind with its summary, artifact names and
        params schema."""
        return [Kind.of(k) for k in self._rest.kinds()]

    # -- plumbing ------------------------------------------------------------------------
    def _full_id(self, job: JobRef) -> str:
        """The full id of a job given by id, unique prefix, ``job:<id>`` or document."""
        job_id = _job_id(job)
        return job_id if len(job_id) == _FULL_ID else str(self._rest.get(job_id)["id"])

    def _digest(self, ref: str | Artifact) -> str:
        return ref.digest if isinstance(ref, Artifact) else self._rest.resolve(ref)

    if not TYPE_CHECKING:  # type checkers flag the deprecated names; they still run

        def __getattr__(self, name: str) -> Any:
            if name not in _DEPRECATED:
                raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
            successor = _DEPRECATED[name]
            use = f"Client.{successor}" if successor else "the methods listed in help(Client)"
            warnings.warn(
                f"Client.{name} is deprecated and goes in the next release: use {use}",
                DeprecationWarning,
                stacklevel=2,
            )
            if successor is None:
                return getattr(self._rest, name)
            return getattr(self, successor)
