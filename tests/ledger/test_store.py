"""The ledger's tables on real SQLite and real PostgreSQL: idempotent history writes, the
link to the queue's attempts, the state timeline and the statistics drawn from them."""

from __future__ import annotations

import asyncio
from typing import Any

import pytest
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy import func, select
from sqlalchemy.engine import Connection
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.errors import DatabaseUnavailable
from kybercore.jobs.models import JobFile, NewJob
from kybercore.jobs.store import JobStore
from kybercore.ledger import records, stats
from kybercore.ledger import timeline as timeline_module
from kybercore.ledger.history import HistoryJob, HistoryStore, parse_job
from kybercore.ledger.tables import history_jobs, metadata, printer_states
from kybercore.ledger.timeline import Timeline

T0 = 1_767_225_600.0  # 2026-01-01T00:00:00Z
DAY = 86400.0


async def intervals(database: AsyncEngine) -> list[tuple[Any, ...]]:
    """Every state interval as (state, start, end), in seconds after T0, in written order."""
    s = printer_states.c
    query = select(s.state, s.started_at - T0, s.ended_at - T0).order_by(s.id)
    async with database.connect() as conn:
        return [tuple(row) for row in await conn.execute(query)]


def job(number: int, status: str = "completed", **fields: Any) -> HistoryJob:
    """A Moonraker history job numbered ``number``, started ``number`` hours after T0."""
    raw = {
        "job_id": f"{number:06X}",
        "filename": f"part-{number}.gcode",
        "status": status,
        "start_time": T0 + number * 3600,
        "end_time": None if status == "in_progress" else T0 + number * 3600 + 1800,
        "print_duration": 0.0 if status == "in_progress" else 1500.0,
        "total_duration": 1800.0,
        "filament_used": 0.0 if status == "in_progress" else 1000.0,
        "metadata": {"filament_type": "PLA", "filament_total": 2000.0,
                     "filament_weight_total": 6.0},
        **fields,
    }  # fmt: skip
    parsed = parse_job(raw)
    assert parsed is not None
    return parsed


async def rows(engine: AsyncEngine) -> list[tuple[str, str, str, str]]:
    h = history_jobs.c
    async with engine.connect() as conn:
        result = await conn.execute(
            select(h.printer, h.instance, h.moonraker_job_id, h.status).order_by(h.id)
        )
        return [tuple(r) for r in result]  # type: ignore[misc]


def _drift(conn: Connection) -> list[object]:
    # The ledger's tables only: the queue's and the audit's have tests of their own.
    def ledger_only(name: str | None, kind: str, _parent: object) -> bool:
        return kind != "table" or name in metadata.tables

    context = MigrationContext.configure(conn, opts={"include_name": ledger_only})
    return list(compare_metadata(context, metadata))


async def test_the_migrated_database_has_the_ledger_tables_the_code_uses(
    database: AsyncEngine,
) -> None:
    async with database.connect() as conn:
        assert await conn.run_sync(_drift) == []


async def test_a_job_fed_twice_or_late_is_one_row_that_never_goes_back(
    database: AsyncEngine,
) -> None:
    store = HistoryStore(database)
    await store.upsert([("a", "i1", job(1, "in_progress"))])
    await store.upsert([("a", "i1", job(1)), ("a", "i1", job(1))])
    # A late copy of the "added" event, alone and in a batch with the finished one.
    await store.upsert([("a", "i1", job(1, "in_progress"))])
    await store.upsert([("a", "i1", job(2)), ("a", "i1", job(2, "in_progress"))])
    # The same job number from another Moonraker database, and on another printer.
    await store.upsert([("a", "i2", job(1, "cancelled")), ("b", "i1", job(1, "error"))])
    assert await rows(database) == [
        ("a", "i1", "000001", "completed"),
        ("a", "i1", "000002", "completed"),
        ("a", "i2", "000001", "cancelled"),
        ("b", "i1", "000001", "error"),
    ]
    assert await store.counts() == {
        ("a", "completed"): 2, ("a", "cancelled"): 1, ("b", "error"): 1,
    }  # fmt: skip
    assert await store.counts(["b"]) == {("b", "error"): 1}


