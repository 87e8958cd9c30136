"""``GET /api/discovery``: the Moonraker servers announcing themselves on the network
(mDNS, Moonraker's ``[zeroconf]``), each marked with the printer that already uses it.
Adding one goes through ``POST /api/printers`` like any printer."""

from __future__ import annotations

from dataclasses import asdict
from typing import Annotated
from urllib.parse import urlsplit

from fastapi import APIRouter, Query
from pydantic import BaseModel, Field

from kybercore.api.deps import ADMIN, Service
from kybercore.api.models import ERROR_RESPONSES
from kybercore.fleet.discovery import browse

router = APIRouter(prefix="/api/discovery")


class FoundPrinter(BaseModel):
    """A Moonraker heard on the network."""

    name: str = Field(description="Its mDNS instance name (Moonraker-<uuid> or its unit).")
    host: str
    port: int
    url: str = Field(description="The address to add it with.")
    version: str = Field(description="Moonraker's version, as it announces it.")
    uuid: str
    suggested_id: str = Field(description="A printer id from its host name.")
    added_as: str | None = Field(description="The printer already using this Moonraker.")


def _where(url: str) -> tuple[str, int | None]:
    parts = urlsplit(url)
    return (parts.hostname or "").lower(), parts.port


@router.get("", response_model=list[FoundPrinter], responses=ERROR_RESPONSES, dependencies=[ADMIN])
async def discover(
    service: Service,
    seconds: Annotated[float, Query(ge=0.5, le=10, description="How long to listen.")] = 3,
) -> list[FoundPrinter]:
    """Listen for Moonraker's mDNS announcements for ``seconds``; what answered, by name."""
    known = {_where(str(view["moonraker_url"])): view["id"] for view in service.views()}
    return [
        FoundPrinter(**asdict(found), added_as=known.get(_where(found.url)))
        for found in await browse(seconds, service.mdns_interfaces)
    ]
