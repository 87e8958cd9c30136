"""The store's job side: queueing, changing, ordering, cancelling jobs; pausing the queue.

Each function is the body of one transaction (:class:`~kybercore.jobs.store_unit.Unit`);
:class:`~kybercore.jobs.store.JobStore` runs it. A job's state always follows from its
counters (:func:`update_job_row`), so no path can leave a job queued with every copy done
or running past ``max_attempts``.
"""

from __future__ import annotations

from datetime import datetime
from types import EllipsisType
from typing import Any

from sqlalchemy import func, select, update

from kybercore.errors import ActionRejected
from kybercore.jobs import tables as t
from kybercore.jobs.models import LIVE, Attempt, Job, NewJob
from kybercore.jobs.store_unit import Unit, upsert

PAUSED_KEY = "paused"
"""The ``settings`` row that says whether the whole queue is paused."""


def attempts_query(job_id: int | None, live_only: bool) -> Any:
    """Attempts in the order they were made, of one job or all, live ones only or all."""
    query = select(t.attempts).order_by(t.attempts.c.id)
    if job_id is not None:
        query = query.where(t.attempts.c.job_id == job_id)
    if live_only:
        query = query.where(t.attempts.c.state.in_(sorted(LIVE)))
    return query


async def create(unit: Unit, new: NewJob, user: str) -> Job:
    """Insert a queued job after every other one."""
    last = await unit.conn.scalar(select(func.max(t.jobs.c.position)))
    job_id = await unit.conn.scalar(
        t.jobs.insert()
        .values(
            file_sha256=new.file.sha256,
            file_name=new.file.name,
            file_size=new.file.size,
            file_meta=dict(new.file.meta),
            quantity=new.quantity,
            priority=new.priority,
            position=(last or 0.0) + 1.0,
            not_before=new.not_before,
            requirements=t.requirements_json(new.requirements),
            allow_mismatch=new.allow_mismatch,
            max_attempts=new.max_attempts,
            state="queued",
            reason="",
            done=0,
            in_flight=0,
            failures=0,
            created_at=unit.now,
            created_by=user,
        )
        .returning(t.jobs.c.id)
    )
    assert job_id is not None
    job = await unit.job(job_id)
    message = f"Job {job_id} queued: {new.quantity} × {new.file.name}"
    await unit.record("job_created", message, user=user, job=job)
    return job


async def change(
    unit: Unit,
    job_id: int,
    *,
    priority: int | None,
    quantity: int | None,
    not_before: datetime | EllipsisType | None,
    max_attempts: int | None,
    user: str,
) -> Job:
    """Change what was given of a job (see :meth:`JobStore.update_job`)."""
    job = await unit.job(job_id, lock=True)
    if job.state == "cancelled":
        raise ActionRejected(f"Job {job_id} is cancelled.", code="job_cancelled")
    values: dict[str, Any] = {}
    if priority is not None and priority != job.priority:
        values["priority"] = priority
    if quantity is not None and quantity != job.quantity:
        if quantity < job.done + job.in_flight:
            raise ActionRejected(
                f"Job {job_id} has {job.done} copies done and {job.in_flight} in flight; "
                f"its quantity cannot go below {job.done + job.in_flight}.",
                code="quantity_in_use",
            )
        values["quantity"] = quantity
    if not isinstance(not_before, EllipsisType) and not_before != job.not_before:
        values["not_before"] = not_before
    if max_attempts is not None and max_attempts != job.max_attempts:
        values["max_attempts"] = max_attempts
    if not values:
        return job
    job = await update_job_row(unit, job, values)
    changed = ", ".join(f"{key} {value}" for key, value in values.items())
    await unit.record("job_updated", f"Job {job_id}: {changed}", user=user, job=job)
    return job


async def move(unit: Unit, job_id: int, before: int | None, user: str) -> Job:
    """Put a job before another one or last (see :meth:`JobStore.move_job`)."""
    job = await unit.job(job_id, lock=True)
    if before == job_id:
        return job
    priority, position = await _place(unit, job, before)
    await unit.conn.execute(
        update(t.jobs).where(t.jobs.c.id == job_id).values(priority=priority, position=position)
    )
    job = await unit.job(job_id)
    where = f"before job {before}" if before is not None else "to the end"
    await unit.record("job_moved", f"Job {job_id} moved {where}", user=user, job=job)
    return job


