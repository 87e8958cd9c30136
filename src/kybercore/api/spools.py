"""The fleet's spools: ``GET /api/spools``, which Spoolman spool is on which printer.

Read from the printers' views (each printer's Moonraker relays its ``[spoolman]``), so it
answers the same on a single server and on a front whose printers run on workers, and
never asks Spoolman or a printer anything: what it shows is what the tiles show.
"""

from __future__ import annotations

from typing import Any, Literal

from fastapi import APIRouter
from pydantic import BaseModel, Field

from kybercore.api.deps import VIEWER, Service
from kybercore.api.models import ERROR_RESPONSES, SpoolOut
from kybercore.core.spools import spool_map

router = APIRouter()


class Holder(BaseModel):
    """A printer, as the spool map names it."""

    id: str
    name: str


class SpoolOnPrinters(SpoolOut):
    """An active spool and the printers it is set active on."""

    printers: list[Holder] = Field(
        description="Usually one; more means the same spool was set active on several "
        "printers, which Spoolman cannot tell apart."
    )


class PrinterWithoutSpool(Holder):
    """A printer that shows no spool, and why."""

    spoolman: Literal["unknown", "absent", "none", "active", "unreachable"] = Field(
        description="unknown (not read yet), absent (no [spoolman] in its moonraker.conf), "
        "none (no spool set active), unreachable (a spool is set but Spoolman did not "
        "answer with it)."
    )


class SpoolMap(BaseModel):
    """Every active spool with its printer, and the printers without one."""

    low_below_g: float = Field(description="A spool with fewer grams left is shown as low.")
    spools: list[SpoolOnPrinters] = Field(description="Fewest grams left first.")
    without: list[PrinterWithoutSpool] = Field(description="In printers.json order.")


@router.get(
    "/api/spools", response_model=SpoolMap, responses=ERROR_RESPONSES, dependencies=[VIEWER]
)
async def spools(service: Service) -> dict[str, Any]:
    """Which Spoolman spool is on which printer (material, colour, grams left), and the
    printers with no spool or no Spoolman. Read only: Moonraker reports usage itself."""
    return spool_map(service.views())
