"""What the routers share: the fleet service, the job queue, the role each route needs,
and the JSON response class.

The dependencies that read the app's state are coroutines: FastAPI runs a plain function
in its thread pool, a round trip through a thread (and, on a busy event loop, several of
its turns) per request for an attribute read.
"""

from __future__ import annotations

from typing import Annotated, Any, Final

import orjson
from fastapi import Depends
from fastapi.responses import JSONResponse
from sqlalchemy.ext.asyncio import AsyncEngine
from starlette.requests import HTTPConnection

from kybercore.api.auth import Identity
from kybercore.api.security import require
from kybercore.errors import not_on_front
from kybercore.fleet.service import FleetService
from kybercore.jobs.service import QueueService

VIEWER: Final = require("viewer")
OPERATOR: Final = require("operator")
ADMIN: Final = require("admin")


async def fleet_service(connection: HTTPConnection) -> FleetService:
    """The app's FleetService, started by the lifespan (HTTP requests and WebSockets)."""
    service: FleetService = connection.app.state.service
    return service


Service = Annotated[FleetService, Depends(fleet_service)]
"""A route parameter that receives the app's FleetService."""


async def queue_service(connection: HTTPConnection) -> QueueService:
    """The app's QueueService, started by the lifespan."""
    queue: QueueService = started(connection, "queue", "The job queue")
    return queue


Queue = Annotated[QueueService, Depends(queue_service)]
"""A route parameter that receives the app's QueueService."""

Operator = Annotated[Identity, OPERATOR]
"""A route parameter: the caller, who must hold the operator role (the queue records who
did what)."""


async def database(connection: HTTPConnection) -> AsyncEngine:
    """The app's database (the queue's and the ledger's; on NATS, the one every front and
    worker shares), opened by the lifespan."""
    engine: AsyncEngine = connection.app.state.engine
    return engine


Database = Annotated[AsyncEngine, Depends(database)]
"""A route parameter that receives the app's database engine."""


def started(connection: HTTPConnection, name: str, what: str) -> Any:
    """The app's ``name`` service; one a front on NATS does not run (the ledger, which its
    workers write) answers that ``what`` is not available there (never a 500)."""
    service = getattr(connection.app.state, name, None)
    if service is None:
        raise not_on_front(what)
    return service


class ORJSONResponse(JSONResponse):
    """JSON answers serialized with orjson: the fleet view is the hot path."""

    def render(self, content: Any) -> bytes:
        """``content`` as JSON bytes."""
        return orjson.dumps(content)
