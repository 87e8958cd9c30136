"""The whole fleet: ``/api/health``, ``/api/ready`` and ``/api/fleet/actions``, one action
(or its dry run) on several printers at once, with one result per printer.
"""

from __future__ import annotations

import asyncio
from typing import Any

from fastapi import APIRouter

from kybercore import __version__
from kybercore.api.deps import OPERATOR, VIEWER, Service
from kybercore.api.models import (
    ERROR_RESPONSES,
    ActionName,
    FleetActionRequest,
    FleetActionResult,
    FleetCheckResult,
    Health,
    Ready,
    action_result,
    check_result,
)
from kybercore.core.messages import Reason
from kybercore.errors import BrokerUnavailable, KyberCoreError
from kybercore.fleet.actions import failed_outcome, reason_dict

router = APIRouter()


@router.get("/api/health", response_model=Health, dependencies=[VIEWER])
async def health(service: Service) -> dict[str, Any]:
    """Liveness plus a one-line picture of the fleet."""
    views = service.views()
    connected = service.broker_connected
    return {
        "status": "ok",
        "version": __version__,
        "printers": len(views),
        "online": sum(v["connection"] == "online" for v in views),
        "browsers": service.hub.client_count,
        "config_error": service.config_error,
        "broker": None if connected is None else "connected" if connected else "disconnected",
    }


@router.get("/api/ready", response_model=Ready, responses=ERROR_RESPONSES)
async def ready(service: Service) -> dict[str, bool]:
    """Whether this process can serve the fleet now, for a load balancer or an orchestrator
    choosing among fronts: 503 ``broker_unavailable`` while a front is cut off from NATS.
    Needs no credential, as such checks carry none; it tells nothing else."""
    if service.broker_connected is False:
        raise BrokerUnavailable(
            "This KyberCore front is not connected to the NATS broker: its printers' states "
            "are stale and their actions are refused. Use another front until it is back."
        )
    return {"ready": True}


@router.post(
    "/api/fleet/actions/{action}",
    response_model=FleetActionResult,
    responses=ERROR_RESPONSES,
    dependencies=[OPERATOR],
)
async def act_many(
    service: Service, action: ActionName, body: FleetActionRequest
) -> dict[str, Any]:
    """One action on several printers at once (starts paced by ``stagger_seconds``); one
    result per printer."""
    outcomes = await service.act_many(
        body.printer_ids, action, body.params(), force=body.force, confirm=body.confirm,
        stagger=body.stagger_seconds,
    )  # fmt: skip
    return {"results": [action_result(o) for o in outcomes]}


@router.post(
    "/api/fleet/actions/{action}/check",
    response_model=FleetCheckResult,
    responses=ERROR_RESPONSES,
    dependencies=[VIEWER],
)
async def check_many(
    service: Service, action: ActionName, body: FleetActionRequest
) -> dict[str, Any]:
    """Dry run on several printers: what would happen on each."""
    params = body.params()

    async def one(printer_id: str) -> dict[str, Any]:
        try:
            verdict = await service.dry_run(printer_id, action, params, body.force)
        except KyberCoreError as exc:
            return _blocked(printer_id, action, exc)
        return check_result(printer_id, action, verdict)

    ids = list(dict.fromkeys(body.printer_ids))
    return {"results": list(await asyncio.gather(*(one(pid) for pid in ids)))}


def _blocked(printer_id: str, action: str, exc: KyberCoreError) -> dict[str, Any]:
    """The check of a printer whose dry run failed (unknown, offline...): a block, with the
    error's reasons, or its message as the one reason when it has none."""
    failed = failed_outcome(printer_id, action, exc)
    reasons = failed.reasons or [
        reason_dict(Reason(failed.code, "block", "state", failed.message, failed.message))
    ]
    return {"printer_id": printer_id, "action": action, "level": "block", "reasons": reasons}
