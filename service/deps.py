"""FastAPI dependencies of the REST API and the dashboard, as ``Annotated`` types.

Route signatures read as plain types: ``def get_job(job_id: JobId, jobs: JobsDep)``. The
stores live in ``app.state`` (set up once by :func:`service.api.create_app`).

Authentication (only when ``settings.token`` is set): a request is let in when it carries

1. ``Authorization: Bearer <token>`` (the CLI and scripts), or
2. the ``matforge_token`` cookie, which a dashboard page sets when it is opened once as
   ``/?token=<token>`` (the browser then sends it with every fetch, image and download:
   HttpOnly, ``SameSite=Strict``, ``Secure`` over https, so other sites can neither read it
   nor ride on it). The cookie holds a session value derived from the token
   (:func:`session_value`, an HMAC), never the token itself: a leaked cookie opens the
   dashboard and API of this server but is not the master token the CLI uses.

``?token=`` itself is accepted on the dashboard pages only, never on ``/api/...``, so tokens
do not end up in API access logs; the page removes it from the address bar at once.
"""

from __future__ import annotations

import hashlib
import hmac
from typing import Annotated

from fastapi import Depends, HTTPException, Path, Query, Request, Response
from starlette.datastructures import Headers

from service.settings import Settings
from storage.artifacts import ArtifactStore
from storage.job_queries import resolve_job_id
from storage.jobs import JobStore

TOKEN_COOKIE = "matforge_token"
JOB_ID_PATTERN = r"^[0-9a-f]{1,32}$"
DIGEST_PATTERN = r"^(sha256:)?[0-9a-f]{64}$"


async def get_settings(request: Request) -> Settings:
    """The app's :class:`Settings`.

    This and the other dependencies that only read ``app.state`` or headers are ``async``:
    FastAPI runs a sync dependency in the thread pool, and those hops (several a request)
    were a measurable part of submission latency under 20 clients (issue 15, B8).
    """
    settings: Settings = request.app.state.settings
    return settings


async def get_jobs(request: Request) -> JobStore:
    """The app's job queue."""
    jobs: JobStore = request.app.state.jobs
    return jobs


async def get_store(request: Request) -> ArtifactStore:
    """The app's content-addressed artifact store."""
    store: ArtifactStore = request.app.state.store
    return store


SettingsDep = Annotated[Settings, Depends(get_settings)]
JobsDep = Annotated[JobStore, Depends(get_jobs)]
StoreDep = Annotated[ArtifactStore, Depends(get_store)]


def resolve_path_job_id(
    job_id: Annotated[
        str,
        Path(
            pattern=JOB_ID_PATTERN,
            description=(
                "job id: 32 lowercase hex digits, or any unique prefix of one (as git's "
                "short ids); an ambiguous prefix is a 422 that lists the matches"
            ),
            examples=["0f3c9a7e5b2d4c1e8a6f0b9d7c3e2a1f", "0f3c9a7e5b2d"],
        ),
    ],
    jobs: JobsDep,
) -> str:
    """The full id of the job a path names by its id or a unique prefix of it."""
    return resolve_job_id(jobs, job_id)


JobId = Annotated[str, Depends(resolve_path_job_id)]
Digest = Annotated[
    str,
    Path(
        pattern=DIGEST_PATTERN,
        description="sha256 of the object: 64 lowercase hex digits, `sha256:` prefix optional",
    ),
]


def token_matches(expected: str, given: str | None) -> bool:
    """Constant-time comparison of a presented token with the configured one."""
    return given is not None and hmac.compare_digest(expected.encode(), given.encode())


def bearer_token(headers: Headers) -> str | None:
    """The token of an ``Authorization: Bearer <token>`` header, if any."""
    value = headers.get("authorization", "")
    scheme, _, token = value.partition(" ")
    if scheme.lower() != "bearer" or not token.strip():
        return None
    return token.strip()


def session_value(token: str) -> str:
    """The dashboard cookie's value for ``token``: HMAC-SHA256 of a fixed label under the
    token (hex). It changes when the token does, and the token cannot be recovered from it."""
    return hmac.new(token.encode(), b"matforge dashboard session v1", hashlib.sha256).hexdigest()


def request_authorized(settings: Settings, headers: Headers, cookies: dict[str, str]) -> bool:
    """Whether a request may pass: no token configured, or a matching bearer/cookie."""
    if not settings.token:
        return True
    return token_matches(settings.token, bearer_token(headers)) or token_matches(
        session_value(settings.token), cookies.get(TOKEN_COOKIE)
    )


def unauthorized(detail: str) -> HTTPException:
    """A 401 with the ``WWW-Authenticate: Bearer`` challenge."""
    return HTTPException(status_code=401, detail=detail, headers={"WWW-Authenticate": "Bearer"})


async def require_auth(request: Request, settings: SettingsDep) -> None:
    """API routes: 401 unless the bearer token (or the dashboard cookie) matches."""
    if not request_authorized(settings, request.headers, request.cookies):
        raise unauthorized(
            "missing or wrong bearer token: send 'Authorization: Bearer <MATFORGE_TOKEN>'"
        )


async def require_page_auth(
    request: Request,
    settings: SettingsDep,
    token: Annotated[
        str | None,
        Query(description="the server's token, for opening the dashboard in a browser"),
    ] = None,
) -> str | None:
    """Dashboard pages: like :func:`require_auth`, but a matching ``?token=`` passes too.

    Returns the token the page must set as its session cookie (see :func:`set_token_cookie`)
    when it came from the query, else ``None``.
    """
    if request_authorized(settings, request.headers, request.cookies):
        return None
    if settings.token and token_matches(settings.token, token):
        return settings.token
    raise unauthorized(
        "this matforge server needs its token: open the dashboard as /?token=<MATFORGE_TOKEN>"
    )


def set_token_cookie(response: Response, token: str | None, request: Request) -> None:
    """Set the dashboard's session cookie (:func:`session_value` of ``token``) on
    ``response``, ``Secure`` when ``request`` came over https; no-op for ``None``."""
    if token:
        response.set_cookie(
            TOKEN_COOKIE,
            session_value(token),
            httponly=True,
            samesite="strict",
            secure=request.url.scheme == "https",
            path="/",
        )


AuthDep = Depends(require_auth)
PageAuth = Annotated[str | None, Depends(require_page_auth)]
