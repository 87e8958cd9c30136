"""A running fleet with its ledger, over real printers and a real database, for the
ledger's integration tests; and what Moonraker itself says, read over HTTP."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import httpx
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.fleet.service import FleetService
from kybercore.ledger.service import LedgerService
from kybercore.registry.models import PrinterConfig
from kybercore.registry.store import PrinterRegistry, write_printers
from kybercore.sim.stack import PrinterStack
from tests.helpers import wait_for

READY_WITHIN = 60.0
"""A fresh fleet connects and reads its history in a second or two; 60 s of slack."""


def configs(stacks: list[PrinterStack]) -> list[PrinterConfig]:
    """printers.json entries for virtual printers, named as their stacks."""
    return [
        PrinterConfig(id=stack.options.name, name=stack.options.name, moonraker_url=stack.url)
        for stack in stacks
    ]


@contextlib.asynccontextmanager
async def running_ledger(
    printers: list[PrinterConfig],
    folder: Path,
    http: httpx.AsyncClient,
    engine: AsyncEngine,
    **options: Any,
) -> AsyncIterator[LedgerService]:
    """KyberCore's fleet and ledger over ``printers``; every enabled printer is online and
    its history caught up before this yields. Both stop on exit (KyberCore stopping)."""
    path = folder / "printers.json"
    write_printers(path, printers)
    fleet = FleetService(PrinterRegistry(path), http)
    ledger = LedgerService(fleet, engine, tick=0.1, queue_poll=0.2, **options)
    await fleet.start()
    try:
        await ledger.start()
        try:
            enabled = [p.id for p in printers if p.enabled]
            await wait_for(
                lambda: all(ledger.caught_up(pid) for pid in enabled),
                READY_WITHIN,
                "every printer online and its history caught up",
            )
            yield ledger
        finally:
            await ledger.stop()
    finally:
        await fleet.stop()


async def moonraker(http: httpx.AsyncClient, stack: PrinterStack, path: str, **params: Any) -> Any:
    """``GET path`` on the printer's Moonraker: its ``result``."""
    answer = await http.get(f"{stack.url}{path}", params=params, timeout=30)
    answer.raise_for_status()
    return answer.json()["result"]


async def newest_job(http: httpx.AsyncClient, stack: PrinterStack) -> dict[str, Any] | None:
    """The printer's newest job in Moonraker's history, if any."""
    jobs = (await moonraker(http, stack, "/server/history/list", limit=1))["jobs"]
    return jobs[0] if jobs else None


def finished(http: httpx.AsyncClient, stack: PrinterStack, job_id: str) -> Callable[[], Any]:
    """A predicate: Moonraker's job ``job_id`` has ended and the printer is idle again."""

    async def check() -> bool:
        job = (await moonraker(http, stack, "/server/history/job", uid=job_id))["job"]
        state = await moonraker(http, stack, "/printer/objects/query", print_stats="state")
        idle = state["status"]["print_stats"]["state"] not in ("printing", "paused")
        return bool(job["status"] != "in_progress" and idle)

    return check
