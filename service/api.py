"""The FastAPI app: REST API, dashboard and OpenAPI document.

:func:`create_app` wires the routers of :mod:`service.routes` to one job queue and one
artifact store (kept in ``app.state``) and maps the error types to HTTP:

==========================================  =====  ============================================
error                                       HTTP   body
==========================================  =====  ============================================
``SpecError``, request validation, bad JSON  422   ``{"detail": [{"loc", "msg", "type"}], "error"}``
``FormatError`` (an upload)                  422   ``{"detail", "error"}``, naming the file
``AmbiguousIdError`` (a short job id)        422   ``{"detail", "error"}``, listing matches
``NotFoundError``                            404   ``{"detail", "error"}``
``TooLargeError``, body over the limit       413   ``{"detail", "error"}``
``CheckerBusy`` (every file checker busy)    503   ``{"detail", "error"}``; ``Retry-After``
``IntegrityError`` (corrupt object)          500   ``{"detail", "error"}``, never a traceback;
                                                   header ``X-Matforge-Error: integrity``
==========================================  =====  ============================================

``error`` is always one line a user can act on. The web process never runs jobs: workers
do (:class:`service.workers.worker.Supervisor`, started by :func:`service.server.serve`).
"""

from __future__ import annotations

import copy
import gc
import logging
from collections.abc import AsyncIterator, Mapping
from contextlib import asynccontextmanager
from typing import Any

from fastapi import APIRouter, FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.openapi.utils import get_openapi
from fastapi.responses import HTMLResponse, JSONResponse, Response
from starlette.datastructures import Headers
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import ASGIApp, Receive, Scope, Send

from jobapi.errors import SpecError
from jobapi.version import __version__
from service import kind_docs, kinds
from service.deps import AuthDep, PageAuth, set_token_cookie
from service.http_methods import MethodsMiddleware
from service.previews import PreviewMaker
from service.routes import ROUTERS
from service.routes.dashboard import render_error_page, static_files
from service.routes.results import OPENAPI_MODELS
from service.settings import Settings
from service.specs import JobSpec
from service.upload_check import CheckerBusy, UploadChecker
from service.web_guard import GuardMiddleware, allowed_hosts
from storage.artifacts import ArtifactStore
from storage.errors import (
    AmbiguousIdError,
    FormatError,
    IntegrityError,
    NotFoundError,
    TooLargeError,
)
from storage.formats import onnx as onnx_format
from storage.jobs import JobStore

log = logging.getLogger("matforge.api")

TITLE = "matforge"
#: The one version (:mod:`jobapi.version`), also ``matforge.__version__``.
VERSION = __version__
DESCRIPTION = """\
Dataset generation and evaluation service for real-time material models.

Submit a **job spec** `{kind, name, seed, params, force}` to `POST /api/jobs`, follow it with
`GET /api/jobs/{id}` (`queued` → `running` → `succeeded` | `failed` | `cancelled`), and
download its artifacts by digest from `GET /api/artifacts/{digest}`. Each job kind's
`params` are documented below as `params.<kind>` and in `GET /api/kinds`.

**Auth**: when the server has `MATFORGE_TOKEN` set, every route but `/api/health` needs
`Authorization: Bearer <token>`. In a browser, open the dashboard once as `/?token=<token>`:
the page sets an HttpOnly, SameSite=Strict cookie (a value derived from the token, not the
token) that its fetches and downloads then carry.

**Browsers**: the server answers only to the host names it was bound to or configured with
(`MATFORGE_ALLOWED_HOSTS`), refuses state-changing requests from other sites' pages
(`Origin`), and takes job specs only as `application/json` or YAML.

**Errors** are JSON `{"error": "<one line>", "detail": ...}`; 422 names the field or file.
"""
UPLOAD_PATH = "/api/artifacts"


# -- errors ------------------------------------------------------------------------------
def _wants_html(request: Request) -> bool:
    return not request.url.path.startswith("/api/") and "text/html" in request.headers.get(
        "accept", ""
    )


def error_response(
    request: Request,
    status: int,
    error: str,
    detail: Any = None,
    headers: Mapping[str, str] | None = None,
) -> Response:
    """The JSON error body (or, for a browser on a dashboard page, an HTML page)."""
    line = " ".join(str(error).split()) or "error"
    if _wants_html(request):
        page = render_error_page(request, status, line)
        page.headers.update(dict(headers or {}))
        return page
    body = {"detail": line if detail is None else detail, "error": line}
    return JSONResponse(
        jsonable_encoder(body), status_code=status, headers=dict(headers) if headers else None
    )


