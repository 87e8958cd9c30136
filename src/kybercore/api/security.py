"""Access control on the HTTP side: who is asking, may they, and the headers that keep a
browser from being turned against the printers.

- Identity: ``Authorization: Bearer <token>`` (scripts) or the HttpOnly, SameSite=Strict
  session cookie that ``POST /api/session`` (:mod:`kybercore.api.session`) sets (the
  browser, REST and WebSocket alike).
- The mode follows tokens.json while the server runs: a server started open (loopback, no
  token) asks for tokens from the moment the first one is created, and stays so.
- What reaches a route has passed :class:`~kybercore.api.guard.GuardMiddleware` first
  (our own Host, our own origin for writes, a token before any body is read, body limits).
"""

from __future__ import annotations

from typing import Any, Final, Literal

from fastapi import Depends, Request

from kybercore.api.auth import (
    COOKIE,
    OPEN_ACCESS,
    BrowserSessions,
    Identity,
    Role,
    TokenStore,
)
from kybercore.errors import AccessDenied

_BASE_POLICY: Final = (
    "default-src 'self'; img-src 'self' data: blob:; script-src 'self'; connect-src 'self'; "
    "frame-ancestors 'none'; base-uri 'none'; form-action 'self'"
)
CONTENT_SECURITY_POLICY: Final = _BASE_POLICY + "; style-src 'self'"
DOCS_CONTENT_SECURITY_POLICY: Final = (
    # Swagger UI and ReDoc, served from here, set styles at run time and ReDoc searches in
    # a worker it builds from a blob; scripts still come only from this server.
    _BASE_POLICY + "; style-src 'self' 'unsafe-inline'; worker-src 'self' blob:"
)
SECURITY_HEADERS: Final = {
    "Content-Security-Policy": CONTENT_SECURITY_POLICY,
    "X-Content-Type-Options": "nosniff",
    "X-Frame-Options": "DENY",
    "Referrer-Policy": "no-referrer",
    "Cross-Origin-Opener-Policy": "same-origin",
}


class Access:
    """How this server decides who may do what.

    ``store`` None: open, always (an app built in-process without tokens). Otherwise tokens
    are required, from the start or, with ``open_until_first_token``, from the moment
    tokens.json first holds one.
    """

    def __init__(self, store: TokenStore | None, *, open_until_first_token: bool = False) -> None:
        self.store = store
        self.sessions = BrowserSessions()
        self._open = store is None or open_until_first_token

    @property
    def mode(self) -> Literal["open", "tokens"]:
        """``open`` (everyone is admin) or ``tokens``, as of now."""
        return "open" if self._guard() is None else "tokens"

    def _guard(self) -> TokenStore | None:
        """The store to check credentials against; None while the server is open."""
        if self.store is None:
            return None
        if self._open and not self.store.records():
            return None
        # Latched: revoking every token later must not reopen a running server.
        self._open = False
        return self.store

    def identify(self, headers: Any, cookies: dict[str, str]) -> Identity | None:
        """The identity behind a request, or None when it presents no valid credential."""
        store = self._guard()
        if store is None:
            return OPEN_ACCESS
        scheme, _, value = str(headers.get("authorization", "")).partition(" ")
        if scheme.lower() == "bearer" and value.strip():
            return store.identify(value.strip())
        session = cookies.get(COOKIE)
        return self.sessions.identify(session, store) if session else None

    def login(self, token: str) -> tuple[Identity, str | None]:
        """Check a token: its identity and a new browser session id (None when open)."""
        store = self._guard()
        if store is None:
            return OPEN_ACCESS, None
        record = store.find(token)
        if record is None:
            raise AccessDenied("That token is not valid. Check it and retry.", code="unauthorized")
        return record.identity(), self.sessions.create(record.id)

    def logout(self, cookies: dict[str, str]) -> None:
        """End the browser session the cookies hold, if any."""
        self.sessions.end(cookies.get(COOKIE, ""))


NOT_LOGGED_IN: Final = (
    "Log in with a KyberCore token (POST /api/session, or send 'Authorization: Bearer "
    "<token>'). An admin creates tokens with `kybercore tokens create`."
)


def require(role: Role) -> Any:
    """A FastAPI dependency: the caller's identity, which must hold at least ``role``."""

    # A coroutine: a plain function would run in FastAPI's thread pool, and that round
    # trip through a thread was the tail of every read on a busy event loop (fleet view
    # p95/p99 24/32 ms against 15/17 ms at N = 1,000). Identifying reads memory only: the
    # server's TokenStore looks at tokens.json at most every SERVER_RECHECK_SECONDS.
    async def check(request: Request) -> Identity:
        access: Access = request.app.state.access
        identity = access.identify(request.headers, request.cookies)
        if identity is None:
            raise AccessDenied(NOT_LOGGED_IN, code="unauthorized")
        if not identity.may(role):
            raise AccessDenied(
                f"Your token ({identity.name}, {identity.role}) may not do this: it needs "
                f"the {role} role. Ask an admin for a token with that role.",
                code="forbidden",
            )
        return identity

    return Depends(check)
