"""``GET /api/audit``: the audit log, for admins (:mod:`kybercore.ledger.audit`).

Read-only by design: no route writes, edits or deletes a row; rows are written by the
actions themselves (:mod:`kybercore.api.recorder`, the CLI).
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request
from pydantic import BaseModel, Field

from kybercore.api.deps import ADMIN
from kybercore.api.models import ERROR_RESPONSES
from kybercore.errors import ConfigError
from kybercore.ledger.audit import MAX_LIMIT, AuditLog, AuditQuery

router = APIRouter()


class AuditItem(BaseModel):
    """One recorded action."""

    id: int
    at: datetime = Field(description="When, ISO-8601 UTC.")
    actor: str = Field(description="Token name, 'local' (open server), 'cli:<user>'...")
    role: str
    action: str = Field(description="e.g. printer.edit, printer.cancel, plate.clear.")
    target: str = Field(description="printer:<id>, job:<id>, token:<id>, or empty.")
    params: dict[str, Any] = Field(description="Its parameters, secrets as '[redacted]'.")
    outcome: str = Field(description="'ok', or the error's code.")
    client: str = Field(description="The client's address; 'local' for the CLI.")
    request_id: str = Field(description="The X-Request-ID of the HTTP answer.")


class AuditPage(BaseModel):
    """A page of the audit log, newest first."""

    total: int = Field(description="Rows matching the filters, over every page.")
    items: list[AuditItem]


@router.get("/api/audit", response_model=AuditPage, responses=ERROR_RESPONSES, dependencies=[ADMIN])
async def audit(
    request: Request,
    actor: Annotated[str | None, Query(max_length=128)] = None,
    target: Annotated[
        str | None, Query(max_length=256, description="printer:a, or just the id a.")
    ] = None,
    action: Annotated[str | None, Query(max_length=64)] = None,
    since: Annotated[
        datetime | None, Query(alias="from", description="ISO-8601; UTC when no offset.")
    ] = None,
    until: Annotated[datetime | None, Query(alias="to", description="ISO-8601, excluded.")] = None,
    limit: Annotated[int, Query(ge=1, le=MAX_LIMIT)] = 50,
    offset: Annotated[int, Query(ge=0)] = 0,
) -> dict[str, Any]:
    """Who did what to which printer or job, when, from where, and how it ended."""
    audit_log: AuditLog | None = getattr(request.app.state, "audit", None)
    if audit_log is None:
        raise ConfigError("This KyberCore runs without a database, so it keeps no audit log.")
    query = AuditQuery(actor, target, action, since, until, limit, offset)
    total, items = await audit_log.query(query)
    return {"total": total, "items": items}
