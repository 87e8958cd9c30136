"""The door every request passes first, before any route parses anything.

In this order, each refusal in the error envelope with ``Connection: close`` (the rest of
the body is never read):

1. ``Host`` must be one of ours (:mod:`kybercore.api.hosts`): 421 ``unknown_host``, or a
   refused WebSocket handshake. Nothing else runs for a rebound name.
2. A write, and every WebSocket, must come from our own origin when it names one: 403
   ``cross_origin`` (a page elsewhere cannot drive a printer through a visitor's browser).
3. In tokens mode a write must carry a valid credential before its body is read: 401
   (``/api/session``, where the browser logs in and out, is the exception).
4. A body larger than its route allows: 413 ``too_large``, from ``Content-Length`` when
   declared, and from the bytes actually received otherwise (chunked bodies): only the
   upload routes (``POST /api/printers/{id}/files`` and ``POST /api/jobs``) take large
   bodies.

Security headers go on every answer; a route that sets its own Content-Security-Policy
(the API docs) keeps it.
"""

from __future__ import annotations

import re
from typing import Final
from urllib.parse import urlsplit

from fastapi.responses import Response
from starlette.requests import HTTPConnection
from starlette.types import ASGIApp, Message, Receive, Scope, Send
from starlette.websockets import WebSocket

from kybercore.api.errors import error_response
from kybercore.api.hosts import HostAllowlist
from kybercore.api.security import NOT_LOGGED_IN, SECURITY_HEADERS, Access

MAX_BODY_BYTES: Final = 1024 * 1024
"""The body limit of every route but the upload: JSON bodies are small."""

SAFE_METHODS: Final = frozenset({"GET", "HEAD", "OPTIONS"})
LOGIN_PATH: Final = "/api/session"
_UPLOAD_PATH: Final = re.compile(r"/api/printers/[^/]+/files|/api/jobs")


def same_origin(origin: str | None, host: str | None) -> bool:
    """True when no Origin is given (not a browser) or it names this very host."""
    if origin is None:
        return True
    return bool(host) and urlsplit(origin).netloc.lower() == str(host).lower()


class _CountedBody:
    """The request's ``receive``, cut off (as a disconnect) once the body passes ``limit``."""

    def __init__(self, receive: Receive, limit: int) -> None:
        self._receive = receive
        self.limit = limit
        self.received = 0
        self.exceeded = False

    async def receive(self) -> Message:
        if self.exceeded:
            return {"type": "http.disconnect"}
        message = await self._receive()
        if message["type"] == "http.request":
            self.received += len(message.get("body", b""))
            if self.received > self.limit:
                self.exceeded = True
                return {"type": "http.disconnect"}
        return message


class GuardMiddleware:
    """Host, origin, credential and body size checked before any handler runs."""

    def __init__(self, app: ASGIApp, hosts: HostAllowlist, upload_limit: int) -> None:
        self.app = app
        self.hosts = hosts
        self.upload_limit = upload_limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "websocket":
            await self._websocket(scope, receive, send)
        elif scope["type"] == "http":
            await self._http(scope, receive, send)
        else:
            await self.app(scope, receive, send)

    async def _websocket(self, scope: Scope, receive: Receive, send: Send) -> None:
        headers = HTTPConnection(scope).headers
        host = headers.get("host")
        if not self.hosts.allows(host) or not same_origin(headers.get("origin"), host):
            # Before accept: the client sees a refused handshake, nothing else.
            await WebSocket(scope, receive, send).close(code=4403)
            return
        await self.app(scope, receive, send)

    async def _http(self, scope: Scope, receive: Receive, send: Send) -> None:
        upload = scope["method"] == "POST" and _UPLOAD_PATH.fullmatch(scope["path"]) is not None
        limit = self.upload_limit if upload else MAX_BODY_BYTES
        refusal = self._refusal(HTTPConnection(scope), limit)
        if refusal is not None:
            await refusal(scope, receive, send)
            return
        body = _CountedBody(receive, limit)
        started = False

        async def guarded_send(message: Message) -> None:
            nonlocal started
            if body.exceeded and not started:
                return  # the route's answer to a cut-off body: replaced by the 413 below
            if message["type"] == "http.response.start":
                started = True
                message["headers"] = _with_security_headers(message.get("headers", []))
            await send(message)

        try:
            await self.app(scope, body.receive, guarded_send)
        except Exception:
            if not body.exceeded:
                raise
        if body.exceeded and not started:
            await _too_large(limit)(scope, receive, send)

    def _refusal(self, request: HTTPConnection, limit: int) -> Response | None:
        headers = request.headers
        host = headers.get("host")
        if not self.hosts.allows(host):
            name = (host or "").split(":")[0][:100] or "?"
            return _refuse(
                421,
                "unknown_host",
                f"This KyberCore does not answer to the name '{name}'. If that is how you "
                f"reach it (a reverse proxy, a LAN name), start it with --allowed-host {name}.",
            )
        if request.scope["method"] in SAFE_METHODS:
            return None
        if not same_origin(headers.get("origin"), host):
            return _refuse(
                403,
                "cross_origin",
                "Requests that change printers must come from KyberCore's own page.",
            )
        access: Access = request.app.state.access
        anonymous = access.identify(headers, request.cookies) is None
        if anonymous and request.scope["path"] != LOGIN_PATH:
            return _refuse(401, "unauthorized", NOT_LOGGED_IN)
        length = headers.get("content-length", "0")
        if not length.isdigit() or int(length) > limit:
            return _too_large(limit)
        return None


def _with_security_headers(headers: list[tuple[bytes, bytes]]) -> list[tuple[bytes, bytes]]:
    present = {name.lower() for name, _ in headers}
    extra = [
        (name.lower().encode(), value.encode())
        for name, value in SECURITY_HEADERS.items()
        if name.lower().encode() not in present
    ]
    return [*headers, *extra]


def _too_large(limit: int) -> Response:
    return _refuse(
        413,
        "too_large",
        f"The request is larger than {limit // 2**20} MiB"
        + (": split the file or upload it to the printer directly." if limit > 2**20 else "."),
    )


def _refuse(status: int, code: str, message: str) -> Response:
    return error_response(
        status, code, message, headers={**SECURITY_HEADERS, "Connection": "close"}
    )
