"""``HEAD`` and ``OPTIONS`` that agree with the routes.

FastAPI answers ``HEAD`` of a ``GET`` route and every ``OPTIONS`` with 405, and its 405s carry
no ``Allow`` header. :class:`MethodsMiddleware` fixes all three from the app's own routes:

- ``OPTIONS <path>``: 204 with ``Allow`` listing the methods the path's routes accept
  (404 as before for a path no route matches); when the server has a token, only for a
  request that carries it, as the path's own routes require (401 otherwise; issue 21, item
  12: the route list was answered to anyone);
- ``HEAD <path>`` of a ``GET`` route: the ``GET`` response's status and headers, no body;
- a 405 carries ``Allow``.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Any

from starlette.requests import Request
from starlette.responses import JSONResponse
from starlette.routing import Mount
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.deps import request_authorized, token_matches

#: Paths every client may ask about without the token (as the routes themselves).
OPEN_PATHS = frozenset({"/api/health"})


def _leaf_routes(routes: Iterable[Any], prefix: str = "") -> Iterator[tuple[str, Any]]:
    """``(prefix, route)`` for every route, looking inside included routers."""
    for route in routes:
        inner = getattr(route, "original_router", None)  # an included router
        if inner is not None:
            more = getattr(getattr(route, "include_context", None), "prefix", "") or ""
            yield from _leaf_routes(inner.routes, prefix + more)
        else:
            yield prefix, route


def allowed_methods(app: Any, path: str) -> set[str]:
    """The methods the app's routes accept at ``path`` (empty: no route matches)."""
    methods: set[str] = set()
    for prefix, route in _leaf_routes(getattr(app, "routes", ())):
        if not path.startswith(prefix):
            continue
        rest = path[len(prefix) :]
        if isinstance(route, Mount):
            if rest == route.path or rest.startswith(route.path + "/"):
                methods |= {"GET"}  # static files
            continue
        regex = getattr(route, "path_regex", None)
        if regex is not None and regex.match(rest) and getattr(route, "methods", None):
            methods |= set(route.methods)
    if "GET" in methods:
        methods.add("HEAD")
    if methods:
        methods.add("OPTIONS")
    return methods


class MethodsMiddleware:
    """See the module docstring. ``routes_app`` is the FastAPI app whose routes decide."""

    def __init__(self, app: ASGIApp, routes_app: Any) -> None:
        self.app = app
        self.routes_app = routes_app

    def _authorized(self, scope: Scope) -> bool:
        """Whether the request may learn a path's methods: as its routes would let it in
        (bearer token or dashboard cookie; ``?token=`` on the dashboard's pages)."""
        settings = self.routes_app.state.settings
        if not settings.token or scope["path"].rstrip("/") in OPEN_PATHS:
            return True
        request = Request(scope)
        if request_authorized(settings, request.headers, request.cookies):
            return True
        page = not scope["path"].startswith("/api/")
        return page and token_matches(settings.token, request.query_params.get("token"))

    async def _unauthorized(self, scope: Scope, receive: Receive, send: Send) -> None:
        msg = "missing or wrong bearer token: send 'Authorization: Bearer <MATFORGE_TOKEN>'"
        response = JSONResponse(
            {"detail": msg, "error": msg},
            status_code=401,
            headers={"WWW-Authenticate": "Bearer"},
        )
        await response(scope, receive, send)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        method = scope["method"]
        allowed = allowed_methods(self.routes_app, scope["path"])
        allow = ", ".join(sorted(allowed))
        if method == "OPTIONS" and allowed:
            if not self._authorized(scope):
                await self._unauthorized(scope, receive, send)
                return
            await send(
                {
                    "type": "http.response.start",
                    "status": 204,
                    "headers": [(b"allow", allow.encode()), (b"content-length", b"0")],
                }
            )
            await send({"type": "http.response.body", "body": b""})
            return
        head = method == "HEAD" and "GET" in allowed
        if head:
            scope = {**scope, "method": "GET"}

        async def send_wrapped(message: Message) -> None:
            if message["type"] == "http.response.start" and message["status"] == 405 and allow:
                headers = [(k, v) for k, v in message.get("headers", []) if k.lower() != b"allow"]
                message = {**message, "headers": [*headers, (b"allow", allow.encode())]}
            elif head and message["type"] == "http.response.body":
                message = {**message, "body": b"", "more_body": message.get("more_body", False)}
            await send(message)

        await self.app(scope, receive, send_wrapped)
