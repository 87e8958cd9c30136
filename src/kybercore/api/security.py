"""Access control on the HTTP side: who is asking, may they, and headers that keep a
browser from being turned against the printers.

- Identity: ``Authorization: Bearer <token>`` (scripts) or the HttpOnly, SameSite=Strict
  cookie that ``POST /api/session`` (:mod:`kybercore.api.session`) sets (the browser, REST
  and WebSocket alike).
- A request that changes anything, and every WebSocket, must come from our own origin
  when it says where it comes from: a page elsewhere cannot pause a printer through a
  visitor's browser, even on an open loopback install.
- CORS stays closed (no CORS headers at all); security headers go on every answer.
"""

from __future__ import annotations

from typing import Any, Final, Literal
from urllib.parse import urlsplit

from fastapi import Depends, Request, WebSocket
from fastapi.responses import Response
from starlette.types import ASGIApp, Receive, Scope, Send

from kybercore.api.auth import COOKIE, OPEN_ACCESS, Identity, Role, TokenStore
from kybercore.api.errors import error_response
from kybercore.errors import AccessDenied

SAFE_METHODS: Final = frozenset({"GET", "HEAD", "OPTIONS"})
SECURITY_HEADERS: Final = {
    "Content-Security-Policy": (
        "default-src 'self'; img-src 'self' data: blob:; style-src 'self'; "
        "script-src 'self'; connect-src 'self'; frame-ancestors 'none'; base-uri 'none'; "
        "form-action 'self'"
    ),
    "X-Content-Type-Options": "nosniff",
    "X-Frame-Options": "DENY",
    "Referrer-Policy": "no-referrer",
    "Cross-Origin-Opener-Policy": "same-origin",
}


class Access:
    """How this server decides who may do what."""

    def __init__(self, mode: Literal["open", "tokens"], store: TokenStore | None) -> None:
        self.mode = mode
        self.store = store

    def identify(self, headers: Any, cookies: dict[str, str]) -> Identity | None:
        """The identity behind a request, or None when it presents no valid token."""
        if self.mode == "open":
            return OPEN_ACCESS
        token = cookies.get(COOKIE, "")
        scheme, _, value = str(headers.get("authorization", "")).partition(" ")
        if scheme.lower() == "bearer" and value:
            token = value.strip()
        if not token or self.store is None:
            return None
        return self.store.identify(token)


def require(role: Role) -> Any:
    """A FastAPI dependency: the caller's identity, which must hold at least ``role``."""

    def check(request: Request) -> Identity:
        access: Access = request.app.state.access
        identity = access.identify(request.headers, request.cookies)
        if identity is None:
            raise AccessDenied(
                "Log in with a KyberCore token (POST /api/session, or send "
                "'Authorization: Bearer <token>'). An admin creates tokens with "
                "`kybercore tokens create`.",
                code="unauthorized",
            )
        if not identity.may(role):
            raise AccessDenied(
                f"Your token ({identity.name}, {identity.role}) may not do this: it needs "
                f"the {role} role. Ask an admin for a token with that role.",
                code="forbidden",
            )
        return identity

    return Depends(check)


def websocket_identity(websocket: WebSocket) -> Identity | None:
    """The identity of a WebSocket client from our own origin, or None."""
    if not same_origin(websocket.headers.get("origin"), websocket.headers.get("host")):
        return None
    access: Access = websocket.app.state.access
    return access.identify(websocket.headers, websocket.cookies)


def same_origin(origin: str | None, host: str | None) -> bool:
    """True when no Origin is given (not a browser) or it names this very host."""
    if origin is None:
        return True
    return bool(host) and urlsplit(origin).netloc.lower() == str(host).lower()


class GuardMiddleware:
    """Security headers on every answer; cross-origin writes and oversized bodies refused
    before any handler parses them."""

    def __init__(self, app: ASGIApp, max_body: int) -> None:
        self.app = app
        self.max_body = max_body

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = {k.decode().lower(): v.decode() for k, v in scope["headers"]}
        refusal = self._refusal(scope["method"], headers)
        if refusal is not None:
            await refusal(scope, receive, send)
            return

        async def with_headers(message: Any) -> None:
            if message["type"] == "http.response.start":
                extra = [(k.lower().encode(), v.encode()) for k, v in SECURITY_HEADERS.items()]
                message["headers"] = list(message.get("headers", [])) + extra
            await send(message)

        await self.app(scope, receive, with_headers)

    def _refusal(self, method: str, headers: dict[str, str]) -> Response | None:
        if method not in SAFE_METHODS and not same_origin(
            headers.get("origin"), headers.get("host")
        ):
            return _refuse(
                403,
                "cross_origin",
                "Requests that change printers must come from KyberCore's own page.",
            )
        length = headers.get("content-length", "0")
        if not length.isdigit() or int(length) > self.max_body:
            return _refuse(
                413,
                "too_large",
                f"The request is larger than {self.max_body // 2**20} MiB: split the file or "
                "upload it to the printer directly.",
            )
        return None


def _refuse(status: int, code: str, message: str) -> Response:
    return error_response(status, code, message, headers=SECURITY_HEADERS)
