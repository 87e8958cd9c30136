"""The store's printer side: reserving a copy on a printer, its attempt's life, the gate.

Each function is the body of one transaction (:class:`~kybercore.jobs.store_unit.Unit`);
:class:`~kybercore.jobs.store.JobStore` runs it. Every write that depends on what was read
is a conditional UPDATE whose row count is checked, on rows locked in the one lock order
(gate, job, attempt), with the partial unique indexes on ``attempts`` underneath.
"""

from __future__ import annotations

import re
from typing import Any, Final

from sqlalchemy import and_, func, or_, select, update

from kybercore.errors import ActionRejected
from kybercore.jobs import tables as t
from kybercore.jobs.models import (
    ENDED,
    LIVE,
    Attempt,
    AttemptState,
    Gate,
    GateState,
    PlateVerdict,
)
from kybercore.jobs.store_jobs import PAUSED_KEY, update_job_row
from kybercore.jobs.store_unit import SYSTEM_USER, Unit

# Forward only along the attempt's life; printing and paused go both ways.
_RANK: Final = {"pending": 0, "uploading": 1, "starting": 2, "printing": 3, "paused": 3}
_SAFE_NAME: Final = re.compile(r"[^A-Za-z0-9._-]+")
_GCODE_SUFFIXES: Final = (".gcode", ".g", ".gco")


class LostRace(Exception):
    """Another transaction took the printer or the copy first: roll back, reserve nothing."""


def holds_copy() -> Any:
    """SQL: the attempt holds its copy (live, completed awaiting a verdict, or good)."""
    a = t.attempts.c
    return or_(
        a.state.in_(sorted(LIVE)),
        and_(a.state == "completed", or_(a.verdict.is_(None), a.verdict == "good")),
    )


def upload_name(job_id: int, copy: int, attempt_id: int, file_name: str) -> str:
    """The attempt's unique file name on the printer, which Moonraker's history keeps."""
    stem = _SAFE_NAME.sub("_", file_name).lstrip("._")[:80] or "job.gcode"
    if not stem.lower().endswith(_GCODE_SUFFIXES):
        stem += ".gcode"
    return f"kybercore/j{job_id}-c{copy}-a{attempt_id}-{stem}"


async def reserve(unit: Unit, job_id: int, printer: str, user: str) -> Attempt | None:
    """A pending attempt of the job's lowest free copy on ``printer``, or None when the job
    has no copy left for it or the printer is not free. Raises :class:`LostRace` after a
    write that must be undone."""
    conn = unit.conn
    paused = await conn.scalar(select(t.settings.c.value).where(t.settings.c.key == PAUSED_KEY))
    if paused:
        return None
    gate = await unit.gate(printer, lock=True)
    if gate.state != "available" or gate.attempt_id is not None:
        return None
    j = t.jobs.c
    taken = await conn.execute(
        update(t.jobs)
        .where(
            j.id == job_id,
            j.state == "queued",
            j.quantity - j.done - j.in_flight > 0,
            or_(j.not_before.is_(None), j.not_before <= unit.now),
        )
        .values(in_flight=j.in_flight + 1)
    )
    if taken.rowcount != 1:
        await unit.job(job_id)  # an unknown job is an error, a full or paused one is not
        return None
    job = await unit.job(job_id)
    used = set(
        (
            await conn.scalars(
                select(t.attempts.c.copy).where(t.attempts.c.job_id == job_id, holds_copy())
            )
        ).all()
    )
    copy = next(n for n in range(1, len(used) + 2) if n not in used)
    attempt_id = await conn.scalar(
        t.attempts.insert()
        .values(
            job_id=job_id,
            copy=copy,
            printer=printer,
            # Unique, replaced below once the attempt's id is known.
            upload_name=f"reserving/j{job_id}-c{copy}-{printer}",
            state="pending",
            reason="",
            cause="",
            by_user=user,
            created_at=unit.now,
            print_seconds=0.0,
        )
        .returning(t.attempts.c.id)
    )
    assert attempt_id is not None
    await conn.execute(
        update(t.attempts)
        .where(t.attempts.c.id == attempt_id)
        .values(upload_name=upload_name(job_id, copy, attempt_id, job.file.name))
    )
    claimed = await conn.execute(
        update(t.gates)
        .where(
            t.gates.c.printer == printer,
            t.gates.c.state == "available",
            t.gates.c.attempt_id.is_(None),
        )
        .values(attempt_id=attempt_id)
    )
    if claimed.rowcount != 1:
        raise LostRace(printer)
    attempt = await unit.attempt(attempt_id)
    await unit.record(
        "attempt_reserved",
        f"Copy {copy} of job {job_id} reserved on {printer}",
        user=user,
        job=job,
        attempt=attempt,
        gate=await unit.gate(printer),
    )
    return attempt


