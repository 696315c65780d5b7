"""What keeps other web sites and DNS tricks away from a local server, and tokens out of logs.

With no token set (the default on 127.0.0.1), any page a user visits could otherwise drive
the server: a cross-site ``text/plain`` POST to ``/api/jobs`` needs no CORS preflight (CSRF),
and a DNS name re-pointed at 127.0.0.1 makes the browser treat the server as that site's own
(DNS rebinding). :class:`GuardMiddleware` therefore answers

- 400 to a ``Host`` header that is not a host the server was bound to or configured with
  (``MATFORGE_ALLOWED_HOSTS``, comma-separated; ``*`` turns the check off);
- 403 to a state-changing request (not GET, HEAD, OPTIONS) whose ``Origin`` is another site
  (or ``null``); same-origin pages (the dashboard) and non-browser clients (no ``Origin``)
  pass.

``POST /api/jobs`` also insists on a JSON or YAML content type (415, in
:mod:`service.routes.jobs`). :class:`RedactTokens` removes ``token=`` values from the access
log (the dashboard is opened once as ``/?token=...``).
"""

from __future__ import annotations

import ipaddress
import logging
import re
from collections.abc import Iterable
from urllib.parse import unquote_plus, urlsplit

from starlette.datastructures import Headers
from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send

LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})
WILDCARDS = frozenset({"", "0.0.0.0", "::"})
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})
#: A query parameter in a logged line: separator, name, ``=``, value.
_PARAM = re.compile(r"([?&;])([^=&;?#\s\"]*)=([^&;#\s\"]*)")


def _decoded_name(name: str) -> str:
    """A parameter's name as the server reads it (percent-decoded, ``+`` a space), decoded
    again while that changes it (``%2574oken``), stripped and in lower case."""
    for _ in range(4):
        plain = unquote_plus(name)
        if plain == name:
            break
        name = plain
    return name.strip().lower()


def _redact_param(m: re.Match[str]) -> str:
    if _decoded_name(m[2]) != "token":
        return m[0]
    return f"{m[1]}{m[2]}=***"


def redact(text: str) -> str:
    """``text`` with the value of every ``token`` query parameter replaced by ``***``.

    The name is compared after URL decoding and case-insensitively: ``?%74oken=`` and
    ``?TOKEN=`` reach the dashboard as ``token`` (issue 21, item 8)."""
    return _PARAM.sub(_redact_param, text)


class RedactTokens(logging.Filter):
    """A logging filter for uvicorn's access log (and any other): no token in clear."""

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.args, tuple):
            record.args = tuple(redact(a) if isinstance(a, str) else a for a in record.args)
        elif isinstance(record.msg, str):
            record.msg = redact(record.msg)
        return True


def is_loopback(host: str) -> bool:
    """Whether ``host`` (a name or an address) is this machine only: localhost, 127/8, ::1."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def allowed_hosts(bind_host: str | None, configured: Iterable[str]) -> frozenset[str] | None:
    """The host names ``Host`` may carry, or ``None`` for no check: configured hosts plus the
    bound host (and every loopback name when bound to loopback). A server bound to all
    interfaces with no configured hosts cannot know its names: no check."""
    conf = {h.strip().lower().strip("[]") for h in configured if h.strip()}
    if "*" in conf:
        return None
    hosts = set(conf)
    bind = (bind_host or "").strip().lower().strip("[]")
    if bind_host is None or bind in WILDCARDS:
        if not conf:
            return None
        hosts |= LOOPBACK_NAMES
    else:
        hosts.add(bind)
        if is_loopback(bind):
            hosts |= LOOPBACK_NAMES
    return frozenset(hosts)


def bind_refusal(bind_host: str, configured: Iterable[str]) -> str | None:
    """Why a server must not start on ``bind_host``, or ``None`` when it may.

    Listening on every interface (``0.0.0.0``, ``::``) with no configured host names leaves
    the server unable to tell its own names from a rebound one: :func:`allowed_hosts` turns
    the ``Host`` check off, and any web page could reach the API through DNS rebinding
    (issue 21, item 11). Such a start is refused; ``*`` in the configured hosts turns the
    check off knowingly."""
    bind = bind_host.strip().lower().strip("[]")
    if bind not in WILDCARDS or any(h.strip() for h in configured):
        return None
    shown = bind_host or "(all interfaces)"
    return (
        f"refusing to listen on every interface (--host {shown}) with no "
        "MATFORGE_ALLOWED_HOSTS: the Host check that stops DNS rebinding would be off. Set "
        "MATFORGE_ALLOWED_HOSTS to the host names clients use (e.g. "
        "'localhost,127.0.0.1,matforge.lab'; '*' turns the check off), or listen on "
        "127.0.0.1 (the default)"
    )


def host_name(value: str) -> str:
    """The host part of a ``Host`` header (port and IPv6 brackets dropped), lower case."""
    value = value.strip().lower()
    if value.startswith("["):
        return value[1:].split("]", 1)[0]
    return value.rsplit(":", 1)[0] if value.count(":") == 1 else value


class GuardMiddleware:
    """The ``Host`` and ``Origin`` checks of the module docstring."""

    def __init__(self, app: ASGIApp, hosts: frozenset[str] | None) -> None:
        self.app = app
        self.hosts = hosts

    async def _refuse(
        self, scope: Scope, receive: Receive, send: Send, status: int, msg: str
    ) -> None:
        await JSONResponse({"detail": msg, "error": msg}, status_code=status)(scope, receive, send)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        host = headers.get("host", "")
        if self.hosts is not None and host_name(host) not in self.hosts:
            shown = host or "(none)"
            msg = (
                f"Host {shown!r} is not a name this server answers to; add it to "
                "MATFORGE_ALLOWED_HOSTS if it is"
            )
            await self._refuse(scope, receive, send, 400, msg)
            return
        origin = headers.get("origin")
        if origin is not None and scope["method"] not in SAFE_METHODS:
            netloc = urlsplit(origin).netloc.lower() if origin != "null" else ""
            if not netloc or netloc != host.lower():
                msg = f"cross-origin {scope['method']} from {origin!r} refused"
                await self._refuse(scope, receive, send, 403, msg)
                return
        await self.app(scope, receive, send)
