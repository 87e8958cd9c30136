"""One unit of work of the job store: its connection, its clock and what it changed.

A :class:`Unit` lives for one database transaction. It loads rows (locking them on
PostgreSQL when asked, in the store's one lock order: gate, then job, then attempt, so two
transactions never wait for each other in a circle), records the queue's history and
collects the notifications the store sends once the transaction has committed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from sqlalchemy import Table, insert, select
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.ext.asyncio import AsyncConnection

from kybercore.errors import FileNotFound
from kybercore.jobs import tables as t
from kybercore.jobs.models import Attempt, Gate, Job

SYSTEM_USER = "kybercore"
"""Who acts when nobody does: a print that ends, a printer whose gate appears."""


@dataclass
class Unit:
    """The transaction one store method runs in."""

    conn: AsyncConnection
    now: datetime
    changes: list[tuple[str, dict[str, Any]]] = field(default_factory=list)
    """``(kind, payload)`` for the store's listener, sent after the commit."""

    async def job(self, job_id: int, *, lock: bool = False) -> Job:
        """The job, locked for this transaction when ``lock`` (PostgreSQL; on SQLite the
        write transaction holds the whole database)."""
        query = t.select_jobs().where(t.jobs.c.id == job_id)
        if lock:
            # FOR NO KEY UPDATE: other transactions may still insert attempts and events
            # that refer to the job (their foreign key check takes KEY SHARE).
            query = query.with_for_update(key_share=True, of=t.jobs)
        row = (await self.conn.execute(query)).mappings().first()
        if row is None:
            raise FileNotFound(
                f"No job with id {job_id}. List the queue with GET /api/jobs or "
                "`kybercore jobs list`."
            )
        return t.to_job(row)

    async def attempt(self, attempt_id: int, *, lock: bool = False) -> Attempt:
        """The attempt, locked when ``lock``."""
        query = select(t.attempts).where(t.attempts.c.id == attempt_id)
        if lock:
            query = query.with_for_update(key_share=True)
        row = (await self.conn.execute(query)).mappings().first()
        if row is None:
            raise FileNotFound(f"No attempt with id {attempt_id}.")
        return t.to_attempt(row)

    async def gate(self, printer: str, *, lock: bool = False) -> Gate:
        """The printer's gate, created ``available`` on first use, locked when ``lock``."""
        await self.conn.execute(
            upsert(self.conn, t.gates)
            .values(
                printer=printer,
                state="available",
                reason="",
                since=self.now,
                attempt_id=None,
                by_user=SYSTEM_USER,
            )
            .on_conflict_do_nothing(index_elements=["printer"])
        )
        query = select(t.gates).where(t.gates.c.printer == printer)
        if lock:
            query = query.with_for_update(key_share=True)
        row = (await self.conn.execute(query)).mappings().one()
        return t.to_gate(row)

    async def record(
        self,
        kind: str,
        message: str,
        *,
        user: str,
        job: Job | None = None,
        attempt: Attempt | None = None,
        gate: Gate | None = None,
        printer: str | None = None,
        notify: dict[str, Any] | None = None,
    ) -> None:
        """Write one history entry and queue a notification per changed object.

        ``notify`` is the payload of a ``queue`` notification (pause and resume).
        """
        if printer is None:
            printer = gate.printer if gate else attempt.printer if attempt else None
        await self.conn.execute(
            insert(t.queue_events).values(
                at=self.now,
                kind=kind,
                job_id=job.id if job else attempt.job_id if attempt else None,
                attempt_id=attempt.id if attempt else None,
                printer=printer,
                by_user=user,
                message=message,
            )
        )
        base = {"event": kind, "message": message, "user": user}
        for name, changed in (("job", job), ("attempt", attempt), ("gate", gate)):
            if changed is not None:
                self.changes.append((name, {**base, name: changed}))
        if notify is not None:
            self.changes.append(("queue", {**base, **notify}))


def upsert(conn: AsyncConnection, table: Table) -> postgresql.Insert | sqlite.Insert:
    """An INSERT with ``ON CONFLICT`` in the connection's dialect (both speak it)."""
    if conn.dialect.name == "postgresql":
        return postgresql.insert(table)
    return sqlite.insert(table)
