"""``GET/POST/DELETE /api/session``: who am I, log in, log out.

The browser logs in once and keeps its token in an HttpOnly cookie, out of reach of the
page's scripts; scripts send ``Authorization: Bearer`` instead and need none of this.
"""

from __future__ import annotations

from typing import Any, Literal

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, Field

from kybercore.api.auth import COOKIE, Role
from kybercore.api.security import Access
from kybercore.errors import AccessDenied

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
    """Check a token and keep it in an HttpOnly cookie for this browser."""
    access: Access = request.app.state.access
    identity = access.identify({"authorization": f"Bearer {body.token}"}, {})
    if identity is None:
        raise AccessDenied("That token is not valid. Check it and retry.", code="unauthorized")
    answer = JSONResponse({"access": access.mode, "name": identity.name, "role": identity.role})
    if access.mode == "tokens":
        answer.set_cookie(
            COOKIE,
            body.token,
            httponly=True,
            samesite="strict",
            secure=request.url.scheme == "https",
            max_age=30 * 24 * 3600,
        )
    return answer


@router.delete("/api/session", status_code=204)
async def logout() -> Response:
    """Forget this browser's token."""
    answer = Response(status_code=204)
    answer.delete_cookie(COOKIE)
    return answer
