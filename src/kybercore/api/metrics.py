"""``GET /metrics``: the fleet in Prometheus' text format, for a viewer token (or anyone on
an open, loopback-only server), built from memory at scrape time
(:mod:`kybercore.ledger.metrics`): a scrape never reaches a printer or the database, and
its formatting runs in a worker thread."""

from __future__ import annotations

import asyncio
from typing import Annotated

from fastapi import APIRouter, Depends
from fastapi.responses import Response
from prometheus_client import CONTENT_TYPE_LATEST
from starlette.requests import HTTPConnection

from kybercore.api.deps import VIEWER, started
from kybercore.ledger.metrics import exposition
from kybercore.ledger.service import LedgerService

router = APIRouter()


def ledger_service(connection: HTTPConnection) -> LedgerService:
    """The app's LedgerService, started by the lifespan (not on a front: the live figures
    are in the workers)."""
    service: LedgerService = started(connection, "ledger", "The fleet's metrics")
    return service


Ledger = Annotated[LedgerService, Depends(ledger_service)]


@router.get(
    "/metrics",
    response_class=Response,
    responses={200: {"content": {"text/plain": {}}}},
    dependencies=[VIEWER],
)
async def metrics(ledger: Ledger) -> Response:
    """Printers by connection and Klippy state, heaters, print progress, jobs by outcome,
    queue depth, Moonraker reconnects, browser clients and event-loop lag."""
    body = await asyncio.to_thread(exposition, ledger.metrics())
    return Response(body, media_type=CONTENT_TYPE_LATEST)
