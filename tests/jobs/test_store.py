"""The job store, jobs and attempts: every transition and every refusal, on SQLite and on
PostgreSQL (the ``database_url`` fixture runs each test on both)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Any

import pytest
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.errors import ActionRejected, FileNotFound, InvalidInput
from kybercore.jobs.models import Attempt, Requirements
from kybercore.jobs.store import JobStore
from tests.jobs.conftest import assert_consistent, new_job


async def reserved(store: JobStore, job_id: int, printer: str) -> Attempt:
    attempt = await store.reserve(job_id, printer)
    assert attempt is not None, f"nothing reserved on {printer}"
    return attempt


async def test_a_new_job_is_queued_and_stored_as_given(store: JobStore) -> None:
    wanted = Requirements(material="PLA", nozzle=0.4, model="voron", tags=("a", "b"))
    job = await store.create_job(
        new_job(3, priority=2, requirements=wanted, allow_mismatch=True, max_attempts=5), "ana"
    )
    assert (job.state, job.done, job.in_flight, job.failures, job.left) == ("queued", 0, 0, 0, 3)
    assert (job.priority, job.requirements, job.allow_mismatch) == (2, wanted, True)
    assert (job.max_attempts, job.created_by, job.file.name) == (5, "ana", "cube.gcode")
    assert job.created_at.tzinfo is not None
    assert await store.job(job.id) == job


@pytest.mark.parametrize(("quantity", "max_attempts"), [(0, 3), (1, 0)])
async def test_a_job_without_copies_or_attempts_is_refused(
    store: JobStore, quantity: int, max_attempts: int
) -> None:
    with pytest.raises(InvalidInput):
        await store.create_job(new_job(quantity, max_attempts=max_attempts), "ana")
    assert await store.jobs(include_finished=True) == []


async def test_an_unknown_job_or_attempt_is_not_found(store: JobStore) -> None:
    with pytest.raises(FileNotFound, match="No job with id 42"):
        await store.job(42)
    with pytest.raises(FileNotFound):
        await store.reserve(42, "p1")
    with pytest.raises(FileNotFound):
        await store.cancel_job(42, "ana")
    with pytest.raises(FileNotFound):
        await store.finish(42, "failed")


async def test_jobs_come_in_priority_then_position_order(store: JobStore) -> None:
    low = await store.create_job(new_job(priority=0), "ana")
    high = await store.create_job(new_job(priority=5), "ana")
    low2 = await store.create_job(new_job(priority=0), "ana")
    assert [j.id for j in await store.jobs()] == [high.id, low.id, low2.id]


async def test_move_puts_a_job_before_another_taking_its_priority_or_last(
    store: JobStore,
) -> None:
    a, b, c = [await store.create_job(new_job(), "ana") for _ in range(3)]
    urgent = await store.create_job(new_job(priority=9), "ana")
    await store.move_job(c.id, a.id, "ana")
    assert [j.id for j in await store.jobs()] == [urgent.id, c.id, a.id, b.id]
    await store.move_job(c.id, None, "ana")
    assert [j.id for j in await store.jobs()] == [urgent.id, a.id, b.id, c.id]
    moved = await store.move_job(b.id, urgent.id, "ana")
    assert moved.priority == 9
    assert [j.id for j in await store.jobs()] == [b.id, urgent.id, a.id, c.id]


async def test_moving_into_the_same_gap_again_and_again_keeps_the_order(store: JobStore) -> None:
    """Halving the gap between two positions runs out of floats after ~50 moves; the
    store renumbers the queue then, and the order stays what the moves asked for."""
    first = await store.create_job(new_job(), "ana")
    second = await store.create_job(new_job(), "ana")
    expected = [first.id, second.id]
    for _ in range(70):  # each new job goes just before `second`, after the last one moved
        job = await store.create_job(new_job(), "ana")
        await store.move_job(job.id, second.id, "ana")
        expected.insert(len(expected) - 1, job.id)
    assert [j.id for j in await store.jobs()] == expected


async def test_reserve_takes_the_lowest_free_copy_and_points_the_gate_at_it(
    store: JobStore,
) -> None:
    job = await store.create_job(new_job(2, name="Benchy v2 (final).gcode"), "ana")
    first = await reserved(store, job.id, "p1")
    second = await reserved(store, job.id, "p2")
    assert (first.copy, second.copy, first.state, first.user) == (1, 2, "pending", "dispatcher")
    assert first.upload_name == f"kybercore/j{job.id}-c1-a{first.id}-Benchy_v2_final_.gcode"
    assert (await store.gate("p1")).attempt_id == first.id
    assert (await store.job(job.id)).in_flight == 2
    assert await store.reserve(job.id, "p3") is None  # no copy left
    await assert_consistent(store)


async def test_a_printer_with_an_attempt_gets_no_second_one(store: JobStore) -> None:
    one = await store.create_job(new_job(), "ana")
    other = await store.create_job(new_job(), "ana")
    await reserved(store, one.id, "p1")
    assert await store.reserve(other.id, "p1") is None
    assert (await store.job(other.id)).in_flight == 0


async def test_reserve_gives_nothing_while_paused_or_before_the_job_may_start(
    store: JobStore,
) -> None:
    now = datetime.now(UTC)
    later = await store.create_job(new_job(not_before=now + timedelta(hours=1)), "ana")
    assert await store.reserve(later.id, "p1") is None
    now_job = await store.create_job(new_job(), "ana")
    await store.set_queue_paused(True, "ana")
    assert await store.queue_paused()
    assert await store.reserve(now_job.id, "p1") is None
    await store.set_queue_paused(False, "ana")
    assert not await store.queue_paused()
    assert await store.reserve(now_job.id, "p1") is not None
    changed = await store.update_job(later.id, not_before=now - timedelta(seconds=1), user="ana")
    assert changed.not_before is not None
    assert await store.reserve(later.id, "p2") is not None


async def test_an_attempt_moves_forward_and_never_back(store: JobStore) -> None:
    job = await store.create_job(new_job(), "ana")
    attempt = await reserved(store, job.id, "p1")
    for state in ("uploading", "starting"):
        assert (await store.advance(attempt.id, state)).state == state
    with pytest.raises(ActionRejected) as back:
        await store.advance(attempt.id, "uploading")
    assert back.value.code == "bad_transition"
    printing = await store.advance(attempt.id, "printing", moonraker_job_id="00001A")
    assert printing.started_at is not None
    assert printing.moonraker_job_id == "00001A"
    assert (await store.advance(attempt.id, "paused", reason="filament")).state == "paused"
    resumed = await store.advance(attempt.id, "printing", print_seconds=12.5)
    assert (resumed.state, resumed.started_at, resumed.print_seconds) == (
        "printing", printing.started_at, 12.5,
    )  # fmt: skip
    with pytest.raises(InvalidInput):
        await store.advance(attempt.id, "completed")
    await store.finish(attempt.id, "completed")
    with pytest.raises(ActionRejected) as ended:
        await store.advance(attempt.id, "printing")
    assert ended.value.code == "attempt_ended"


async def test_a_step_may_be_skipped(store: JobStore) -> None:
    """A restart may first see an attempt printing that it left pending."""
    job = await store.create_job(new_job(), "ana")
    attempt = await reserved(store, job.id, "p1")
    assert (await store.advance(attempt.id, "printing")).state == "printing"


async def test_finishing_twice_the_same_way_is_a_no_op_and_another_way_is_refused(
    store: JobStore,
) -> None:
    job = await store.create_job(new_job(), "ana")
    attempt = await reserved(store, job.id, "p1")
    first = await store.finish(attempt.id, "failed", reason="thermal runaway")
    assert await store.finish(attempt.id, "failed", reason="told again") == first
    with pytest.raises(ActionRejected, match="already ended failed"):
        await store.finish(attempt.id, "completed")
    with pytest.raises(InvalidInput):
        await store.finish(attempt.id, "printing")
    assert (await store.job(job.id)).failures == 1


async def test_a_failure_gives_the_copy_back_at_once_and_counts(store: JobStore) -> None:
    job = await store.create_job(new_job(1), "ana")
    attempt = await reserved(store, job.id, "p1")
    await store.finish(attempt.id, "failed", reason="nozzle clog", print_seconds=30.0)
    job = await store.job(job.id)
    assert (job.in_flight, job.failures, job.left, job.state) == (0, 1, 1, "queued")
    gate = await store.gate("p1")
    assert (gate.state, gate.attempt_id, gate.reason) == (
        "awaiting_clear", attempt.id, "failed: nozzle clog",
    )  # fmt: skip
    again = await reserved(store, job.id, "p2")
    assert again.copy == 1
    await assert_consistent(store)


async def test_a_cancelled_attempt_gives_the_copy_back_without_a_failure(
    store: JobStore,
) -> None:
    job = await store.create_job(new_job(1), "ana")
    attempt = await reserved(store, job.id, "p1")
    await store.finish(attempt.id, "cancelled", reason="cancelled on the printer")
    job = await store.job(job.id)
    assert (job.in_flight, job.failures) == (0, 0)
    assert (await store.gate("p1")).state == "awaiting_clear"


async def test_a_start_that_never_happens_holds_the_printer_and_retries_the_copy(
    store: JobStore,
) -> None:
    job = await store.create_job(new_job(1), "ana")
    attempt = await reserved(store, job.id, "p1")
    reason = "print_started: false"
    ended = await store.finish(attempt.id, "failed_to_start", reason=reason)
    assert (ended.state, ended.reason, ended.ended_at is not None) == (
        "failed_to_start", reason, True,
    )  # fmt: skip
    gate = await store.gate("p1")
    assert (gate.state, gate.reason, gate.attempt_id) == (
        "held", f"failed to start: {reason}", None,
    )  # fmt: skip
    job = await store.job(job.id)
    assert (job.in_flight, job.failures, job.state) == (0, 1, "queued")
    assert await store.reserve(job.id, "p1") is None
    assert (await reserved(store, job.id, "p2")).copy == 1
    await assert_consistent(store)


async def test_max_attempts_failures_block_the_job_with_the_last_reason(
    store: JobStore,
) -> None:
    job = await store.create_job(new_job(2, max_attempts=2), "ana")
    one = await reserved(store, job.id, "p1")
    two = await reserved(store, job.id, "p2")
    await store.finish(one.id, "failed_to_start", reason="never reached printing")
    assert (await store.job(job.id)).state == "queued"
    await store.finish(two.id, "failed", reason="klippy shutdown")
    job = await store.job(job.id)
    assert (job.state, job.reason, job.failures) == ("blocked", "p2: failed: klippy shutdown", 2)
    assert await store.reserve(job.id, "p3") is None
    requeued = await store.requeue_job(job.id, "ana")
    assert (requeued.state, requeued.failures, requeued.reason) == ("queued", 0, "")
    with pytest.raises(ActionRejected) as not_blocked:
        await store.requeue_job(job.id, "ana")
    assert not_blocked.value.code == "job_not_blocked"
    assert await store.reserve(job.id, "p3") is not None


async def test_more_attempts_allowed_unblock_a_job_and_fewer_block_it(store: JobStore) -> None:
    job = await store.create_job(new_job(1, max_attempts=3), "ana")
    attempt = await reserved(store, job.id, "p1")
    await store.finish(attempt.id, "failed", reason="clog")
    blocked = await store.update_job(job.id, max_attempts=1, user="ana")
    assert (blocked.state, blocked.reason) == ("blocked", "failed attempts: 1 of 1 allowed")
    assert (await store.update_job(job.id, max_attempts=2, user="ana")).state == "queued"


async def test_quantity_changes_keep_copies_in_use_and_settle_the_state(store: JobStore) -> None:
    job = await store.create_job(new_job(3), "ana")
    attempt = await reserved(store, job.id, "p1")
    await store.finish(attempt.id, "completed")
    await store.clear("p1", "good", user="ana")
    await reserved(store, job.id, "p1")
    with pytest.raises(ActionRejected, match="cannot go below 2") as refused:
        await store.update_job(job.id, quantity=1, user="ana")
    assert refused.value.code == "quantity_in_use"
    with pytest.raises(InvalidInput):
        await store.update_job(job.id, quantity=0, user="ana")
    assert (await store.update_job(job.id, quantity=2, priority=4, user="ana")).priority == 4
    unchanged = await store.update_job(job.id, quantity=2, user="ana")
    assert unchanged == await store.job(job.id)


async def test_cancel_returns_the_live_attempts_and_stops_new_copies(store: JobStore) -> None:
    job = await store.create_job(new_job(3), "ana")
    live = await reserved(store, job.id, "p1")
    awaiting = await reserved(store, job.id, "p2")
    await store.finish(awaiting.id, "completed")
    cancelled, attempts = await store.cancel_job(job.id, "ana", reason="wrong colour")
    assert (cancelled.state, cancelled.reason) == ("cancelled", "wrong colour")
    assert [a.id for a in attempts] == [live.id]
    assert await store.reserve(job.id, "p3") is None
    assert (await store.cancel_job(job.id, "bob"))[0] == cancelled
    assert [j.id for j in await store.jobs()] == []
    await store.finish(live.id, "cancelled")
    await store.clear("p2", "good", user="ana")  # the part was printed: it counts
    job = await store.job(job.id)
    assert (job.state, job.in_flight, job.done) == ("cancelled", 0, 1)
    with pytest.raises(ActionRejected):
        await store.update_job(job.id, priority=3, user="ana")
    await assert_consistent(store)


async def test_a_done_job_cannot_be_cancelled(store: JobStore) -> None:
    job = await store.create_job(new_job(1), "ana")
    attempt = await reserved(store, job.id, "p1")
    await store.finish(attempt.id, "completed")
    await store.clear("p1", "good", user="ana")
    with pytest.raises(ActionRejected) as refused:
        await store.cancel_job(job.id, "ana")
    assert refused.value.code == "job_done"


async def test_every_change_is_in_the_history_and_told_after_commit(database: AsyncEngine) -> None:
    told: list[tuple[str, dict[str, Any]]] = []
    store = JobStore(database, on_change=lambda kind, payload: told.append((kind, payload)))
    job = await store.create_job(new_job(), "ana")
    created = [(kind, p["event"], p["job"].id) for kind, p in told]
    assert created == [("job", "job_created", job.id)]
    told.clear()
    attempt = await reserved(store, job.id, "p1")
    assert sorted(kind for kind, _ in told) == ["attempt", "gate", "job"]
    assert {p["event"] for _, p in told} == {"attempt_reserved"}
    told.clear()
    await store.set_queue_paused(True, "bob")
    assert told == [
        ("queue", {"event": "queue_paused", "message": "Queue paused", "user": "bob",
                   "paused": True}),
    ]  # fmt: skip
    told.clear()
    with pytest.raises(ActionRejected):
        await store.release("p1", "bob")
    assert told == []  # nothing committed, nothing told
    kinds = [e.kind for e in await store.events()]
    assert kinds == ["queue_paused", "attempt_reserved", "job_created"]
    history = await store.events(job_id=job.id)
    assert [(e.kind, e.attempt_id, e.printer, e.user) for e in history] == [
        ("attempt_reserved", attempt.id, "p1", "dispatcher"),
        ("job_created", None, None, "ana"),
    ]


async def test_a_failing_listener_does_not_undo_the_change(database: AsyncEngine) -> None:
    def broken(kind: str, payload: dict[str, Any]) -> None:
        raise RuntimeError("listener bug")

    store = JobStore(database, on_change=broken)
    job = await store.create_job(new_job(), "ana")
    assert (await store.job(job.id)).state == "queued"


async def test_usage_counts_print_time_since_a_moment_and_the_last_start(
    database: AsyncEngine,
) -> None:
    moments = iter(datetime(2026, 1, day, tzinfo=UTC) for day in range(1, 30))
    store = JobStore(database, clock=lambda: next(moments))
    job = await store.create_job(new_job(3), "ana")  # day 1
    old = await reserved(store, job.id, "p1")  # day 2
    await store.advance(old.id, "printing")  # day 3
    await store.finish(old.id, "completed", print_seconds=100.0)  # day 4
    await store.clear("p1", "good", user="ana")  # day 5
    new = await reserved(store, job.id, "p1")  # day 6
    await store.finish(new.id, "failed", print_seconds=40.0)  # day 7
    other = await reserved(store, job.id, "p2")  # day 8
    usage = await store.usage(datetime(2026, 1, 5, tzinfo=UTC))
    assert usage == {
        "p1": (40.0, datetime(2026, 1, 6, tzinfo=UTC)),
        "p2": (0.0, other.created_at),
    }
    assert (await store.attempts_per_printer([job.id]))[job.id] == {"p1": 2, "p2": 1}
    assert [a.id for a in await store.attempts(job.id, live_only=True)] == [other.id]
    assert [a.id for a in await store.attempts()] == [old.id, new.id, other.id]
