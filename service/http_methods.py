"""``HEAD`` and ``OPTIONS`` that agree with the routes.

FastAPI answers ``HEAD`` of a ``GET`` route and every ``OPTIONS`` with 405, and its 405s carry
no ``Allow`` header. :class:`MethodsMiddleware` fixes all three from the app's own routes:

- ``OPTIONS <path>``: 204 with ``Allow`` listing the methods the path's routes accept
  (404 as before for a path no route matches);
- ``HEAD <path>`` of a ``GET`` route: the ``GET`` response's status and headers, no body;
- a 405 carries ``Allow``.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Any

from starlette.routing import Mount
from starlette.types import ASGIApp, Message, Receive, Scope, Send


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

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        method = scope["method"]
        allowed = allowed_methods(self.routes_app, scope["path"])
        allow = ", ".join(sorted(allowed))
        if method == "OPTIONS" and allowed:
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
