"""The ledger service's own promises, without printers: what ``flush`` guarantees."""

from __future__ import annotations

import asyncio
from collections.abc import Sequence
from pathlib import Path

import httpx
import pytest
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.fleet.service import FleetService
from kybercore.ledger import records
from kybercore.ledger.service import LedgerService, Row, _Feed
from kybercore.moonraker.events import Notification
from kybercore.registry.store import PrinterRegistry, write_printers

FINISHED = {
    "action": "finished",
    "job": {
        "job_id": "00002A",
        "filename": "cube.gcode",
        "status": "completed",
        "start_time": 1_767_225_600.0,
        "end_time": 1_767_229_200.0,
        "print_duration": 3500.0,
        "filament_used": 1200.0,
    },
}


async def test_flush_returns_once_the_batch_the_writer_took_is_written(
    tmp_path: Path, http: httpx.AsyncClient, database: AsyncEngine, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``flush()`` promises every job heard before it is in the table when it returns, also
    the batch the writer task took just before and is still writing (a caller reading the
    history right after a flush, as the statistics do, must not miss it)."""
    path = tmp_path / "printers.json"
    write_printers(path, [])
    ledger = LedgerService(FleetService(PrinterRegistry(path), http), database)
    await ledger.start()
    try:
        taken, release, written = asyncio.Event(), asyncio.Event(), asyncio.Event()
        upsert = ledger.history.upsert

        async def held_upsert(rows: Sequence[Row]) -> None:
            taken.set()
            await release.wait()
            await upsert(rows)
            written.set()

        monkeypatch.setattr(ledger.history, "upsert", held_upsert)
        # The printer's Moonraker instance is known (its catch-up read it): the job is
        # written live, by the writer task.
        ledger._feeds["p1"] = _Feed(instance="moonraker-1")
        ledger._on_event("p1", Notification("notify_history_changed", [FINISHED]))
        await taken.wait()
        flushing = asyncio.create_task(ledger.flush())
        release.set()
        await flushing
        assert written.is_set(), "flush() returned before the job heard was written"
        total, rows = await records.page(database, records.HistoryFilter(), 10, 0)
        assert (total, rows[0]["moonraker_job_id"]) == (1, "00002A")
    finally:
        await ledger.stop()
