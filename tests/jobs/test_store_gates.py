"""The job store, printer gates: a plate a print ended on stays uncleared, through
restarts, until an operator's verdict; holds, maintenance, release. SQLite and PostgreSQL."""

from __future__ import annotations

import pytest
from sqlalchemy import insert
from sqlalchemy.exc import IntegrityError
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.db import open_database
from kybercore.errors import ActionRejected, InvalidInput
from kybercore.jobs import tables
from kybercore.jobs.models import Attempt
from kybercore.jobs.store import JobStore
from tests.jobs.conftest import assert_consistent, new_job


async def completed_on(store: JobStore, job_id: int, printer: str) -> Attempt:
    attempt = await store.reserve(job_id, printer)
    assert attempt is not None
    await store.advance(attempt.id, "printing")
    return await store.finish(attempt.id, "completed", print_seconds=60.0)


async def test_a_printer_never_seen_is_available(store: JobStore) -> None:
    assert await store.gates() == {}
    gate = await store.gate("p1")
    assert (gate.state, gate.attempt_id, gate.reason) == ("available", None, "")
    assert await store.gates() == {"p1": gate}


async def test_a_completed_print_leaves_the_printer_awaiting_a_clear(store: JobStore) -> None:
    job = await store.create_job(new_job(2), "ana")
    attempt = await completed_on(store, job.id, "p1")
    gate = await store.gate("p1")
    assert (gate.state, gate.attempt_id) == ("awaiting_clear", attempt.id)
    job = await store.job(job.id)
    assert (job.in_flight, job.awaiting_clear) == (1, 1)  # the copy waits for its verdict
    assert await store.reserve(job.id, "p1") is None
    await assert_consistent(store)


async def test_clear_good_counts_the_copy_and_the_last_one_finishes_the_job(
    store: JobStore,
) -> None:
    job = await store.create_job(new_job(2), "ana")
    for printer in ("p1", "p2"):
        await completed_on(store, job.id, printer)
    gate = await store.clear("p1", "good", user="ana")
    assert (gate.state, gate.attempt_id, gate.user) == ("available", None, "ana")
    job = await store.job(job.id)
    assert (job.done, job.in_flight, job.awaiting_clear, job.state) == (1, 1, 1, "queued")
    await store.clear("p2", "good", user="ana")
    job = await store.job(job.id)
    assert (job.done, job.in_flight, job.awaiting_clear, job.left) == (2, 0, 0, 0)
    assert job.state == "done"
    assert await store.reserve(job.id, "p1") is None
    assert await store.jobs() == []
    await assert_consistent(store)


async def test_clear_bad_sends_the_copy_back_to_the_queue(store: JobStore) -> None:
    job = await store.create_job(new_job(2), "ana")
    first = await completed_on(store, job.id, "p1")
    await store.clear("p1", "bad", cause="spaghetti", user="ana")
    cleared = await store.attempt(first.id)
    assert (cleared.verdict, cleared.cause) == ("bad", "spaghetti")
    job = await store.job(job.id)
    assert (job.done, job.in_flight, job.left, job.failures) == (0, 0, 2, 0)
    again = await store.reserve(job.id, "p1")
    assert again is not None
    assert again.copy == first.copy
    assert again.upload_name != first.upload_name
    await assert_consistent(store)


async def test_clearing_after_a_failure_records_the_verdict_and_counts_nothing(
    store: JobStore,
) -> None:
    job = await store.create_job(new_job(1), "ana")
    attempt = await store.reserve(job.id, "p1")
    assert attempt is not None
    await store.finish(attempt.id, "failed", reason="layer shift")
    before = await store.job(job.id)
    await store.clear("p1", "good", user="ana")
    assert (await store.attempt(attempt.id)).verdict == "good"
    assert await store.job(job.id) == before


async def test_there_must_be_a_plate_to_clear(store: JobStore) -> None:
    job = await store.create_job(new_job(1), "ana")
    with pytest.raises(ActionRejected, match="p1 has no plate to clear: it is available"):
        await store.clear("p1", "good", user="ana")
    attempt = await store.reserve(job.id, "p1")
    assert attempt is not None
    with pytest.raises(ActionRejected) as printing:
        await store.clear("p1", "good", user="ana")
    assert printing.value.code == "nothing_to_clear"
    await store.finish(attempt.id, "completed")
    with pytest.raises(InvalidInput):
        await store.clear("p1", "fine", user="ana")  # type: ignore[arg-type]
    await store.clear("p1", "good", user="ana")
    with pytest.raises(ActionRejected):
        await store.clear("p1", "good", user="ana")  # twice: the second finds nothing
    assert (await store.job(job.id)).done == 1