def _loc(path: str) -> list[str | int]:
    """``"params.resolution.0"`` → ``["body", "params", "resolution", 0]``."""
    parts: list[str | int] = [int(p) if p.isdigit() else p for p in path.split(".") if p]
    if not parts or parts[0] not in ("body", "query", "path", "header"):
        parts.insert(0, "body")
    return parts


def _spec_error(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, SpecError)
    # ``type`` as pydantic's own 422s carry it: the documented ``ValidationError`` schema
    # requires it (schemathesis, issue 15 B7, found the spec errors without it)
    detail = [{"loc": _loc(loc), "msg": msg, "type": "value_error"} for loc, msg in exc.errors]
    return error_response(request, 422, str(exc), detail)


def _validation_error(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, RequestValidationError)
    detail, lines = [], []
    for err in exc.errors():
        loc = [p for p in err.get("loc", ()) if p is not None]
        msg = str(err.get("msg", "invalid"))
        detail.append({"loc": loc, "msg": msg, "type": err.get("type")})
        lines.append(f"{'.'.join(str(p) for p in loc)}: {msg}" if loc else msg)
    return error_response(request, 422, "; ".join(lines) or "invalid request", detail)


def _status_handler(status: int) -> Any:
    def handler(request: Request, exc: Exception) -> Response:
        return error_response(request, status, str(exc))

    return handler


#: Header of a 500 that is a corrupt object on disk, not a server failure: the CLI exits 1
#: with the message (a failure of the data), not 3 (an unreachable server).
INTEGRITY_HEADER = "X-Matforge-Error"


def _integrity_error(request: Request, exc: Exception) -> Response:
    log.error("serving %s failed: %s", request.url.path, exc)
    return error_response(request, 500, str(exc), headers={INTEGRITY_HEADER: "integrity"})


def _http_error(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, StarletteHTTPException)
    detail = exc.detail if isinstance(exc.detail, str) else str(exc.detail)
    if exc.status_code == 404 and detail == "Not Found":
        detail = f"no route {request.method} {request.url.path}"
    if exc.status_code == 400 and detail == _BODY_UNPARSED:
        # A JSON body FastAPI reads for a route (PATCH /api/jobs/{id}) that is not UTF-8:
        # bad input like any other body that does not parse (a JSON syntax error is a 422).
        return error_response(request, 422, "body: not a JSON document (not UTF-8 text)")
    return error_response(request, exc.status_code, detail, headers=exc.headers)


#: FastAPI's 400 for a route's JSON body it could not decode (bytes that are not UTF-8).
_BODY_UNPARSED = "There was an error parsing the body"


def _busy_error(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, CheckerBusy)
    return error_response(request, 503, str(exc), headers={"Retry-After": str(exc.retry_after)})


def _internal_error(request: Request, exc: Exception) -> Response:
    log.exception("internal error on %s %s", request.method, request.url.path, exc_info=exc)
    return error_response(request, 500, f"internal error: {type(exc).__name__}; see the server log")


# -- body size limit ---------------------------------------------------------------------
class BodyLimitMiddleware:
    """Caps request bodies: ``upload_limit`` for ``POST /api/artifacts``, ``json_limit``
    for everything else. A declared ``Content-Length`` over the cap is answered 413 at once;
    a body without one is counted as it streams and stopped with :class:`TooLargeError`."""

    def __init__(self, app: ASGIApp, json_limit: int, upload_limit: int) -> None:
        self.app = app
        self.json_limit = json_limit
        self.upload_limit = upload_limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        upload = scope["method"] == "POST" and scope["path"].rstrip("/") == UPLOAD_PATH
        limit = self.upload_limit if upload else self.json_limit
        what = "upload" if upload else "request body"
        declared = Headers(scope=scope).get("content-length", "")
        if declared.isdigit() and int(declared) > limit:
            error = f"{what} of {int(declared)} bytes exceeds the limit of {limit} bytes"
            response = JSONResponse({"detail": error, "error": error}, status_code=413)
            await response(scope, receive, send)
            return
        received = 0

        async def limited() -> Any:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    raise TooLargeError(f"{what} exceeds the limit of {limit} bytes")
            return message

        await self.app(scope, limited, send)


# -- OpenAPI -----------------------------------------------------------------------------
def _kind_components(schemas: dict[str, Any]) -> dict[str, str]:
    """Add ``params.<kind>`` (and its nested models) for every kind; returns kind → ref."""
    refs = {}
    for name, kind in kinds.all_kinds().items():
        key = f"params.{name}"
        try:
            js = kind.params.model_json_schema(ref_template=f"#/components/schemas/{key}.{{model}}")
        except Exception as exc:  # one broken kind must not hide the others' docs
            log.warning("no JSON schema for the params of %s: %s", name, exc)
            js = {"type": "object", "description": f"schema unavailable: {exc}"}
        for def_name, sub in js.pop("$defs", {}).items():
            schemas[f"{key}.{def_name}"] = sub
        js.setdefault("description", kind.description)
        schemas[key] = js
        refs[name] = f"#/components/schemas/{key}"
    return refs


