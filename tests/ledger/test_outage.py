"""A ledger whose database stops answering: an ingest worker at a site writes to the central
PostgreSQL across the WAN, and a cut line must lose nothing. The jobs heard and the state
changes seen meanwhile are written once the database answers again, the ledger's tasks
outlive the outage, and the log says it in a line, not a traceback per retry. A real
PostgreSQL, reached through a :class:`~tests.cable.Cable` the test cuts and mends."""

from __future__ import annotations

import logging
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from sqlalchemy import select
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.db import open_database, transaction
from kybercore.fleet.service import FleetService
from kybercore.ledger import records
from kybercore.ledger.service import LedgerService, _Feed
from kybercore.ledger.tables import printer_states
from kybercore.ledger.unwritten import UNWRITTEN
from kybercore.moonraker.events import Notification
from kybercore.registry.store import PrinterRegistry, write_printers
from tests.cable import Cable, to_database
from tests.helpers import wait_for
from tests.ledger.test_service import FINISHED

T0 = 1_700_000_000.0

BACK_WITHIN = 30.0
"""The writer retries every second, the timeline every tick; a busy machine is slower."""


@pytest.fixture
async def line(postgres_database: str) -> AsyncIterator[tuple[Cable, AsyncEngine, AsyncEngine]]:
    """The cable to the database, an engine through it and one straight to it."""
    direct = await open_database(postgres_database)
    cable, remote_url = to_database(postgres_database)
    remote = await open_database(remote_url)
    yield cable, remote, direct
    await remote.dispose()
    await direct.dispose()
    cable.close()


def finished(job_id: str) -> Notification:
    return Notification(
        "notify_history_changed", [{**FINISHED, "job": {**FINISHED["job"], "job_id": job_id}}]
    )


def no_printers(folder: Path, http: httpx.AsyncClient) -> FleetService:
    """A fleet of none: the ledgers here hear what the tests make them hear."""
    path = folder / "printers.json"
    write_printers(path, [])
    return FleetService(PrinterRegistry(path), http)


def hear(ledger: LedgerService, event: Notification) -> None:
    """``event`` from printer p1, whose Moonraker instance its catch-up read (a printer not
    in the fleet: the ledger forgets it at its next sweep)."""
    ledger._feeds["p1"] = _Feed(instance="moonraker-1")
    ledger._on_event("p1", event)


async def jobs_written(engine: AsyncEngine) -> set[str]:
    _, rows = await records.page(engine, records.HistoryFilter(), 10, 0)
    return {row["moonraker_job_id"] for row in rows}


async def states_written(engine: AsyncEngine, printer: str) -> list[Any]:
    async def read(conn: Any) -> list[Any]:
        found = await conn.execute(
            select(printer_states.c.state).where(printer_states.c.printer == printer)
        )
        return [row.state for row in found]

    return await transaction(engine, read, write=False)


async def test_a_database_cut_off_loses_nothing_the_ledger_heard(
    line: tuple[Cable, AsyncEngine, AsyncEngine],
    tmp_path: Path,
    http: httpx.AsyncClient,
    caplog: pytest.LogCaptureFixture,
) -> None:
    cable, remote, direct = line
    kept = tmp_path / UNWRITTEN
    ledger = LedgerService(
        no_printers(tmp_path, http), remote, tick=0.05, queue_poll=0.05, unwritten=kept
    )
    await ledger.start()
    try:
        hear(ledger, finished("00001A"))
        await ledger.flush()
        assert await jobs_written(direct) == {"00001A"}
        caplog.set_level(logging.INFO, logger="kybercore")
        cable.cut()
        # Heard while the line is cut: a job that finished, a printer that started printing.
        hear(ledger, finished("00002B"))
        ledger.timeline.observe("p1", "printing")

        def said(what: str) -> bool:
            return any(what in r.getMessage() for r in caplog.records)

        await wait_for(
            lambda: said("job history heard meanwhile is kept")
            and said("state changes seen meanwhile are kept")
            and said("cannot read the queue's gates"),
            BACK_WITHIN, "the ledger to find the database away",
        )  # fmt: skip
        # Kept on disk meanwhile (a process killed now would not lose it) ...
        await wait_for(kept.exists, BACK_WITHIN, "the state change kept on disk")
        cable.mend()
        await wait_for(
            lambda: _equal(jobs_written(direct), {"00001A", "00002B"}), BACK_WITHIN,
            "the job heard during the cut written",
        )  # fmt: skip
        await wait_for(
            lambda: _equal(states_written(direct, "p1"), ["printing"]), BACK_WITHIN,
            "the state seen during the cut written",
        )  # fmt: skip
        # ... and the file goes once it is written: a next start would not take it back.
        await wait_for(lambda: not kept.exists(), BACK_WITHIN, "the kept file removed")
        assert all(not task.done() for task in ledger._tasks), "a ledger task died"
        # Said once the write returns, which is after its commit the test saw.
        await wait_for(
            lambda: said("can write the job history again"), BACK_WITHIN, "the writer to say so"
        )
        traced = [r.getMessage() for r in caplog.records if r.exc_info]
        assert traced == [], "an outage is said in a line, not a traceback"
    finally:
        await ledger.stop()
    assert await jobs_written(direct) == {"00001A", "00002B"}  # each once