async def cancel(unit: Unit, job_id: int, user: str, reason: str) -> tuple[Job, list[Attempt]]:
    """Cancel a job; its live attempts are the caller's to stop."""
    job = await unit.job(job_id, lock=True)
    if job.state == "done":
        raise ActionRejected(f"Job {job_id} is already done.", code="job_done")
    if job.state != "cancelled":
        await unit.conn.execute(
            update(t.jobs)
            .where(t.jobs.c.id == job_id)
            .values(state="cancelled", reason=reason or f"cancelled by {user}")
        )
        job = await unit.job(job_id)
        message = f"Job {job_id} cancelled" + (f": {reason}" if reason else "")
        await unit.record("job_cancelled", message, user=user, job=job)
    live = (await unit.conn.execute(attempts_query(job_id, True))).mappings()
    return job, [t.to_attempt(row) for row in live]


async def requeue(unit: Unit, job_id: int, user: str) -> Job:
    """Queue a blocked job again with its failures forgotten."""
    job = await unit.job(job_id, lock=True)
    if job.state != "blocked":
        raise ActionRejected(f"Job {job_id} is {job.state}, not blocked.", code="job_not_blocked")
    job = await update_job_row(unit, job, {"failures": 0})
    await unit.record("job_requeued", f"Job {job_id} queued again", user=user, job=job)
    return job


async def set_paused(unit: Unit, paused: bool, user: str) -> None:
    """Pause or resume the whole queue."""
    values = {"value": paused, "updated_at": unit.now, "by_user": user}
    await unit.conn.execute(
        upsert(unit.conn, t.settings)
        .values(key=PAUSED_KEY, **values)
        .on_conflict_do_update(index_elements=["key"], set_=values)
    )
    word = "paused" if paused else "resumed"
    await unit.record(f"queue_{word}", f"Queue {word}", user=user, notify={"paused": paused})


async def update_job_row(
    unit: Unit, job: Job, values: dict[str, Any], *, blocked_reason: str = ""
) -> Job:
    """Write ``values`` to a locked job and settle its state from its counters: done at
    ``quantity`` good copies, blocked at ``max_attempts`` failures (with
    ``blocked_reason``, the last failure's), queued otherwise; cancelled stays."""
    merged = {
        "done": job.done,
        "quantity": job.quantity,
        "failures": job.failures,
        "max_attempts": job.max_attempts,
        **values,
    }
    state, reason = job.state, job.reason
    if state != "cancelled":
        if merged["done"] >= merged["quantity"]:
            state, reason = "done", ""
        elif merged["failures"] >= merged["max_attempts"]:
            fallback = job.reason if job.state == "blocked" else ""
            reason = (
                blocked_reason
                or fallback
                or f"failed attempts: {merged['failures']} of {merged['max_attempts']} allowed"
            )
            state = "blocked"
        else:
            state, reason = "queued", ""
    await unit.conn.execute(
        update(t.jobs).where(t.jobs.c.id == job.id).values(**values, state=state, reason=reason)
    )
    return await unit.job(job.id)


async def _place(unit: Unit, job: Job, before: int | None) -> tuple[int, float]:
    """The priority and position that put ``job`` just before job ``before`` (or last)."""
    j = t.jobs.c
    if before is None:
        last = await unit.conn.scalar(select(func.max(j.position)).where(j.id != job.id))
        return job.priority, (last or 0.0) + 1.0
    target = await unit.job(before)
    previous = await unit.conn.scalar(
        select(func.max(j.position)).where(
            j.priority == target.priority, j.id != job.id, j.position < target.position
        )
    )
    if previous is None:
        return target.priority, target.position - 1.0
    middle = (previous + target.position) / 2
    if previous < middle < target.position:
        return target.priority, middle
    # Halved so often that no float fits between: number every job 1, 2, 3… in queue
    # order (a rare O(jobs) write) and place it again.
    order = await unit.conn.scalars(select(j.id).order_by(j.priority.desc(), j.position, j.id))
    for index, other in enumerate(order.all(), start=1):
        await unit.conn.execute(update(t.jobs).where(j.id == other).values(position=float(index)))
    return await _place(unit, job, before)
