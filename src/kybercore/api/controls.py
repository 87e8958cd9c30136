"""What a printer's page needs besides its live view: its macros, the running print's
objects, and whether its host serves Mainsail or Fluidd. Everything the page *does* goes
through the validated G-code and action routes (:mod:`kybercore.api.printers`), never
through here.
"""

from __future__ import annotations

from typing import Literal

from fastapi import APIRouter
from pydantic import BaseModel, Field

from kybercore.api.deps import VIEWER, Service
from kybercore.api.models import ERROR_RESPONSES
from kybercore.core.print_objects import print_objects_of

router = APIRouter(prefix="/api/printers")


class MacroOut(BaseModel):
    """A ``[gcode_macro]`` of the printer's Klipper configuration."""

    name: str = Field(description="The command that runs it, upper case.")
    description: str = Field(description="Its ``description`` option; empty when none.")


class PrintObjectOut(BaseModel):
    """An object of the print, as the slicer labelled it, in bed millimetres."""

    name: str = Field(description="As Klipper knows it, upper case; EXCLUDE_OBJECT NAME=...")
    center: tuple[float, float] | None
    polygon: list[tuple[float, float]] = Field(description="Its outline; empty when none.")


class PrintObjectsOut(BaseModel):
    """The running print's objects: which are excluded, which is being printed."""

    available: bool = Field(description="False when Klipper has no [exclude_object] section.")
    objects: list[PrintObjectOut]
    excluded: list[str]
    current: str | None = Field(description="The object being printed now, if any.")


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
    "/{printer_id}/objects",
    response_model=PrintObjectsOut,
    responses=ERROR_RESPONSES,
    dependencies=[VIEWER],
)
async def print_objects(service: Service, printer_id: str) -> PrintObjectsOut:
    """The running print's objects, read from Klipper now. Excluding one goes through the
    validated G-code route: ``EXCLUDE_OBJECT NAME=<name>``."""
    found = print_objects_of(await service.exclude_object_status(printer_id))
    return PrintObjectsOut.model_validate(found, from_attributes=True)


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
