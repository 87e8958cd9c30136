"""What a printer's page needs besides its live view: its macros, and whether its host
serves Mainsail or Fluidd. Everything the page *does* goes through the validated G-code
and action routes (:mod:`kybercore.api.printers`), never through here.
"""

from __future__ import annotations

from typing import Literal

from fastapi import APIRouter
from pydantic import BaseModel, Field

from kybercore.api.deps import VIEWER, Service
from kybercore.api.models import ERROR_RESPONSES

router = APIRouter(prefix="/api/printers")


class MacroOut(BaseModel):
    """A ``[gcode_macro]`` of the printer's Klipper configuration."""

    name: str = Field(description="The command that runs it, upper case.")
    description: str = Field(description="Its ``description`` option; empty when none.")


class WebUiOut(BaseModel):
    """The web interface on the printer's host, if any."""

    kind: Literal["mainsail", "fluidd"] | None = Field(description="null when none found.")
    url: str | None


@router.get(
    "/{printer_id}/macros",
    response_model=list[MacroOut],
    responses=ERROR_RESPONSES,
    dependencies=[VIEWER],
)
async def macros(service: Service, printer_id: str) -> list[MacroOut]:
    """The printer's G-code macros, by name, without the ``_helpers``; read from Klipper's
    configuration each time (it changes with a firmware restart)."""
    found = await service.macros(printer_id)
    return [MacroOut(name=m.name, description=m.description) for m in found]


@router.get(
    "/{printer_id}/web_ui",
    response_model=WebUiOut,
    responses=ERROR_RESPONSES,
    dependencies=[VIEWER],
)
async def web_ui(service: Service, printer_id: str) -> WebUiOut:
    """Mainsail or Fluidd on the printer's host (its root page, port 80/443), for a link."""
    found = await service.web_ui.find(str(service.config(printer_id).moonraker_url))
    return WebUiOut(kind=found.kind, url=found.url) if found else WebUiOut(kind=None, url=None)