async def advance(
    unit: Unit,
    attempt_id: int,
    state: AttemptState,
    *,
    reason: str,
    moonraker_job_id: str | None,
    print_seconds: float | None,
) -> Attempt:
    """Move a live attempt along its life (see :meth:`JobStore.advance`)."""
    attempt = await unit.attempt(attempt_id, lock=True)
    if not attempt.live:
        raise ActionRejected(
            f"Attempt {attempt_id} already ended ({attempt.state}); it cannot become {state}.",
            code="attempt_ended",
        )
    moving = state != attempt.state
    if moving and not _forward(attempt.state, state):
        raise ActionRejected(
            f"Attempt {attempt_id} is {attempt.state}; it cannot go back to {state}.",
            code="bad_transition",
        )
    values: dict[str, Any] = {"state": state}
    if reason:
        values["reason"] = reason
    if moonraker_job_id is not None:
        values["moonraker_job_id"] = moonraker_job_id
    if print_seconds is not None:
        values["print_seconds"] = print_seconds
    if state == "printing" and attempt.started_at is None:
        values["started_at"] = unit.now
    await _update_attempt(unit, attempt, values)
    attempt = await unit.attempt(attempt_id)
    if moving:
        await unit.record(
            f"attempt_{state}",
            f"Attempt {attempt_id} on {attempt.printer}: {state}"
            + (f" ({reason})" if reason else ""),
            user=SYSTEM_USER,
            attempt=attempt,
        )
    return attempt


async def finish(
    unit: Unit,
    attempt_id: int,
    state: AttemptState,
    *,
    reason: str,
    print_seconds: float | None,
    moonraker_job_id: str | None,
) -> Attempt:
    """End an attempt (see :meth:`JobStore.finish`)."""
    seen = await unit.attempt(attempt_id)
    gate = await unit.gate(seen.printer, lock=True)
    job = await unit.job(seen.job_id, lock=True)
    attempt = await unit.attempt(attempt_id, lock=True)
    if not attempt.live:
        if attempt.state == state:
            return attempt  # told twice (an event and the history both report it)
        raise ActionRejected(
            f"Attempt {attempt_id} already ended {attempt.state}; it cannot end {state}.",
            code="attempt_ended",
        )
    values: dict[str, Any] = {"state": state, "reason": reason, "ended_at": unit.now}
    if print_seconds is not None:
        values["print_seconds"] = print_seconds
    if moonraker_job_id is not None:
        values["moonraker_job_id"] = moonraker_job_id
    await _update_attempt(unit, attempt, values)

    counters: dict[str, int] = {}
    if state != "completed":  # a completed copy waits for its verdict
        counters["in_flight"] = job.in_flight - 1
    if state in ("failed", "failed_to_start"):
        counters["failures"] = job.failures + 1
    what = f"{state}: {reason}" if reason else state
    job = await update_job_row(unit, job, counters, blocked_reason=f"{attempt.printer}: {what}")

    if state == "failed_to_start":
        # Nothing printed, so no plate to clear; the printer waits for an operator.
        gate = await set_gate(
            unit, gate, "held" if gate.state == "available" else gate.state,
            reason=f"failed to start: {reason}" if reason else "failed to start",
            attempt_id=None, user=SYSTEM_USER,
        )  # fmt: skip
    else:
        # Whatever is on the plate stays until someone clears it; a hold set during the
        # print stays too, the uncleared plate kept in attempt_id.
        gate = await set_gate(
            unit, gate, "awaiting_clear" if gate.state == "available" else gate.state,
            reason=what if gate.state == "available" else gate.reason,
            attempt_id=attempt_id, user=SYSTEM_USER,
        )  # fmt: skip
    attempt = await unit.attempt(attempt_id)
    await unit.record(
        f"attempt_{state}",
        f"Attempt {attempt_id} (job {job.id}, copy {attempt.copy}) on {attempt.printer}: {what}",
        user=SYSTEM_USER,
        job=job,
        attempt=attempt,
        gate=gate,
    )
    return attempt


