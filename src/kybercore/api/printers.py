"""``/api/printers``: the fleet's printers (add, read, edit, remove), actions on one
printer, their dry runs, and G-code.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query
from fastapi.responses import Response

from kybercore.api.deps import ADMIN, OPERATOR, VIEWER, ORJSONResponse, Service
from kybercore.api.models import (
    ERROR_RESPONSES,
    ActionName,
    ActionRequest,
    ActionResult,
    CheckResult,
    ConsoleEntry,
    GcodeRequest,
    GcodeResult,
    PrinterView,
    action_result,
    check_result,
    gcode_result,
)
from kybercore.registry.models import PrinterCreate, PrinterUpdate

router = APIRouter(prefix="/api/printers")


@router.get("", responses={200: {"model": list[PrinterView]}}, dependencies=[VIEWER])
async def list_printers(service: Service) -> Response:
    """Every printer: configuration fused with live state, from the live cache."""
    # Serialized once per tick and shared by every reader: nothing to encode per request.
    return Response(service.fleet_json(), media_type="application/json")


@router.post(
    "",
    status_code=201,
    responses={201: {"model": PrinterView}, **ERROR_RESPONSES},
    dependencies=[ADMIN],
)
async def add_printer(
    service: Service,
    new: PrinterCreate,
    check: Annotated[
        bool,
        Query(
            description="Test the connection first: save only if Moonraker answers (the "
            "dashboard asks this; resend without it to save a printer that is off)."
        ),
    ] = False,
) -> Response:
    """Add a printer to printers.json and connect to it."""
    return ORJSONResponse(await service.add_printer(new, check=check), status_code=201)


@router.get(
    "/{printer_id}",
    responses={200: {"model": PrinterView}, **ERROR_RESPONSES},
    dependencies=[VIEWER],
)
async def get_printer(service: Service, printer_id: str) -> Response:
    """One printer, fused with its live state."""
    return ORJSONResponse(service.view(printer_id))


@router.patch(
    "/{printer_id}",
    responses={200: {"model": PrinterView}, **ERROR_RESPONSES},
    dependencies=[ADMIN],
)
async def edit_printer(service: Service, printer_id: str, patch: PrinterUpdate) -> Response:
    """Edit a printer (PATCH: omitted fields keep their value)."""
    return ORJSONResponse(await service.update_printer(printer_id, patch))


@router.delete("/{printer_id}", status_code=204, responses=ERROR_RESPONSES, dependencies=[ADMIN])
async def remove_printer(service: Service, printer_id: str) -> Response:
    """Remove a printer from printers.json and disconnect from it."""
    await service.remove_printer(printer_id)
    return Response(status_code=204)


@router.post(
    "/{printer_id}/actions/{action}",
    response_model=ActionResult,
    responses=ERROR_RESPONSES,
    dependencies=[OPERATOR],
)
async def act(
    service: Service, printer_id: str, action: ActionName, body: ActionRequest | None = None
) -> dict[str, Any]:
    """Validate, then run an action on one printer; the real outcome or an error."""
    body = body or ActionRequest()
    outcome = await service.act(
        printer_id, action, body.params(), force=body.force, confirm=body.confirm
    )
    return action_result(outcome)


@router.post(
    "/{printer_id}/actions/{action}/check",
    response_model=CheckResult,
    responses=ERROR_RESPONSES,
    dependencies=[VIEWER],
)
async def check(
    service: Service, printer_id: str, action: ActionName, body: ActionRequest | None = None
) -> dict[str, Any]:
    """Dry run: what validation says about the action now, without doing it."""
    body = body or ActionRequest()
    verdict = await service.dry_run(printer_id, action, body.params(), body.force)
    return check_result(printer_id, action, verdict)


@router.post(
    "/{printer_id}/gcode",
    response_model=GcodeResult,
    responses=ERROR_RESPONSES,
    dependencies=[OPERATOR],
)
async def gcode(service: Service, printer_id: str, body: GcodeRequest) -> dict[str, Any]:
    """Run G-code; answers when it has finished, with Klipper's response lines (they
    also stream over /ws to the consoles watching this printer)."""
    outcome = await service.act(
        printer_id, "gcode", {"script": body.script}, force=body.force, confirm=body.confirm
    )
    return gcode_result(outcome)


@router.get(
    "/{printer_id}/console",
    response_model=list[ConsoleEntry],
    responses=ERROR_RESPONSES,
    dependencies=[VIEWER],
)
async def console(
    service: Service,
    printer_id: str,
    count: Annotated[int, Query(ge=1, le=1000, description="How many entries, newest.")] = 100,
) -> list[dict[str, Any]]:
    """The printer's recent console, oldest first: the commands every client sent and
    Klipper's responses (Moonraker's G-code store)."""
    return await service.console_history(printer_id, count)
