"""The ledger over real Moonraker + Klippy printers: what it records equals what Moonraker
counts, a print that ends while KyberCore is down is recorded once, and a long history is
read once, in as few requests as its pages allow."""

from __future__ import annotations

import asyncio
import math
import sqlite3
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from sqlalchemy import func, select
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.db import default_database_url, open_database
from kybercore.jobs.store import JobStore
from kybercore.ledger import records, stats
from kybercore.ledger.service import LedgerService
from kybercore.ledger.tables import history_jobs, printer_states
from kybercore.registry.models import PrinterConfig
from kybercore.sim.stack import PrinterStack
from tests.helpers import travel_gcode, wait_for
from tests.ledger.live_ledger import configs, finished, moonraker, newest_job, running_ledger

pytestmark = pytest.mark.integration

SHORT = travel_gcode(moves=4, feedrate=6000)
"""Homing plus 2 s of moves."""
LONG = travel_gcode(moves=300, feedrate=1200)
"""12 minutes: long enough to cancel or to outlive a restart."""
PRINT_WITHIN = 120.0
"""A short print ends in ~5 s on an idle machine; a cancel in ~1 s."""
CAUGHT_UP_WITHIN = 10.0
"""The ledger hears a finished job within a second (notify_history_changed): 10x slack."""


@pytest.fixture
async def engine(tmp_path: Path) -> AsyncIterator[AsyncEngine]:
    """A fresh SQLite ledger database (the statistics run on PostgreSQL too, in
    test_store.py; printing twice as much here would prove nothing more)."""
    database = await open_database(default_database_url(tmp_path))
    yield database
    await database.dispose()


async def run_print(
    http: httpx.AsyncClient, ledger: LedgerService, stack: PrinterStack, name: str,
    *, cancel: bool = False,
) -> str:  # fmt: skip
    """Print ``name`` on the printer (cancelled once it runs when asked); Moonraker's job id."""
    client = ledger.fleet.sessions.get(stack.options.name).client
    assert client is not None
    before = await newest_job(http, stack)
    await client.print_start(name)

    async def started() -> bool:
        newest = await newest_job(http, stack)
        return newest is not None and (before is None or newest["job_id"] != before["job_id"])

    await wait_for(started, PRINT_WITHIN, f"{name} in Moonraker's history")
    job = await newest_job(http, stack)
    assert job is not None
    if cancel:
        await client.print_cancel()
    await wait_for(finished(http, stack, job["job_id"]), PRINT_WITHIN, f"{name} to end")
    return str(job["job_id"])


async def prints_on(http: httpx.AsyncClient, ledger: LedgerService, stack: PrinterStack) -> None:
    client = ledger.fleet.sessions.get(stack.options.name).client
    assert client is not None
    await client.upload("ledger-short.gcode", SHORT)
    await client.upload("ledger-long.gcode", LONG)
    await run_print(http, ledger, stack, "ledger-short.gcode")
    await run_print(http, ledger, stack, "ledger-long.gcode", cancel=True)
    await run_print(http, ledger, stack, "ledger-short.gcode")