async def test_restarting_never_releases_a_printer_awaiting_its_clear(
    database_url: str,
) -> None:
    engine = await open_database(database_url)
    store = JobStore(engine)
    job = await store.create_job(new_job(2), "ana")
    attempt = await completed_on(store, job.id, "p1")
    await engine.dispose()  # KyberCore stops

    engine = await open_database(database_url)
    try:
        store = JobStore(engine)
        gate = await store.gate("p1")
        assert (gate.state, gate.attempt_id) == ("awaiting_clear", attempt.id)
        assert await store.reserve(job.id, "p1") is None
        assert (await store.job(job.id)).in_flight == 1
        await store.clear("p1", "good", user="ana")
        assert (await store.job(job.id)).done == 1
    finally:
        await engine.dispose()


async def test_a_held_printer_gets_nothing_until_released(store: JobStore) -> None:
    job = await store.create_job(new_job(1), "ana")
    held = await store.hold("p1", "bed re-levelling", "ana")
    assert (held.state, held.reason, held.user) == ("held", "bed re-levelling", "ana")
    assert await store.reserve(job.id, "p1") is None
    maintenance = await store.set_maintenance("p1", "new hotend", "bob")
    assert (maintenance.state, maintenance.reason) == ("maintenance", "new hotend")
    assert await store.reserve(job.id, "p1") is None
    released = await store.release("p1", "bob")
    assert (released.state, released.reason) == ("available", "")
    assert released.since >= maintenance.since
    assert await store.reserve(job.id, "p1") is not None


async def test_only_a_held_printer_can_be_released(store: JobStore) -> None:
    with pytest.raises(ActionRejected, match="p1 is not held: it is available") as refused:
        await store.release("p1", "ana")
    assert refused.value.code == "not_held"
    job = await store.create_job(new_job(1), "ana")
    await completed_on(store, job.id, "p1")
    with pytest.raises(ActionRejected, match="Clear its plate with a verdict"):
        await store.release("p1", "ana")


async def test_a_printer_held_while_printing_keeps_its_plate_to_clear(store: JobStore) -> None:
    """Drain: hold a printer mid-print. The print ends; the printer stays held and its
    plate stays uncleared, whatever is done first: release or clear."""
    job = await store.create_job(new_job(3), "ana")
    for printer in ("p1", "p2"):
        attempt = await store.reserve(job.id, printer)
        assert attempt is not None
        await store.hold(printer, "drain", "ana")
        await store.finish(attempt.id, "completed")
        gate = await store.gate(printer)
        assert (gate.state, gate.reason, gate.attempt_id) == ("held", "drain", attempt.id)
    # p1: released first, so it awaits its clear; cleared, it is available.
    assert (await store.release("p1", "ana")).state == "awaiting_clear"
    assert await store.reserve(job.id, "p1") is None
    assert (await store.clear("p1", "good", user="ana")).state == "available"
    # p2: cleared first, it stays held; released, it is available.
    cleared = await store.clear("p2", "bad", user="ana")
    assert (cleared.state, cleared.attempt_id) == ("held", None)
    assert (await store.release("p2", "ana")).state == "available"
    job = await store.job(job.id)
    assert (job.done, job.in_flight) == (1, 0)
    await assert_consistent(store)


async def test_the_database_itself_refuses_two_live_attempts_on_a_printer_or_a_copy(
    store: JobStore, database: AsyncEngine
) -> None:
    """Under the store's checks, the partial unique indexes: the last line against a bug."""
    job = await store.create_job(new_job(5), "ana")
    attempt = await store.reserve(job.id, "p1")
    assert attempt is not None
    row = {
        "job_id": job.id, "state": "printing", "reason": "", "cause": "", "by_user": "x",
        "created_at": attempt.created_at, "print_seconds": 0.0,
    }  # fmt: skip
    for clash in (
        {"copy": 2, "printer": "p1", "upload_name": "same-printer"},
        {"copy": attempt.copy, "printer": "p2", "upload_name": "same-copy"},
    ):
        with pytest.raises(IntegrityError):
            async with database.begin() as conn:
                await conn.execute(insert(tables.attempts).values(**row, **clash))
    # An ended attempt holds neither its printer nor (failed) its copy.
    async with database.begin() as conn:
        await conn.execute(
            insert(tables.attempts).values(
                **{**row, "state": "failed"}, copy=attempt.copy, printer="p1", upload_name="old"
            )
        )
