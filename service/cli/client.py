"""The typed HTTP client of the matforge REST API: the one implementation under the CLI,
the batch runner and the public :class:`matforge.Client` (which holds one, and answers
with typed objects built from the server's response models).

Every failure is one of these types, which the CLI maps to the contract's exit codes:

- :class:`ServerUnreachable` (exit 3): the connection was refused or timed out, the name did
  not resolve, the server refused the credentials (401/403, :class:`ServerRefused`), or it
  answered with a 5xx.
- :class:`CorruptObject` (exit 1): the server's copy of an object is damaged on disk.
- :class:`BadInput` (exit 2): the server rejected what we sent (400, 404, 413, 422), with the
  server's one-line ``error`` message; or the input was malformed before anything was sent.
  :class:`SpecError` (exit 2) is the 422 of a rejected spec, with the fields it names.
- :class:`JobFailed` (exit 1): a job that was waited for failed or was cancelled.
"""

from __future__ import annotations

import builtins
import hashlib
import os
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, BinaryIO

import httpx

JOB_ID = re.compile(r"^[0-9a-f]{32}\Z")
JOB_ID_PREFIX = re.compile(r"^[0-9a-f]{1,32}\Z")
DIGEST = re.compile(r"^[0-9a-f]{64}\Z")
_CHUNK = 1 << 20


class ClientError(Exception):
    """Base of the client's errors; ``str(err)`` is one line a user can act on."""

    exit_code = 1


class ServerUnreachable(ClientError):
    """No usable answer from the server: connection, timeout, refused credentials, 5xx."""

    exit_code = 3


class ServerRefused(ServerUnreachable):
    """The server refused our credentials (401/403): ``MATFORGE_TOKEN`` is missing or wrong.
    Exit 3, like an unreachable server, but retrying does not help."""


class CorruptObject(ClientError):
    """The server holds the object but its bytes are damaged (a 500 marked
    ``X-Matforge-Error: integrity``). Exit 1: the data failed, the server did not."""

    exit_code = 1


class BadInput(ClientError):
    """The server rejected the request as bad input (or it was malformed before sending).

    ``status`` is the HTTP status (``None`` when the request was never sent) and ``detail``
    the server's structured ``detail`` field when it gave one.
    """

    exit_code = 2

    def __init__(self, message: str, status: int | None = None, detail: Any = None) -> None:
        super().__init__(message)
        self.status = status
        self.detail = detail


class SpecError(BadInput):
    """The server rejected a job spec (HTTP 422). ``errors`` lists ``(field, message)``
    pairs, e.g. ``("params.spp", "Input should be greater than or equal to 1")``;
    ``field`` is the first field named."""

    def __init__(self, message: str, errors: list[tuple[str, str]], detail: Any = None) -> None:
        super().__init__(message, status=422, detail=detail)
        self.errors = errors

    @property
    def field(self) -> str | None:
        """The first field the server named (``None`` when it named none)."""
        return next((loc for loc, _ in self.errors if loc), None)

    @classmethod
    def from_bad_input(cls, exc: BadInput) -> SpecError:
        """The :class:`SpecError` of a 422 :class:`BadInput` (its ``detail`` list)."""
        errors: list[tuple[str, str]] = []
        if isinstance(exc.detail, list):
            for item in exc.detail:
                if isinstance(item, dict):
                    loc = ".".join(str(p) for p in item.get("loc", ()) if p != "body")
                    errors.append((loc, str(item.get("msg", item))))
        return cls(str(exc), errors or [("", str(exc))], exc.detail)


class JobFailed(ClientError):
    """A job that was waited for ended ``failed`` or ``cancelled``; ``job`` is its final
    document (``job["error"]`` the one-line reason)."""

    exit_code = 1

    def __init__(self, job: dict[str, Any]) -> None:
        reason = job.get("error") or job.get("state")
        super().__init__(f"job {job.get('id')} {job.get('state')}: {reason}")
        self.job = job


def check_job_id(job_id: str) -> str:
    """Return ``job_id`` if it is a job id or a prefix of one (1 to 32 lowercase hex digits;
    the server resolves a unique prefix, as git does), else raise :class:`BadInput`."""
    if not JOB_ID_PREFIX.match(job_id):
        raise BadInput(
            f"not a job id: {job_id!r} (expected 32 lowercase hex digits, or a unique prefix)"
        )
    return job_id


def check_digest(digest: str) -> str:
    """Return the 64-hex digest of ``digest`` (``sha256:`` prefix optional) or raise."""
    d = digest.removeprefix("sha256:")
    if not DIGEST.match(d):
        raise BadInput(f"not a sha256 digest: {digest!r} (expected 64 lowercase hex digits)")
    return d


def _one_line(text: str) -> str:
    return " ".join(text.split())


