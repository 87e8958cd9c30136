"""What the routers share: the fleet service, the role each route needs, and the JSON
response class.
"""

from __future__ import annotations

from typing import Annotated, Any, Final

import orjson
from fastapi import Depends
from fastapi.responses import JSONResponse
from starlette.requests import HTTPConnection

from kybercore.api.security import require
from kybercore.fleet.service import FleetService

VIEWER: Final = require("viewer")
OPERATOR: Final = require("operator")
ADMIN: Final = require("admin")


def fleet_service(connection: HTTPConnection) -> FleetService:
    """The app's FleetService, started by the lifespan (HTTP requests and WebSockets)."""
    service: FleetService = connection.app.state.service
    return service


Service = Annotated[FleetService, Depends(fleet_service)]
"""A route parameter that receives the app's FleetService."""


class ORJSONResponse(JSONResponse):
    """JSON answers serialized with orjson: the fleet view is the hot path."""

    def render(self, content: Any) -> bytes:
        """``content`` as JSON bytes."""
        return orjson.dumps(content)