async def test_per_printer_totals_equal_moonraker_history_totals(
    fleet_stacks: list[PrinterStack], tmp_path: Path, http: httpx.AsyncClient, engine: AsyncEngine
) -> None:
    async with running_ledger(configs(fleet_stacks), tmp_path, http, engine) as ledger:
        await asyncio.gather(*(prints_on(http, ledger, stack) for stack in fleet_stacks))

        async def totals_match() -> bool:
            await ledger.flush()
            rows = await stats.statistics(engine, "printer", 0.0, time.time() + 60)
            ours = {row["key"]: row for row in rows}
            for stack in fleet_stacks:
                theirs = (await moonraker(http, stack, "/server/history/totals"))["job_totals"]
                row = ours.get(stack.options.name)
                # Every print has ended, so a job still in progress here is one whose end
                # KyberCore has not heard yet. Moonraker shows a job finished a moment before
                # it adds it to its totals: both sides can then agree while both still lag.
                if row is None or row["jobs"].get("in_progress"):
                    return False
                # Moonraker counts a job in its totals when it finishes; one cut short by a
                # crash of Moonraker itself is "interrupted" and never counted.
                counted = {k: n for k, n in row["jobs"].items() if k not in COUNTED_NOT}
                if sum(counted.values()) != theirs["total_jobs"]:
                    return False
                assert row["print_hours"] * 3600 == pytest.approx(
                    theirs["total_print_time"], abs=0.5
                )
                assert row["filament_mm"] == pytest.approx(theirs["total_filament_used"], abs=0.01)
            return True

        await wait_for(totals_match, CAUGHT_UP_WITHIN, "KyberCore's totals equal Moonraker's")
        for stack in fleet_stacks:
            counts = {
                outcome: n
                for (printer, outcome), n in ledger.job_counts.items()
                if printer == stack.options.name
            }
            assert counts["completed"] >= 2
            assert counts["cancelled"] >= 1
        # The history lists Moonraker's jobs, once each, as Moonraker names them: a loaded
        # Moonraker may record a print's job before it knows the file (filename "").
        for stack in fleet_stacks:
            theirs = (await moonraker(http, stack, "/server/history/list", limit=500))["jobs"]
            total, items = await records.page(
                engine, records.HistoryFilter(printer=stack.options.name), 500, 0
            )
            ours = [(r["moonraker_job_id"], r["filename"], r["status"]) for r in items]
            assert total >= 3
            assert sorted(ours) == sorted((j["job_id"], j["filename"], j["status"]) for j in theirs)


COUNTED_NOT = frozenset({"in_progress", "interrupted"})


async def test_a_print_that_ends_while_kybercore_is_down_is_recorded_once(
    fleet_stacks: list[PrinterStack], tmp_path: Path, http: httpx.AsyncClient, engine: AsyncEngine
) -> None:
    stack = fleet_stacks[0]
    printer = configs([stack])
    quick = travel_gcode(moves=16, feedrate=6000)  # homing plus 8 s
    h = history_jobs.c

    async def status_of(job_id: str) -> list[str]:
        async with engine.connect() as conn:
            return list(
                (await conn.scalars(select(h.status).where(h.moonraker_job_id == job_id))).all()
            )

    async with running_ledger(printer, tmp_path, http, engine) as ledger:
        client = ledger.fleet.sessions.get(stack.options.name).client
        assert client is not None
        await client.upload("ledger-restart.gcode", quick)
        before = await newest_job(http, stack)
        await client.print_start("ledger-restart.gcode")

        async def heard() -> bool:
            newest = await newest_job(http, stack)
            if newest is None or (before is not None and newest["job_id"] == before["job_id"]):
                return False
            await ledger.flush()
            return await status_of(newest["job_id"]) == ["in_progress"]

        await wait_for(heard, CAUGHT_UP_WITHIN, "the running print in the ledger")
        job = await newest_job(http, stack)
        assert job is not None
    # KyberCore is stopped (fleet and ledger); the print goes on and ends.
    await wait_for(finished(http, stack, job["job_id"]), PRINT_WITHIN, "the print to end")
    async with running_ledger(printer, tmp_path, http, engine) as ledger:
        assert await status_of(job["job_id"]) == ["completed"]
        # The catch-up read one page: it stops at the job that was still running.
        assert ledger.backfill_requests == 1
    async with engine.connect() as conn:
        keys = select(h.printer, h.instance, h.moonraker_job_id).distinct().subquery()
        distinct = await conn.scalar(select(func.count()).select_from(keys))
        assert await conn.scalar(select(func.count()).select_from(history_jobs)) == distinct


def seed_history(stack: PrinterStack, count: int) -> None:
    """Give a stopped Moonraker ``count`` past jobs, written into its own database."""
    database = stack.data_dir / "database" / "moonraker-sql.db"
    start = time.time() - count * 600
    rows = [
        (n, "No User", f"old-{n}.gcode", "completed" if n % 5 else "cancelled",
         start + n * 600, start + n * 600 + 300, 280.0, 300.0, 10.0 * n, "{}", "[]", "default")
        for n in range(1, count + 1)
    ]  # fmt: skip
    with sqlite3.connect(database) as db:
        db.executemany(f"INSERT INTO job_history VALUES ({','.join('?' * 12)})", rows)


