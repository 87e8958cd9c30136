"""The job queue's database: jobs, their attempts, printer gates, the queue's history.

:class:`JobStore` is the only code that writes these tables. Every public method is one
transaction (:func:`kybercore.db.transaction`), so a change is whole or absent, and is safe
with many coroutines and several KyberCore processes on one database, SQLite or PostgreSQL:
writes that depend on what was read are conditional UPDATEs with their row counts checked,
on rows locked in one order (gate, job, attempt), and two partial unique indexes make two
live attempts on one printer, or two holders of one copy, impossible whatever happens above.
The transactions' bodies are :mod:`~kybercore.jobs.store_jobs` (jobs, the queue) and
:mod:`~kybercore.jobs.store_copies` (attempts, gates).
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable, Collection
from datetime import UTC, datetime
from types import EllipsisType
from typing import Any, TypeVar

from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.ext.asyncio import AsyncConnection, AsyncEngine

from kybercore.db import is_unique_violation, transaction
from kybercore.errors import InvalidInput
from kybercore.jobs import store_copies as copies
from kybercore.jobs import store_jobs as jobs
from kybercore.jobs import tables as t
from kybercore.jobs.models import ENDED, LIVE, Attempt, AttemptState, Gate, Job, NewJob
from kybercore.jobs.models import PlateVerdict as Verdict
from kybercore.jobs.store_unit import Unit
from kybercore.jobs.tables import QueueEvent

__all__ = ["JobStore", "Listener", "QueueEvent"]

log = logging.getLogger(__name__)

T = TypeVar("T")
Listener = Callable[[str, dict[str, Any]], None]
"""Called after each commit with ``(kind, payload)``: kind ``job``, ``attempt``, ``gate``
or ``queue``; the payload has ``event`` (``attempt_reserved``…), ``message``, ``user`` and
the changed object under its kind (``{"job": Job}``), or ``paused`` for ``queue``."""


def _utcnow() -> datetime:
    return datetime.now(UTC)


class JobStore:
    """Jobs, attempts and gates in the database behind ``engine``."""

    def __init__(
        self,
        engine: AsyncEngine,
        *,
        on_change: Listener | None = None,
        clock: Callable[[], datetime] = _utcnow,
    ) -> None:
        self._engine = engine
        self._on_change = on_change
        self._clock = clock

    def listen(self, on_change: Listener) -> None:
        """Call ``on_change(kind, payload)`` after each commit (replaces any listener): the
        queue service is built after the store it listens to."""
        self._on_change = on_change

    # -- jobs and the queue ----------------------------------------------------------------

    async def create_job(self, new: NewJob, user: str) -> Job:
        """Queue a job, after every other job of its priority."""
        _check_limits(new.quantity, new.max_attempts)
        return await self._write(lambda unit: jobs.create(unit, new, user))

    async def job(self, job_id: int) -> Job:
        """One job; :class:`~kybercore.errors.FileNotFound` when there is none."""
        return await self._read(lambda unit: unit.job(job_id))

    async def jobs(self, include_finished: bool = False) -> list[Job]:
        """Jobs in queue order: priority (highest first), position, id. Without
        ``include_finished``, only queued and blocked ones."""
        j = t.jobs.c
        query = t.select_jobs().order_by(j.priority.desc(), j.position, j.id)
        if not include_finished:
            query = query.where(j.state.in_(("queued", "blocked")))
        return await self._read(lambda unit: _all(unit.conn, query, t.to_job))

    async def update_job(
        self,
        job_id: int,
        *,
        priority: int | None = None,
        quantity: int | None = None,
        not_before: datetime | EllipsisType | None = ...,
        max_attempts: int | None = None,
        user: str,
    ) -> Job:
        """Change a job's priority, quantity, not-before time (``None`` clears it, ``...``
        leaves it) or max attempts. The quantity cannot go below the copies done or in
        flight; the job's state follows its counters (more copies: queued again; more
        attempts allowed: no longer blocked)."""
        _check_limits(
            1 if quantity is None else quantity, 1 if max_attempts is None else max_attempts
        )
        return await self._write(
            lambda unit: jobs.change(
                unit,
                job_id,
                priority=priority,
                quantity=quantity,
                not_before=not_before,
                max_attempts=max_attempts,
                user=user,
            )
        )

    async def move_job(self, job_id: int, before: int | None, user: str) -> Job:
        """Put a job just before job ``before``, taking its priority; with ``None``, after
        every job of its own priority."""
        return await self._write(lambda unit: jobs.move(unit, job_id, before, user))

    async def cancel_job(
        self, job_id: int, user: str, reason: str = ""
    ) -> tuple[Job, list[Attempt]]:
        """Cancel a job: no new copy of it starts. Returns it and its live attempts, which
        the caller must cancel on their printers (each then ends through :meth:`finish`).
        Cancelling a cancelled job again changes nothing; a done one is refused."""
        return await self._write(lambda unit: jobs.cancel(unit, job_id, user, reason))

    async def requeue_job(self, job_id: int, user: str) -> Job:
        """Queue a blocked job again, its failures forgotten."""
        return await self._write(lambda unit: jobs.requeue(unit, job_id, user))

    async def queue_paused(self) -> bool:
        """Whether the whole queue is paused: :meth:`reserve` then reserves nothing."""
        query = select(t.settings.c.value).where(t.settings.c.key == jobs.PAUSED_KEY)
        return bool(await self._read(lambda unit: unit.conn.scalar(query)))

    async def set_queue_paused(self, paused: bool, user: str) -> None:
        """Pause or resume the whole queue; prints under way go on."""
        await self._write(lambda unit: jobs.set_paused(unit, paused, user))

    # -- attempts --------------------------------------------------------------------------

    async def attempts(self, job_id: int | None = None, live_only: bool = False) -> list[Attempt]:
        """Attempts in the order they were made, of one job or all, live ones or all."""
        query = jobs.attempts_query(job_id, live_only)
        return await self._read(lambda unit: _all(unit.conn, query, t.to_attempt))

    async def attempt(self, attempt_id: int) -> Attempt:
        """One attempt; :class:`~kybercore.errors.FileNotFound` when there is none."""
        return await self._read(lambda unit: unit.attempt(attempt_id))

    async def reserve(self, job_id: int, printer: str, user: str = "dispatcher") -> Attempt | None:
        """Reserve the job's next copy on ``printer``, atomically: a pending attempt for the
        lowest free copy with a unique upload name, the printer's gate pointing at it, the
        job's ``in_flight`` one up. None when the queue is paused, the job is not queued,
        has no copy left or its not-before time is ahead, or the printer's gate is not
        available or has an attempt: someone else won, or there is nothing to do."""
        try:
            return await self._write(lambda unit: copies.reserve(unit, job_id, printer, user))
        except copies.LostRace:
            return None
        except IntegrityError as exc:
            if is_unique_violation(exc):
                return None  # the unique indexes caught a race the updates did not
            raise

    async def advance(
        self,
        attempt_id: int,
        state: AttemptState,
        *,
        reason: str = "",
        moonraker_job_id: str | None = None,
        print_seconds: float | None = None,
    ) -> Attempt:
        """Move a live attempt on: pending → uploading → starting → printing ⇄ paused
        (steps may be skipped, never taken back; an ended attempt is refused). The same
        state again only stores the Moonraker job id and print time given."""
        if state not in LIVE:
            raise InvalidInput(f"'{state}' is not a live attempt state; end attempts with finish.")
        return await self._write(
            lambda unit: copies.advance(
                unit,
                attempt_id,
                state,
                reason=reason,
                moonraker_job_id=moonraker_job_id,
                print_seconds=print_seconds,
            )
        )

    async def finish(
        self,
        attempt_id: int,
        state: AttemptState,
        *,
        reason: str = "",
        print_seconds: float | None = None,
        moonraker_job_id: str | None = None,
    ) -> Attempt:
        """End an attempt; the same end again is a no-op, another end is refused.

        ``completed``, ``failed``, ``cancelled``: the printer awaits a clear (persisted;
        a printer held meanwhile stays held, its plate still to clear). ``failed`` and
        ``cancelled`` give the copy back at once (``failed`` counts a failure);
        ``completed`` keeps it in flight until the verdict. ``failed_to_start``: the
        printer is held with the reason, the copy goes back, a failure counts. A job whose
        failures reach ``max_attempts`` is blocked with the last reason.
        """
        if state not in ENDED:
            raise InvalidInput(f"'{state}' is not an end state of an attempt.")
        return await self._write(
            lambda unit: copies.finish(
                unit,
                attempt_id,
                state,
                reason=reason,
                print_seconds=print_seconds,
                moonraker_job_id=moonraker_job_id,
            )
        )

    async def attempts_per_printer(self, job_ids: Collection[int]) -> dict[int, dict[str, int]]:
        """How many attempts of each job each printer has had (one query for all jobs)."""
        if not job_ids:
            return {}
        a = t.attempts.c
        query = (
            select(a.job_id, a.printer, func.count())
            .where(a.job_id.in_(list(job_ids)))
            .group_by(a.job_id, a.printer)
        )

        async def read(unit: Unit) -> dict[int, dict[str, int]]:
            counts: dict[int, dict[str, int]] = {}
            for job_id, printer, count in await unit.conn.execute(query):
                counts.setdefault(job_id, {})[printer] = count
            return counts

        return await self._read(read)

    async def usage(self, since: datetime) -> dict[str, tuple[float, datetime | None]]:
        """Per printer that ever had an attempt: seconds printed by attempts made since
        ``since``, and when its last attempt started."""
        return await self._read(lambda unit: copies.usage(unit, since))

    # -- gates -----------------------------------------------------------------------------

    async def clear(self, printer: str, verdict: Verdict, *, cause: str = "", user: str) -> Gate:
        """An operator cleared the plate: ``good`` counts a completed copy done, ``bad``
        (with an optional cause) sends it back to the queue. The printer becomes
        available (or stays held). Refused when there is no plate to clear."""
        if verdict not in ("good", "bad"):
            raise InvalidInput(f"A plate verdict is 'good' or 'bad', not '{verdict}'.")
        return await self._write(
            lambda unit: copies.clear(unit, printer, verdict, cause=cause, user=user)
        )

    async def hold(self, printer: str, reason: str, user: str) -> Gate:
        """Hold a printer: no new copy until released (a print on it goes on)."""
        return await self._write(lambda unit: copies.hold(unit, printer, "held", reason, user))

    async def set_maintenance(self, printer: str, reason: str, user: str) -> Gate:
        """Take a printer out for maintenance: a hold under another name."""
        return await self._write(
            lambda unit: copies.hold(unit, printer, "maintenance", reason, user)
        )

    async def release(self, printer: str, user: str) -> Gate:
        """Release a held printer or one in maintenance: available, or awaiting a clear
        when a print ended on it and its plate was not cleared."""
        return await self._write(lambda unit: copies.release(unit, printer, user))

    async def gates(self) -> dict[str, Gate]:
        """Every gate ever set, by printer; a printer missing here is available."""
        query = select(t.gates).order_by(t.gates.c.printer)

        async def read(unit: Unit) -> dict[str, Gate]:
            return {gate.printer: gate for gate in await _all(unit.conn, query, t.to_gate)}

        return await self._read(read)

    async def gate(self, printer: str) -> Gate:
        """One printer's gate (created available the first time it is asked for)."""
        return await self._write(lambda unit: unit.gate(printer))

    async def events(self, limit: int = 200, job_id: int | None = None) -> list[QueueEvent]:
        """The queue's history, newest first, of one job or all."""
        query = select(t.queue_events).order_by(t.queue_events.c.id.desc()).limit(limit)
        if job_id is not None:
            query = query.where(t.queue_events.c.job_id == job_id)
        return await self._read(lambda unit: _all(unit.conn, query, t.to_event))

    # -- plumbing --------------------------------------------------------------------------

    async def _write(self, work: Callable[[Unit], Awaitable[T]]) -> T:
        units: list[Unit] = []

        async def run(conn: AsyncConnection) -> T:
            units.append(Unit(conn, self._clock()))  # one per try: a retry starts clean
            return await work(units[-1])

        result = await transaction(self._engine, run)
        self._notify(units[-1].changes)
        return result

    async def _read(self, work: Callable[[Unit], Awaitable[T]]) -> T:
        return await transaction(
            self._engine, lambda conn: work(Unit(conn, self._clock())), write=False
        )

    def _notify(self, changes: list[tuple[str, dict[str, Any]]]) -> None:
        if self._on_change is None:
            return
        for kind, payload in changes:
            try:
                self._on_change(kind, payload)
            except Exception:
                # The change is committed; a listener's failure must not make it look failed.
                log.exception("Queue change listener failed on %s", kind)


def _check_limits(quantity: int, max_attempts: int) -> None:
    if quantity < 1:
        raise InvalidInput(f"A job needs at least one copy, not {quantity}.")
    if max_attempts < 1:
        raise InvalidInput(f"A job needs at least one attempt, not {max_attempts}.")


async def _all(conn: AsyncConnection, query: Any, convert: Callable[[Any], T]) -> list[T]:
    return [convert(row) for row in (await conn.execute(query)).mappings()]