async def test_the_backfill_floor_is_the_oldest_open_job_else_the_newest(
    database: AsyncEngine,
) -> None:
    store = HistoryStore(database)
    assert await store.floor("a", "i1") == 0
    await store.upsert([("a", "i1", job(n)) for n in (1, 2, 0x10, 0xFF)])
    assert await store.floor("a", "i1") == 0xFF
    await store.upsert([("a", "i1", job(0x100, "in_progress")), ("a", "i1", job(0x101))])
    assert await store.floor("a", "i1") == 0x100
    # Past six hex digits the ids grow longer: still the newest, not the largest string.
    await store.upsert([("a", "i1", job(0x100)), ("a", "i1", job(0x1000000))])
    assert await store.floor("a", "i1") == 0x1000000


async def test_a_queued_print_links_to_its_attempt_job_and_verdict(
    database: AsyncEngine,
) -> None:
    queue = JobStore(database)
    new = NewJob(JobFile("ab" * 32, "bracket.gcode", 100, {"filament_type": "PETG"}))
    queued = await queue.create_job(new, "ana")
    attempt = await queue.reserve(queued.id, "a")
    assert attempt is not None
    store = HistoryStore(database)
    printed = job(5, "in_progress", filename=attempt.upload_name)
    anonymous = [job(n, user=name) for n, name in ((7, "_TRUSTED_USER_"), (8, "_API_KEY_USER_"))]
    await store.upsert([("a", "i1", j) for j in (printed, job(6, user="bob"), *anonymous)])
    await queue.advance(attempt.id, "printing", moonraker_job_id="000005")
    await queue.finish(attempt.id, "completed", print_seconds=1500.0)
    await store.upsert([("a", "i1", job(5, filename=attempt.upload_name))])
    await queue.clear("a", "bad", cause="warped", user="carla")

    total, items = await records.page(database, records.HistoryFilter(printer="a"), 10, 0)
    assert total == 4
    # Moonraker's names for "no person" (a trusted address, its API key) name nobody.
    assert [item["user"] for item in items[:2]] == [None, None]
    linked, plain = items[3], items[2]
    assert (linked["attempt_id"], linked["job_id"], linked["sha256"]) == (
        attempt.id, queued.id, "ab" * 32,
    )  # fmt: skip
    assert (linked["verdict"], linked["cause"], linked["user"]) == ("bad", "warped", "ana")
    assert linked["queued_at"] <= linked["cleared_at"]  # both ISO-8601 UTC, comparable
    assert linked["started_at"] == "2026-01-01T05:00:00Z"
    assert linked["filament_g"] == pytest.approx(3.0)
    assert (plain["attempt_id"], plain["sha256"], plain["user"]) == (None, None, "bob")

    by_user = records.HistoryFilter(user="ana")
    assert (await records.page(database, by_user, 10, 0))[0] == 1
    by_file = records.HistoryFilter(file="BRACKET")
    assert (await records.page(database, by_file, 10, 0))[0] == 1
    wildcard = records.HistoryFilter(file="%")
    assert (await records.page(database, wildcard, 10, 0))[0] == 0
    window = records.HistoryFilter(start=T0 + 5.5 * 3600, end=T0 + 7 * 3600)
    assert (await records.page(database, window, 10, 0))[0] == 1

    by_file_stats = await stats.statistics(database, "file", T0, T0 + DAY)
    bracket = next(r for r in by_file_stats if r["key"] == "bracket.gcode")
    assert bracket["jobs"] == {"completed": 1}
    assert bracket["success_rate"] == 0.0  # completed, but the plate was cleared bad
    assert bracket["failure_causes"] == {"warped": 1}