async def test_five_thousand_past_jobs_are_read_once_in_ceil_count_over_limit_requests(
    own_printer: PrinterStack, tmp_path: Path, http: httpx.AsyncClient, engine: AsyncEngine
) -> None:
    past, limit = 5000, 100
    await asyncio.to_thread(own_printer.stop_moonraker)
    await asyncio.to_thread(seed_history, own_printer, past)
    await asyncio.to_thread(own_printer.start_moonraker)
    await asyncio.to_thread(own_printer.wait_ready)
    printer = configs([own_printer])
    async with running_ledger(printer, tmp_path, http, engine, page=limit) as ledger:
        assert ledger.backfill_requests == math.ceil(past / limit)
        total, _ = await records.page(engine, records.HistoryFilter(), 10, 0)
        assert total == past
        counts: dict[str, Any] = dict(ledger.job_counts)
        assert counts == {
            (own_printer.options.name, "completed"): 4000,
            (own_printer.options.name, "cancelled"): 1000,
        }
        # Reading the ledger never asks the printer.
        await records.page(engine, records.HistoryFilter(status="cancelled"), 50, 900)
        await stats.statistics(engine, "day", time.time() - 40 * 86400, time.time())
        assert ledger.backfill_requests == math.ceil(past / limit)
        # A reconnect reads one page: the newest, down to the newest job known.
        await asyncio.to_thread(own_printer.stop_moonraker)
        await asyncio.to_thread(own_printer.start_moonraker)
        await wait_for(
            lambda: (
                ledger.backfill_requests == math.ceil(past / limit) + 1
                and ledger.caught_up(own_printer.options.name)
            ),
            60,
            "the catch-up after Moonraker's restart",
        )
        assert (await records.page(engine, records.HistoryFilter(), 10, 0))[0] == past
        assert ledger.reconnects == {own_printer.options.name: 1}


async def test_plate_gates_and_disabled_printers_reach_the_timeline_on_change_only(
    fleet_stacks: list[PrinterStack], tmp_path: Path, http: httpx.AsyncClient, engine: AsyncEngine
) -> None:
    stack = fleet_stacks[2]
    pid = stack.options.name
    off = PrinterConfig(id="ledger-off", name="Off", moonraker_url=stack.url, enabled=False)
    queue = JobStore(engine)
    async with running_ledger([*configs([stack]), off], tmp_path, http, engine) as ledger:
        await wait_for(
            lambda: ledger.timeline.current == {pid: "idle", "ledger-off": "disabled"},
            CAUGHT_UP_WITHIN,
            "the printers' first states",
        )
        await queue.set_maintenance(pid, "new nozzle", "ana")
        await wait_for(
            lambda: ledger.timeline.current.get(pid) == "maintenance",
            CAUGHT_UP_WITHIN,
            "maintenance from the queue's gate",
        )
        await queue.release(pid, "ana")
        await wait_for(
            lambda: ledger.timeline.current.get(pid) == "idle", CAUGHT_UP_WITHIN, "idle again"
        )
        await ledger.flush()
        # Temperatures keep arriving four times a second: nothing to write.
        assert await ledger.timeline.flush() == 0
    s = printer_states.c
    async with engine.connect() as conn:
        intervals = (
            await conn.execute(select(s.printer, s.state, s.ended_at).order_by(s.id))
        ).all()
    mine = [state for printer, state, _ in intervals if printer == pid]
    # Offline first when the ledger looked before the session was up.
    assert mine in (["idle", "maintenance", "idle"], ["offline", "idle", "maintenance", "idle"])
    assert [state for printer, state, _ in intervals if printer == "ledger-off"] == ["disabled"]
    assert all(ended is not None for *_, ended in intervals)  # closed when KyberCore stopped