def error_message(response: httpx.Response) -> str:
    """The server's one-line ``error`` of a failed response (or a description of it)."""
    try:
        body = response.json()
    except ValueError:
        body = None
    if isinstance(body, dict):
        if isinstance(body.get("error"), str) and body["error"].strip():
            return _one_line(body["error"])
        detail = body.get("detail")
        if isinstance(detail, str) and detail.strip():
            return _one_line(detail)
        if isinstance(detail, list) and detail:
            parts = []
            for item in detail:
                if isinstance(item, dict):
                    loc = ".".join(str(p) for p in item.get("loc", ()) if p != "body")
                    msg = str(item.get("msg", item))
                    parts.append(f"{loc}: {msg}" if loc else msg)
                else:
                    parts.append(str(item))
            return _one_line("; ".join(parts))
    text = _one_line(response.text)[:300]
    return f"HTTP {response.status_code} {response.reason_phrase}" + (f": {text}" if text else "")


class Client:
    """The REST API of one matforge server.

    Args:
        server: base URL, e.g. ``http://127.0.0.1:8000`` (default: ``MATFORGE_SERVER``, as
            the CLI reads it, else ``http://127.0.0.1:8000``).
        token: bearer token (default: ``MATFORGE_TOKEN`` when ``server`` is not given
            either), or ``None`` for a server without auth.
        timeout: seconds for connecting and for each read; transfers stream, so a large
            download is not bounded by it as a whole.
    """

    def __init__(
        self, server: str | None = None, token: str | None = None, timeout: float = 30.0
    ) -> None:
        if server is None:
            from service.settings import Settings

            settings = Settings.from_env()
            server, token = settings.server, token if token is not None else settings.token
        self.server = server.rstrip("/")
        headers = {"Accept": "application/json"}
        if token:
            headers["Authorization"] = f"Bearer {token}"
        try:
            self._http = httpx.Client(
                base_url=self.server,
                headers=headers,
                timeout=httpx.Timeout(timeout, connect=min(timeout, 10.0)),
            )
        except (httpx.InvalidURL, ValueError) as exc:
            raise BadInput(f"bad server URL {server!r}: {exc}") from None

    # -- plumbing ------------------------------------------------------------------------
    def close(self) -> None:
        """Close the connection pool."""
        self._http.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _check(self, response: httpx.Response) -> httpx.Response:
        code = response.status_code
        if code < 400:
            return response
        if code in (401, 403):
            raise ServerRefused(
                f"{self.server} refused the request (HTTP {code}): "
                f"{error_message(response)}; check MATFORGE_TOKEN"
            )
        if code >= 500 and response.headers.get("x-matforge-error") == "integrity":
            raise CorruptObject(
                f"{error_message(response)} (on the server at {self.server}; "
                "'matforge store verify --repair' there restores it where it can)"
            )
        if code >= 500:
            raise ServerUnreachable(
                f"{self.server} failed (HTTP {code}): {error_message(response)}"
            )
        detail = None
        try:
            body = response.json()
            detail = body.get("detail") if isinstance(body, dict) else None
        except ValueError:
            pass
        raise BadInput(error_message(response), status=code, detail=detail)

    def _request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        try:
            response = self._http.request(method, path, **kwargs)
        except httpx.TimeoutException:
            raise ServerUnreachable(f"{self.server} did not answer in time") from None
        except httpx.UnsupportedProtocol as exc:
            raise BadInput(f"bad server URL {self.server!r}: {exc}") from None
        except httpx.TransportError as exc:
            raise ServerUnreachable(
                f"cannot reach the server at {self.server}: "
                f"{_one_line(str(exc)) or type(exc).__name__}"
            ) from None
        return self._check(response)

    def _json(self, method: str, path: str, **kwargs: Any) -> Any:
        response = self._request(method, path, **kwargs)
        try:
            return response.json()
        except ValueError:
            raise ServerUnreachable(
                f"{self.server} answered {path} with something that is "
                "not JSON; is this a matforge server?"
            ) from None

    # -- the API -------------------------------------------------------------------------
    def health(self) -> dict[str, Any]:
        """``GET /api/health``: ``{"status": "ok"}``."""
        result: dict[str, Any] = self._json("GET", "/api/health")
        return result

    def submit(self, spec: Any) -> dict[str, Any]:
        """``POST /api/jobs``: queue a spec; returns the job document."""
        return self.submit_created(spec)[0]

    def submit_created(self, spec: Any) -> tuple[dict[str, Any], bool]:
        """``POST /api/jobs``: ``(job document, created)``; ``created`` is false when the
        server returned an existing job of the identical spec (HTTP 200, not 201)."""
        try:
            response = self._request("POST", "/api/jobs", json=spec)
        except BadInput as exc:
            if exc.status == 422 and isinstance(exc.detail, list):
                raise SpecError.from_bad_input(exc) from None
            raise
        try:
            doc: dict[str, Any] = response.json()
        except ValueError:
            raise ServerUnreachable(
                f"{self.server} answered /api/jobs with something that is not JSON"
            ) from None
        return doc, response.status_code == 201

    def get(self, job_id: str) -> dict[str, Any]:
        """``GET /api/jobs/{id}``: the job document."""
        result: dict[str, Any] = self._json("GET", f"/api/jobs/{check_job_id(job_id)}")
        return result

    def list(
        self, state: str | None = None, kind: str | None = None
    ) -> builtins.list[dict[str, Any]]:
        """``GET /api/jobs``: jobs, newest first, optionally filtered."""
        return self.list_page(state=state, kind=kind)[0]

    def list_page(
        self,
        *,
        state: str | None = None,
        kind: str | None = None,
        name: str | None = None,
        sort: str | None = None,
        limit: int | None = None,
        offset: int = 0,
        columns: Sequence[str] = (),
        filters: Sequence[str] = (),
        tag: str | None = None,
        batch: str | None = None,
    ) -> tuple[builtins.list[dict[str, Any]], int | None]:
        """``GET /api/jobs``: one page of jobs and how many match in all (``None`` when the
        server does not say). ``columns`` (``params.<path>``, ``metric.<name>``) adds each
        job's values as its ``columns``; ``filters`` (``params.model=hybrid``,
        ``metric.brdf.smape<0.1``) keeps the jobs that pass all of them."""
        query: dict[str, Any] = {
            "state": state,
            "kind": kind,
            "name": name,
            "sort": sort,
            "limit": limit,
            "offset": offset or None,
            "columns": builtins.list(columns) or None,
            "filter": builtins.list(filters) or None,
            "tag": tag,
            "batch": batch,
        }
        params = {k: v for k, v in query.items() if v is not None and v != ""}
        response = self._request("GET", "/api/jobs", params=params)
        try:
            result = response.json()
        except ValueError:
            raise ServerUnreachable(f"{self.server} answered /api/jobs with non-JSON") from None
        if isinstance(result, dict) and isinstance(result.get("jobs"), list):
            result = result["jobs"]
        total = response.headers.get("x-total-count")
        return builtins.list(result), int(total) if total and total.isdigit() else None

    def kinds(self) -> builtins.list[dict[str, Any]]:
        """``GET /api/kinds``: every kind with its summary, artifacts and params schema."""
        return builtins.list(self._json("GET", "/api/kinds"))

    def cancel(self, job_id: str) -> dict[str, Any]:
        """``POST /api/jobs/{id}/cancel``: the job, now cancelled (or already finished)."""
        result: dict[str, Any] = self._json("POST", f"/api/jobs/{check_job_id(job_id)}/cancel")
        return result

    def rename(self, job_id: str, name: str | None) -> dict[str, Any]:
        """``PATCH /api/jobs/{id}``: give the job a new name (``None``: no name)."""
        body = {"name": name or ""}
        result: dict[str, Any] = self._json("PATCH", f"/api/jobs/{check_job_id(job_id)}", json=body)
        return result

    def tag(
        self, job_id: str, add: Sequence[str] = (), remove: Sequence[str] = ()
    ) -> dict[str, Any]:
        """``PATCH /api/jobs/{id}``: add and remove tags; the job, with its ``tags``."""
        body = {"add_tags": builtins.list(add), "remove_tags": builtins.list(remove)}
        result: dict[str, Any] = self._json("PATCH", f"/api/jobs/{check_job_id(job_id)}", json=body)
        return result

    def logs(self, job_id: str, tail: int | None = None) -> str:
        """``GET /api/jobs/{id}/logs``: the job's log as text (``""`` before a worker
        started it); ``tail``: only its last lines."""
        params = {} if tail is None else {"tail": tail}
        response = self._request("GET", f"/api/jobs/{check_job_id(job_id)}/logs", params=params)
        return response.text

    def summary(self, job_id: str) -> dict[str, Any] | None:
        """``GET /api/jobs/{id}/summary``: the job's result table document, or ``None``."""
        result: dict[str, Any] | None = self._json(
            "GET", f"/api/jobs/{check_job_id(job_id)}/summary"
        )
        return result

    def results(self, params: dict[str, Any]) -> builtins.list[dict[str, Any]]:
        """``GET /api/results``: result rows (``params`` are its query parameters)."""
        return builtins.list(self._json("GET", "/api/results", params=params))

    def batch_results(self, steps: Any, params: dict[str, Any]) -> dict[str, Any]:
        """``POST /api/results/batch``: ``{"steps", "rows"}`` of a batch's steps."""
        result: dict[str, Any] = self._json(
            "POST", "/api/results/batch", json={"steps": steps}, params=params
        )
        return result

    def artifacts(self, job_id: str) -> builtins.list[dict[str, Any]]:
        """``GET /api/jobs/{id}/artifacts``: ``[{"name", "digest", "size", "media_type"}]``."""
        result = self._json("GET", f"/api/jobs/{check_job_id(job_id)}/artifacts")
        return builtins.list(result)

    def artifact(self, job_id: str, name: str) -> dict[str, Any]:
        """The record of artifact ``name`` of a job; :class:`BadInput` if it has none."""
        arts = self.artifacts(job_id)
        for art in arts:
            if art.get("name") == name:
                return art
        have = ", ".join(a.get("name", "?") for a in arts) or "none"
        raise BadInput(f"job {job_id} has no artifact {name!r} (artifacts: {have})")

    def resolve(self, ref: str) -> str:
        """The 64-hex digest of ``sha256:<hex>``, a bare digest, or ``job:<id>/<name>`` (an
        artifact of a job; the id may be a unique prefix)."""
        if ref.startswith("job:"):
            job, sep, name = ref[4:].partition("/")
            if not sep or not name:
                raise BadInput(f"{ref!r}: an artifact ref is job:<id>/<artifact name>")
            return str(self.artifact(str(self.get(job)["id"]), name)["digest"])
        return check_digest(ref)

    def read_bytes(self, digest: str, max_bytes: int = 64 * 1024 * 1024) -> bytes:
        """``GET /api/artifacts/{digest}`` into memory (small objects such as metrics),
        verified against the digest."""
        d = check_digest(digest)
        data = self._request("GET", f"/api/artifacts/{d}").content
        if len(data) > max_bytes:
            raise BadInput(f"sha256:{d} is {len(data)} bytes; fetch it to a file instead")
        if hashlib.sha256(data).hexdigest() != d:
            raise ServerUnreachable(
                f"the bytes received for sha256:{d} do not match the "
                "digest (corrupt transfer); try again"
            )
        return data

    def _stream(self, d: str, write: Callable[[bytes], object]) -> int:
        """Stream ``GET /api/artifacts/{d}`` into ``write``; raises
        :class:`ServerUnreachable` after the last chunk when the bytes do not hash to ``d``."""
        h, size = hashlib.sha256(), 0
        try:
            with self._http.stream("GET", f"/api/artifacts/{d}") as response:
                if response.status_code >= 400:
                    response.read()
                    self._check(response)
                for chunk in response.iter_bytes(_CHUNK):
                    h.update(chunk)
                    size += len(chunk)
                    write(chunk)
        except httpx.TimeoutException:
            raise ServerUnreachable(f"{self.server} did not answer in time") from None
        except httpx.TransportError as exc:
            raise ServerUnreachable(
                f"download of sha256:{d} from {self.server} failed: {_one_line(str(exc))}"
            ) from None
        if h.hexdigest() != d:
            raise ServerUnreachable(
                f"the bytes received for sha256:{d} do not match the "
                "digest (corrupt transfer); try again"
            )
        return size

    def fetch(self, digest: str, dest: Path, mode: int = 0o644) -> int:
        """Download an object to ``dest``; returns the size in bytes.

        The bytes are hashed as they arrive and reach ``dest`` only once verified: a regular
        file is written atomically (a temporary file beside it, renamed once the digest
        matched) with ``mode`` (the CLI passes the one the user's umask gives new files); a
        FIFO or a terminal is written in place, never renamed over; a block device or a
        socket is refused with :class:`BadInput` (:mod:`service.cli.fetch_output`).
        """
        from service.cli.fetch_output import write_verified

        d = check_digest(digest)
        return write_verified(dest, lambda write: self._stream(d, write), mode=mode)

    def fetch_to(self, digest: str, out: BinaryIO) -> int:
        """Download an object to an open binary stream (``fetch -o -``); nothing is written
        to ``out`` unless the bytes match the digest (they are verified first, in memory or
        a temporary file)."""
        from service.cli.fetch_output import write_stream

        d = check_digest(digest)
        return write_stream(lambda write: self._stream(d, write), out)

    def upload(self, path: Path, name: str | None = None) -> dict[str, Any]:
        """``POST /api/artifacts?name=``: stream a file to the server, which validates and
        stores it; returns ``{"digest", "ref", "size", "media_type"}``."""
        label = name or path.name
        with open(path, "rb") as fh:
            headers = {
                "Content-Type": "application/octet-stream",
                "Content-Length": str(os.fstat(fh.fileno()).st_size),
            }
            result: dict[str, Any] = self._json(
                "POST", "/api/artifacts", params={"name": label}, content=fh, headers=headers
            )
        return result