def _document_kind_filter(doc: dict[str, Any], names: list[str]) -> None:
    """``GET /api/jobs?kind=`` takes a registered kind only (422 otherwise): say so with an
    ``enum`` of the kinds registered when the document is built (plugins included)."""
    op = doc.get("paths", {}).get("/api/jobs", {}).get("get", {})
    for param in op.get("parameters", []):
        if param.get("in") == "query" and param.get("name") == "kind" and names:
            param["schema"] = {
                "anyOf": [{"type": "string", "enum": names}, {"type": "null"}],
                "title": "Kind",
                "description": "only this kind (a registered kind; 422 otherwise)",
            }


def _document_step_kinds(schemas: dict[str, Any], names: list[str]) -> None:
    """A batch step's ``spec.kind`` (``POST /api/results/batch``) is one of the registered
    kinds, as the route checks."""
    spec = schemas.get("BatchStep", {}).get("properties", {}).get("spec", {})
    kind = spec.get("properties", {}).get("kind")
    if kind is not None and names:
        kind["enum"] = names


def build_openapi(app: FastAPI) -> dict[str, Any]:
    """The OpenAPI document, with every kind's params schema and the job spec body as a
    ``oneOf`` over kinds (discriminated by ``kind``)."""
    if app.openapi_schema:
        return app.openapi_schema
    doc = get_openapi(title=TITLE, version=VERSION, description=DESCRIPTION, routes=app.routes)
    schemas = doc.setdefault("components", {}).setdefault("schemas", {})
    for model in OPENAPI_MODELS:  # request bodies the routes read themselves
        js = model.model_json_schema(ref_template="#/components/schemas/{model}")
        for def_name, sub in js.pop("$defs", {}).items():
            schemas.setdefault(def_name, sub)
        schemas.setdefault(model.__name__, js)
    base = JobSpec.model_json_schema()
    base["title"] = "JobCreate"
    refs = _kind_components(schemas)
    variants = {}
    for name, ref in refs.items():
        v = copy.deepcopy(base)
        v["title"] = f"JobCreate.{name}"
        v["description"] = kinds.all_kinds()[name].description
        v["properties"]["kind"] = {"type": "string", "const": name, "title": "Kind"}
        v["properties"]["params"] = {"$ref": ref}
        v["required"] = ["kind"]
        schemas[f"JobCreate.{name}"] = v
        variants[name] = f"#/components/schemas/JobCreate.{name}"
    if variants:
        schemas["JobCreate"] = {
            "title": "JobCreate",
            "type": "object",
            "description": "A job spec; `params` follow the schema of its `kind`.",
            "oneOf": [{"$ref": r} for r in variants.values()],
            "discriminator": {"propertyName": "kind", "mapping": variants},
        }
    else:
        schemas["JobCreate"] = base
    _document_kind_filter(doc, sorted(refs))
    _document_step_kinds(schemas, sorted(refs))
    doc.setdefault("components", {})["securitySchemes"] = {
        "bearer": {
            "type": "http",
            "scheme": "bearer",
            "description": "needed when the server sets MATFORGE_TOKEN",
        }
    }
    doc["security"] = [{"bearer": []}, {}]
    app.openapi_schema = doc
    return doc


def _docs_router(app: FastAPI) -> APIRouter:
    """``/openapi.json`` and ``/docs``, behind the same token as everything else."""
    router = APIRouter(include_in_schema=False)

    @router.get("/openapi.json", dependencies=[AuthDep])
    def openapi_json() -> JSONResponse:
        return JSONResponse(build_openapi(app))

    @router.get("/docs", response_class=HTMLResponse)
    def swagger(request: Request, cookie_token: PageAuth) -> Response:
        page = get_swagger_ui_html(
            openapi_url="/openapi.json",
            title=f"{TITLE}: API",
            swagger_js_url="/static/vendor/swagger-ui/swagger-ui-bundle.js",
            swagger_css_url="/static/vendor/swagger-ui/swagger-ui.css",
            swagger_favicon_url="/static/favicon.svg",
        )
        set_token_cookie(page, cookie_token, request)
        return page

    return router