async def test_every_row_reads_past_its_batches_in_order(database: AsyncEngine) -> None:
    store = HistoryStore(database)
    count = records.CSV_BATCH * 2 + 3
    # Pairs of jobs with the same start time: the keyset must not skip either.
    await store.upsert(
        [("a", "i1", job(n, start_time=T0 + (n // 2) * 60)) for n in range(1, count + 1)]
    )
    every = records.every_row(database, records.HistoryFilter())
    seen = [row["moonraker_job_id"] async for row in every]
    assert len(seen) == len(set(seen)) == count
    text = records.csv_text([], header=True)
    assert text.startswith("printer,moonraker_job_id,filename,sha256,")


async def test_intervals_open_on_change_close_on_the_next_and_recover_after_a_crash(
    database: AsyncEngine,
) -> None:
    timeline = Timeline(database)
    timeline.observe("a", "idle", T0)
    timeline.observe("a", "idle", T0 + 10)  # no change: nothing to write
    timeline.observe("a", "printing", T0 + 100)
    timeline.observe("b", "maintenance", T0)
    assert await timeline.flush() == 3
    timeline.observe("a", "idle", T0 + 400)
    timeline.forget(["b"], T0 + 500)
    assert await timeline.flush() == 2
    assert await timeline.flush() == 0
    timeline.observe("a", "printing", T0 + 600)
    await timeline.flush()

    s = printer_states.c
    async with database.connect() as conn:
        intervals = (
            await conn.execute(
                select(s.printer, s.state, s.started_at - T0, s.ended_at - T0).order_by(s.id)
            )
        ).all()
    assert [tuple(i) for i in intervals] == [
        ("a", "idle", 0, 100), ("a", "printing", 100, 400), ("b", "maintenance", 0, 500),
        ("a", "idle", 400, 600), ("a", "printing", 600, None),
    ]  # fmt: skip
    # Another run starts after this one died: the open interval ends at its last change.
    await Timeline(database).recover()
    async with database.connect() as conn:
        assert await conn.scalar(select(func.count()).where(s.ended_at.is_(None))) == 0
        assert await conn.scalar(select(s.ended_at - T0).where(s.started_at == T0 + 600)) == 600


async def test_a_new_owner_ends_the_old_ones_interval_but_not_the_reverse(
    database: AsyncEngine,
) -> None:
    # Two ingest workers on NATS: `old` held the printer, was paused past its lease, and
    # `new` took it over; `old` wakes up and lets go of it afterwards.
    old, new = Timeline(database), Timeline(database)
    old.observe("p", "idle", T0)
    await old.flush()
    new.observe("p", "idle", T0 + 10)
    await new.flush()
    old.forget(["p"], T0 + 20)
    await old.flush()
    new.observe("p", "printing", T0 + 30)
    await new.flush()
    assert await intervals(database) == [
        ("idle", 0, 10), ("idle", 10, 30), ("printing", 30, None)
    ]  # fmt: skip


async def test_changes_a_stopped_owner_could_not_write_leave_its_successors_alone(
    database: AsyncEngine,
) -> None:
    # `old` stopped while the database was away, keeping its changes; `new` took the
    # printer over meanwhile. `old`'s next start writes them late: they fill in its own
    # past, and neither end nor overlap what `new` wrote since.
    old, new = Timeline(database), Timeline(database)
    old.observe("p", "idle", T0)
    await old.flush()
    old.observe("p", "printing", T0 + 10)
    old.forget(["p"], T0 + 20)
    kept = old.unwritten()
    new.observe("p", "idle", T0 + 30)
    await new.flush()
    later = Timeline(database)
    later.take_back(*kept)
    assert await later.flush() == 2
    # `new` ended old's open interval on taking over, at 30 as it knew no better; the late
    # change ends it where it really ended. From 20 to 30 nobody watched the printer.
    assert await intervals(database) == [
        ("idle", 0, 10), ("idle", 30, None), ("printing", 10, 20)
    ]  # fmt: skip


async def test_changes_taken_back_that_were_written_already_are_not_written_twice(
    database: AsyncEngine,
) -> None:
    # A run kept its changes during an outage, wrote them once the database answered, and
    # was killed before it removed its file: the next start finds them in both.
    old = Timeline(database)
    old.observe("p", "idle", T0)
    await old.flush()
    old.observe("p", "printing", T0 + 10)
    kept = old.unwritten()
    await old.flush()
    later = Timeline(database)
    later.take_back(*kept)
    assert await later.flush() == 0
    old.observe("p", "paused", T0 + 20)
    old.forget(["p"], T0 + 30)
    changes, opened = old.unwritten()
    again = Timeline(database)
    again.take_back(kept[0] + changes, opened)  # written and not: only the latter
    assert await again.flush() == 2  # the pause and the leaving
    assert await intervals(database) == [
        ("idle", 0, 10), ("printing", 10, 20), ("paused", 20, 30)
    ]  # fmt: skip


async def test_a_write_whose_reply_was_lost_is_not_written_again(
    database: AsyncEngine, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The line cut mid-commit: the rows are in, yet the write failed. No real server loses
    # a reply on demand, so the fault is injected right after a real commit.
    real, reply = timeline_module.transaction, {"lost": False}

    async def reply_lost(engine: AsyncEngine, work: Any, *, write: bool = True) -> Any:
        done = await real(engine, work, write=write)
        if write and reply["lost"]:
            reply["lost"] = False
            raise DatabaseUnavailable("connection lost while committing")
        return done

    monkeypatch.setattr(timeline_module, "transaction", reply_lost)
    timeline = Timeline(database)
    timeline.observe("p", "idle", T0)
    await timeline.flush()
    timeline.observe("p", "printing", T0 + 10)
    reply["lost"] = True
    with pytest.raises(DatabaseUnavailable):
        await timeline.flush()
    assert timeline.pending == 1  # for all it knows, not written
    timeline.observe("p", "paused", T0 + 20)
    assert await timeline.flush() == 1  # the pause only: the print start is there
    timeline.forget(["p"], T0 + 30)  # ends the pause, which this timeline knows it opened
    await timeline.flush()
    assert await intervals(database) == [
        ("idle", 0, 10), ("printing", 10, 20), ("paused", 20, 30)
    ]  # fmt: skip


async def test_a_flush_cancelled_mid_write_neither_doubles_nor_loses_an_interval(
    database: AsyncEngine,
) -> None:
    # KyberCore stopping cancels the timeline's writer wherever it is, the commit in the
    # driver's thread included: try every point, as many loop turns in as it takes.
    s = printer_states.c
    turns = 0
    while True:
        timeline = Timeline(database)
        printer = f"p{turns}"
        timeline.observe(printer, "idle", T0)
        writer = asyncio.ensure_future(timeline.flush())
        for _ in range(turns):
            await asyncio.sleep(0)
        finished = writer.done()
        writer.cancel()
        await asyncio.wait({writer})
        await timeline.flush()  # what stopping writes next
        async with database.connect() as conn:
            rows = await conn.scalar(select(func.count()).where(s.printer == printer))
        assert rows == 1, f"cancelled after {turns} loop turns: {rows} intervals"
        if finished:
            break
        turns += 1


async def test_statistics_per_printer_and_day(database: AsyncEngine) -> None:
    store = HistoryStore(database)
    await store.upsert(
        [("a", "i1", job(1)), ("a", "i1", job(2, "cancelled")), ("a", "i1", job(30, "error")),
         ("b", "i1", job(3, filament_used=500.0, metadata={"filament_type": "PETG"}))]
    )  # fmt: skip
    timeline = Timeline(database)
    # a: printing 2 h of 10 h observed, 2 h of them in maintenance.
    for at, state in ((0, "idle"), (1, "printing"), (3, "maintenance"), (5, "idle")):
        timeline.observe("a", state, T0 + at * 3600)  # type: ignore[arg-type]
    # b: disabled all along: offline by plan, no time to divide by.
    timeline.observe("b", "disabled", T0)
    await timeline.flush()
    now = T0 + 10 * 3600

    by_printer = await stats.statistics(database, "printer", T0, T0 + DAY, now=now)
    a, b = by_printer
    assert a["key"] == "a"
    assert a["jobs"] == {"completed": 1, "cancelled": 1}  # job 30 starts the next day
    assert a["success_rate"] == 0.5
    assert a["print_hours"] == pytest.approx(3000 / 3600, abs=1e-3)
    assert a["utilisation"] == pytest.approx(2 / 8)
    assert a["filament_mm"] == 2000
    assert a["filament_g"] == pytest.approx(6.0)
    assert b["key"] == "b"
    assert b["utilisation"] is None
    assert b["filament_g"] is None  # b's file does not say what its filament weighs

    by_day = await stats.statistics(database, "day", T0, T0 + 2 * DAY, now=T0 + 2 * DAY)
    assert [r["key"] for r in by_day] == ["2026-01-01", "2026-01-02"]
    first, second = by_day
    assert first["jobs"] == {"completed": 2, "cancelled": 1}
    assert second["jobs"] == {"error": 1}
    assert first["utilisation"] == pytest.approx(2 / 22, abs=1e-4)  # a: 24 h less 2 h maintenance
    assert second["utilisation"] == 0.0

    by_material = await stats.statistics(database, "material", T0, T0 + 2 * DAY)
    assert {r["key"]: sum(r["jobs"].values()) for r in by_material} == {"PLA": 3, "PETG": 1}
    assert all(r["utilisation"] is None for r in by_material)


def test_a_window_must_run_forward_and_a_daily_one_must_be_bounded() -> None:
    from datetime import UTC, datetime

    late, early = datetime(2026, 2, 1, tzinfo=UTC), datetime(2026, 1, 1)
    assert stats.window(early, late) == (T0, T0 + 31 * DAY)  # naive is UTC
    with pytest.raises(Exception, match="before"):
        stats.window(late, early)
    with pytest.raises(Exception, match="at most"):
        stats._days(0, 2000 * DAY)