async def clear(unit: Unit, printer: str, verdict: PlateVerdict, *, cause: str, user: str) -> Gate:
    """Clear a printer's plate with a verdict (see :meth:`JobStore.clear`)."""
    gate = await unit.gate(printer, lock=True)
    ended = await _uncleared(unit, gate)
    if ended is None:
        raise ActionRejected(
            f"{printer} has no plate to clear: it is {gate.state.replace('_', ' ')}.",
            code="nothing_to_clear",
        )
    job = await unit.job(ended.job_id, lock=True)
    attempt = await unit.attempt(ended.id, lock=True)
    await _update_attempt(unit, attempt, {"verdict": verdict, "cause": cause})
    if attempt.state == "completed":
        counters = {"in_flight": job.in_flight - 1}
        if verdict == "good":
            counters["done"] = job.done + 1
        job = await update_job_row(unit, job, counters)
    gate = await set_gate(
        unit, gate, "available" if gate.state == "awaiting_clear" else gate.state,
        reason="" if gate.state == "awaiting_clear" else gate.reason,
        attempt_id=None, user=user,
    )  # fmt: skip
    await unit.record(
        "gate_cleared",
        f"{printer} cleared: {verdict}" + (f" ({cause})" if cause else ""),
        user=user,
        job=job,
        attempt=await unit.attempt(attempt.id),
        gate=gate,
    )
    return gate


async def hold(unit: Unit, printer: str, state: GateState, reason: str, user: str) -> Gate:
    """Hold a printer or put it in maintenance; a print on it runs on, an uncleared plate
    stays uncleared."""
    gate = await unit.gate(printer, lock=True)
    gate = await set_gate(unit, gate, state, reason=reason, attempt_id=gate.attempt_id, user=user)
    await unit.record(
        f"gate_{state}", f"{printer}: {state}" + (f" ({reason})" if reason else ""),
        user=user, gate=gate,
    )  # fmt: skip
    return gate


async def release(unit: Unit, printer: str, user: str) -> Gate:
    """Release a held printer: available, or awaiting a clear when its plate still is."""
    gate = await unit.gate(printer, lock=True)
    if gate.state not in ("held", "maintenance"):
        advice = " Clear its plate with a verdict." if gate.state == "awaiting_clear" else ""
        raise ActionRejected(
            f"{printer} is not held: it is {gate.state.replace('_', ' ')}.{advice}",
            code="not_held",
        )
    plate = await _uncleared(unit, gate)
    gate = await set_gate(
        unit, gate, "awaiting_clear" if plate else "available",
        reason=f"{plate.state}, plate not cleared yet" if plate else "",
        attempt_id=gate.attempt_id, user=user,
    )  # fmt: skip
    await unit.record("gate_released", f"{printer} released", user=user, gate=gate)
    return gate


async def set_gate(
    unit: Unit, gate: Gate, state: GateState, *, reason: str, attempt_id: int | None, user: str
) -> Gate:
    """Write a locked gate; ``since`` moves only when its state does."""
    since = gate.since if state == gate.state else unit.now
    await unit.conn.execute(
        update(t.gates)
        .where(t.gates.c.printer == gate.printer)
        .values(state=state, reason=reason, attempt_id=attempt_id, since=since, by_user=user)
    )
    return await unit.gate(gate.printer)


def _forward(current: str, new: str) -> bool:
    return _RANK[new] > _RANK[current] or {current, new} == {"printing", "paused"}


async def _update_attempt(unit: Unit, attempt: Attempt, values: dict[str, Any]) -> None:
    # Conditional on the state read: belt and braces under the row lock.
    done = await unit.conn.execute(
        update(t.attempts)
        .where(t.attempts.c.id == attempt.id, t.attempts.c.state == attempt.state)
        .values(**values)
    )
    if done.rowcount != 1:
        raise LostRace(f"attempt {attempt.id}")


async def _uncleared(unit: Unit, gate: Gate) -> Attempt | None:
    """The ended attempt whose plate the printer still holds, if any."""
    if gate.attempt_id is None:
        return None
    attempt = await unit.attempt(gate.attempt_id)
    return attempt if attempt.state in ENDED and attempt.verdict is None else None


async def usage(unit: Unit, since: Any) -> dict[str, tuple[float, Any]]:
    """Per printer: print seconds of attempts created since ``since``, last attempt start."""
    a = t.attempts.c
    rows = await unit.conn.execute(
        select(
            a.printer,
            func.coalesce(func.sum(a.print_seconds).filter(a.created_at >= since), 0.0),
            func.max(func.coalesce(a.started_at, a.created_at)),
        ).group_by(a.printer)
    )
    return {printer: (float(seconds), last) for printer, seconds, last in rows}