# -- the app -----------------------------------------------------------------------------
def _prepare_routes(app: FastAPI) -> None:
    """Have every route build its validators now. FastAPI builds a route's parameter and
    response validators (pydantic ``TypeAdapter``s) when a request first reaches it; built
    on the event loop while other requests run in the thread pool, that is where pydantic
    could read a type's source with ``ast`` in two threads at once, which CPython 3.11 does
    not survive (``SystemError: AST constructor recursion depth mismatch``). Matching a
    path no route has walks every route of every router (``tests/unit/service/
    test_request_validators.py`` counts what a request builds: nothing)."""
    scope: dict[str, Any] = {
        "type": "http",
        "method": "GET",
        "path": "/\x00",
        "root_path": "",
        "headers": [],
        "query_string": b"",
    }
    for route in app.router.routes:
        route.matches(dict(scope))


@asynccontextmanager
async def _lifespan(app: FastAPI) -> AsyncIterator[None]:
    # Import the kind modules (about 1.5 s) before the server accepts connections: done
    # lazily, the first submissions after a start all waited for it, which was the p99 of
    # bench_submit.py at 20 clients (issue 15, B8).
    kinds.load()  # built-in kinds, then plugins (a broken plugin is logged, never fatal)
    # The ONNX checker's library, imported on a submission's first ONNX ref, held the
    # process for about 2 s (bench_attack.py's health latency); import it here instead.
    onnx_format.preload()
    _prepare_routes(app)
    kind_docs.prepare(list(kinds.all_kinds().values()))
    # What is alive now (the modules, numpy, the kinds) lives as long as the server: out of
    # the collector's sight, a full collection no longer walks it, which stalled every
    # request in flight for ~100 ms once in a few hundred submissions.
    gc.collect()
    gc.freeze()
    yield
    app.state.upload_checker.close()  # the child processes that check uploads


def create_app(settings: Settings | None = None, bind_host: str | None = None) -> FastAPI:
    """The matforge web app over ``settings.data_dir`` (default: from the environment).

    ``bind_host``: the address the server listens on (``matforge serve`` passes it); with
    ``settings.allowed_hosts`` it decides which ``Host`` headers are answered
    (:mod:`service.web_guard`). ``None`` (tests, embedding) checks only configured hosts.
    """
    settings = settings or Settings.from_env()
    app = FastAPI(
        title=TITLE,
        version=VERSION,
        description=DESCRIPTION,
        docs_url=None,
        redoc_url=None,
        openapi_url=None,
        lifespan=_lifespan,
        # matforge exports no OpenTelemetry data; left on, FastAPI asks the global
        # providers whether they are configured on every request (~0.1 ms; issue 15, B8)
        telemetry={"tracing": False, "metrics": False, "logs": False},
    )
    app.state.settings = settings
    app.state.jobs = JobStore(settings.db_path)
    app.state.store = ArtifactStore(settings.store_dir)
    app.state.upload_checker = UploadChecker(
        settings.upload_check_bytes,
        settings.upload_check_seconds,
        processes=settings.upload_checkers,
        queue_wait=settings.upload_queue_seconds,
        max_archive_pixels=settings.archive_max_pixels,
        budget_seconds=settings.upload_budget_seconds,
        inflate_ratio=settings.upload_inflate_ratio,
    )
    app.state.previews = PreviewMaker(
        app.state.upload_checker, max_pixels=settings.preview_max_pixels
    )
    app.openapi = lambda: build_openapi(app)  # type: ignore[method-assign]

    app.add_exception_handler(SpecError, _spec_error)
    app.add_exception_handler(RequestValidationError, _validation_error)
    app.add_exception_handler(FormatError, _status_handler(422))
    app.add_exception_handler(AmbiguousIdError, _status_handler(422))
    app.add_exception_handler(NotFoundError, _status_handler(404))
    app.add_exception_handler(TooLargeError, _status_handler(413))
    app.add_exception_handler(CheckerBusy, _busy_error)
    app.add_exception_handler(IntegrityError, _integrity_error)
    app.add_exception_handler(StarletteHTTPException, _http_error)
    app.add_exception_handler(Exception, _internal_error)
    app.add_middleware(MethodsMiddleware, routes_app=app)
    app.add_middleware(
        BodyLimitMiddleware,
        json_limit=settings.max_body_bytes,
        upload_limit=settings.max_upload_bytes,
    )

    # Outermost: a request from the wrong Host or another site's page goes no further.
    app.add_middleware(GuardMiddleware, hosts=allowed_hosts(bind_host, settings.allowed_hosts))

    for router in ROUTERS:
        app.include_router(router)
    app.include_router(_docs_router(app))
    app.mount("/static", static_files(), name="static")
    return app
