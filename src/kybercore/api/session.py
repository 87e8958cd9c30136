"""``GET/POST/DELETE /api/session``: who am I, log in, log out.

The browser logs in with a token and gets a session in an HttpOnly cookie, out of reach
of the page's scripts: a random id that lasts 12 hours, ends at logout and with the token
(:class:`~kybercore.api.auth.BrowserSessions`); the token itself never goes into the
cookie. Scripts send ``Authorization: Bearer`` instead and need none of this.
"""

from __future__ import annotations

from typing import Any, Literal

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, Field

from kybercore.api.auth import COOKIE, SESSION_SECONDS, Role
from kybercore.api.recorder import note
from kybercore.api.security import Access

router = APIRouter()


class SessionLogin(BaseModel):
    """A token to log the browser in with."""

    token: str = Field(min_length=1, max_length=200, description="A KyberCore token.")


class SessionInfo(BaseModel):
    """Whether this server asks for tokens, and who the caller is."""

    access: Literal["open", "tokens"]
    name: str | None
    role: Role | None


@router.get("/api/session", response_model=SessionInfo)
async def session(request: Request) -> dict[str, Any]:
    """Whether tokens are required, and the caller's identity if any."""
    access: Access = request.app.state.access
    identity = access.identify(request.headers, request.cookies)
    return {
        "access": access.mode,
        "name": identity.name if identity else None,
        "role": identity.role if identity else None,
    }


@router.post("/api/session", response_model=SessionInfo)
async def login(request: Request, body: SessionLogin) -> Response:
    """Check a token and give this browser a session (an HttpOnly cookie) made from it."""
    access: Access = request.app.state.access
    identity, session = access.login(body.token)
    note(request, actor=identity.name, role=identity.role)  # the audit row names who logged in
    answer = JSONResponse({"access": access.mode, "name": identity.name, "role": identity.role})
    if session is not None:
        answer.set_cookie(
            COOKIE,
            session,
            httponly=True,
            samesite="strict",
            secure=request.url.scheme == "https",
            max_age=SESSION_SECONDS,
        )
    return answer


@router.delete("/api/session", status_code=204)
async def logout(request: Request) -> Response:
    """End this browser's session: its cookie is worth nothing from now on."""
    access: Access = request.app.state.access
    access.logout(request.cookies)
    answer = Response(status_code=204)
    answer.delete_cookie(COOKIE, httponly=True, samesite="strict")
    return answer
