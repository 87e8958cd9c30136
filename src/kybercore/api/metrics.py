"""``GET /metrics``: the fleet in Prometheus' text format, for a viewer token (or anyone on
an open, loopback-only server), built from memory at scrape time
(:mod:`kybercore.ledger.metrics`): a scrape never reaches a printer or the database, and
its formatting runs in a worker thread. On ``serve`` the ledger holds the figures, on a
front on NATS :class:`kybercore.scale.front_metrics.FrontMetrics`."""

from __future__ import annotations

import asyncio
from typing import Annotated

from fastapi import APIRouter, Depends
from fastapi.responses import Response
from prometheus_client import CONTENT_TYPE_LATEST
from starlette.requests import HTTPConnection

from kybercore.api.deps import VIEWER, started
from kybercore.ledger.metrics import Source, exposition

router = APIRouter()


async def metrics_source(connection: HTTPConnection) -> Source:
    """The app's source of the metrics, started by the lifespan."""
    source: Source = started(connection, "metrics", "The fleet's metrics")
    return source


Figures = Annotated[Source, Depends(metrics_source)]


@router.get(
    "/metrics",
    response_class=Response,
    responses={200: {"content": {"text/plain": {}}}},
    dependencies=[VIEWER],
)
async def metrics(figures: Figures) -> Response:
    """Printers by connection and Klippy state, heaters, print progress, jobs by outcome,
    queue depth, Moonraker reconnects (not on a front), browser clients and event-loop lag."""
    body = await asyncio.to_thread(exposition, figures.metrics())
    return Response(body, media_type=CONTENT_TYPE_LATEST)