async def test_a_process_killed_while_the_database_is_away_loses_no_state_change(
    line: tuple[Cable, AsyncEngine, AsyncEngine],
    tmp_path: Path,
    http: httpx.AsyncClient,
) -> None:
    cable, remote, direct = line
    kept = tmp_path / UNWRITTEN
    fleet = no_printers(tmp_path, http)
    ledger = LedgerService(fleet, remote, tick=0.05, unwritten=kept)
    await ledger.start()
    cable.cut()
    ledger.timeline.observe("p1", "printing", at=T0)
    await wait_for(kept.exists, BACK_WITHIN, "the state change kept on disk")
    # Killed: its tasks end where they are, and nothing of stop() runs.
    ledger._unlisten()
    for task in ledger._tasks:
        task.cancel()
    killed = time.time()
    cable.mend()
    again = LedgerService(fleet, remote, tick=3600, unwritten=kept)
    await again.start()
    try:
        assert not kept.exists()
        # Ended where the killed run saw p1 leave (p1 is in no fleet here: its sweep
        # forgot it), kept on disk with it.
        [(state, started, ended)] = await transaction(direct, _intervals, write=False)
        assert (state, started) == ("printing", T0)
        assert ended is not None
        assert T0 < ended <= killed
    finally:
        await again.stop()


async def _equal(read: Any, expected: Any) -> bool:
    return await read == expected


async def test_stopping_while_the_database_is_away_keeps_the_state_changes_for_next_start(
    line: tuple[Cable, AsyncEngine, AsyncEngine],
    tmp_path: Path,
    http: httpx.AsyncClient,
    caplog: pytest.LogCaptureFixture,
) -> None:
    cable, remote, direct = line
    kept = tmp_path / UNWRITTEN
    fleet = no_printers(tmp_path, http)
    # A tick and a write retry longer than the test: only stop() tries to write.
    ledger = LedgerService(fleet, remote, tick=3600, unwritten=kept)
    await ledger.start()
    ledger.timeline.observe("p1", "idle", at=T0)
    await ledger.flush()
    cable.cut()
    hear(ledger, finished("00003C"))
    ledger.timeline.observe("p1", "printing", at=T0 + 10)
    caplog.set_level(logging.INFO, logger="kybercore")
    before = time.time()
    await ledger.stop()
    after = time.time()
    said = [r.getMessage() for r in caplog.records if "stopping with" in r.getMessage()]
    assert len(said) == 1, [r.getMessage() for r in caplog.records]
    assert "1 jobs heard and 1 state changes seen not written" in said[0]
    assert "the database does not answer" in said[0]
    assert "come back from the printers' Moonraker history" in said[0]
    assert f"the state changes are kept in {kept}" in said[0]
    # The next start, the database back: the stop's changes are written, up to the stop.
    cable.mend()
    again = LedgerService(fleet, remote, tick=3600, unwritten=kept)
    await again.start()
    try:
        assert not kept.exists()
        assert any("wrote the 2 state changes a previous run could not" in r.getMessage()
                   for r in caplog.records)  # fmt: skip
        intervals = await transaction(direct, _intervals, write=False)
        assert intervals[:2] == [("idle", T0, T0 + 10), ("printing", T0 + 10, intervals[1][2])]
        assert before <= intervals[1][2] <= after
    finally:
        await again.stop()


async def _intervals(conn: Any) -> list[tuple[str, float, float | None]]:
    s = printer_states.c
    found = await conn.execute(
        select(s.state, s.started_at, s.ended_at).where(s.printer == "p1").order_by(s.id)
    )
    return [tuple(row) for row in found]
