"""``GET /metrics``: the fleet in Prometheus' text format, for a viewer token (or anyone on
an open, loopback-only server), built from memory at scrape time
(:mod:`kybercore.ledger.metrics`): a scrape never reaches a printer or the database, and
its formatting runs in a worker thread."""

from __future__ import annotations

import asyncio

from fastapi import APIRouter
from fastapi.responses import Response
from prometheus_client import CONTENT_TYPE_LATEST

from kybercore.api.deps import VIEWER
from kybercore.api.history import Ledger
from kybercore.ledger.metrics import exposition

router = APIRouter()


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
