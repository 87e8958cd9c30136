"""``GET /api/printers/{printer_id}/temperatures``: a printer's heaters over the last
minutes, for the graph on its detail view, from the in-memory ring
(:mod:`kybercore.fleet.temperatures`) of the process holding the printer's session (a front
asks the printer's worker): no request reaches the printer.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query
from pydantic import BaseModel, Field

from kybercore.api.deps import VIEWER, Service
from kybercore.api.models import ERROR_RESPONSES
from kybercore.fleet.temperatures import WINDOW_SECONDS

router = APIRouter(prefix="/api/printers")


class HeaterSeries(BaseModel):
    """One heater's samples: equal-length columns, oldest first (uPlot's data layout)."""

    t: list[float] = Field(description="Sample times, Unix epoch seconds.")
    temperature: list[float | None] = Field(description="°C; null where the series breaks.")
    target: list[float | None] = Field(description="°C; null where the series breaks.")


class TemperatureHistory(BaseModel):
    """A printer's heaters; only those that reported since KyberCore started."""

    printer: str
    series: dict[str, HeaterSeries] = Field(
        description="By heater: extruder, heater_bed. At most one sample a second; the "
        "last values are repeated at the time of the answer (a heater sends only changes)."
    )


@router.get(
    "/{printer_id}/temperatures",
    response_model=TemperatureHistory,
    responses=ERROR_RESPONSES,
    dependencies=[VIEWER],
)
async def temperatures(
    service: Service,
    printer_id: str,
    minutes: Annotated[
        float, Query(gt=0, le=WINDOW_SECONDS / 60, description="How far back, in minutes.")
    ] = 30,
) -> dict[str, Any]:
    """The printer's heater temperatures and targets over the last ``minutes``."""
    series = await service.temperatures(printer_id, minutes)  # an unknown printer: a 404
    return {"printer": printer_id, "series": series}
