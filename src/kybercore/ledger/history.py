"""Moonraker's job history, kept once per job in KyberCore's database.

Each printer's Moonraker numbers its jobs itself (``job_id``, hex, counting up in its own
database), so a job is known by (printer, Moonraker instance, job id): the instance is the
id Moonraker stores in that same database (:func:`read_instance`), so a reinstalled
Moonraker, whose numbering starts again, never overwrites the jobs of the old one.

Jobs come in two ways, in any order and any number of times: live ``notify_history_changed``
events, and a backfill of ``/server/history/list`` after every (re)connect
(:func:`backfill`). :meth:`HistoryStore.upsert` makes that safe: one row per job, and a
finished job's row never goes back to ``in_progress`` when an older copy arrives late.
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

from sqlalchemy import and_, bindparam, func, or_, select
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.ext.asyncio import AsyncConnection, AsyncEngine

from kybercore.core.numbers import finite_number
from kybercore.db import reading, transaction
from kybercore.errors import MoonrakerRpcError
from kybercore.jobs.tables import attempts
from kybercore.ledger.tables import history_jobs

log = logging.getLogger(__name__)

IN_PROGRESS: Final = "in_progress"
PAGE: Final = 100
"""Jobs per ``/server/history/list`` request when backfilling."""
UNKNOWN_INSTANCE: Final = "unknown"
"""Used when Moonraker does not tell its instance id (an old or locked-down Moonraker)."""
_UPDATED: Final = (
    "filename", "status", "moonraker_user", "start_time", "end_time", "print_duration",
    "total_duration", "filament_used", "filament_g", "material", "file_meta", "updated_at",
)  # fmt: skip
"""What a newer copy of a known job replaces."""

HistoryPage = Callable[[int, int], Awaitable[Mapping[str, Any]]]
"""``(limit, start) -> {count, jobs}``: one page of Moonraker's history, newest first."""


@dataclass(frozen=True)
class HistoryJob:
    """One job as Moonraker's history reports it (the fields the ledger keeps)."""

    job_id: str
    filename: str
    status: str
    start_time: float
    end_time: float | None = None
    print_duration: float = 0.0
    total_duration: float = 0.0
    filament_used: float = 0.0
    user: str = ""
    meta: Mapping[str, Any] = field(default_factory=dict)

    @property
    def number(self) -> int:
        """The job id as the number Moonraker counts with."""
        return int(self.job_id, 16)

    @property
    def material(self) -> str | None:
        """The filament type the file was sliced for (``PLA``), if it says."""
        value = self.meta.get("filament_type")
        return str(value)[:64] if isinstance(value, str) and value.strip() else None

    @property
    def filament_g(self) -> float | None:
        """Grams used: the millimetres used times the file's weight per millimetre, when
        its metadata gives both its total length and weight (a cancelled print used part)."""
        weight = finite_number(self.meta.get("filament_weight_total"))
        length = finite_number(self.meta.get("filament_total"))
        if weight is None or length is None or weight <= 0 or length <= 0:
            return None
        return round(self.filament_used * weight / length, 3)


def parse_job(raw: Any) -> HistoryJob | None:
    """A job of Moonraker's history, or None when it lacks what identifies it (an id and a
    start time): a peer's bad record is skipped, never allowed to stop the ingest."""
    if not isinstance(raw, Mapping):
        return None
    job_id = raw.get("job_id")
    start = finite_number(raw.get("start_time"))
    if not isinstance(job_id, str) or start is None:
        return None
    try:
        int(job_id, 16)
    except ValueError:
        return None
    meta = raw.get("metadata")
    user = raw.get("user")
    return HistoryJob(
        job_id=job_id.upper()[:16],
        filename=str(raw.get("filename") or ""),
        status=str(raw.get("status") or IN_PROGRESS)[:32],
        start_time=start,
        end_time=finite_number(raw.get("end_time")),
        print_duration=finite_number(raw.get("print_duration")) or 0.0,
        total_duration=finite_number(raw.get("total_duration")) or 0.0,
        filament_used=finite_number(raw.get("filament_used")) or 0.0,
        user="" if not isinstance(user, str) or user == "No User" else user[:100],
        meta={k: v for k, v in meta.items() if k != "thumbnails"}
        if isinstance(meta, Mapping)
        else {},
    )


def jobs_of_notification(params: Sequence[Any]) -> list[HistoryJob]:
    """The jobs a ``notify_history_changed`` notification carries (``added``/``finished``)."""
    jobs = []
    for item in params:
        if isinstance(item, Mapping) and item.get("action") in ("added", "finished"):
            job = parse_job(item.get("job"))
            if job is not None:
                jobs.append(job)
    return jobs


async def read_instance(call: Callable[[str, Mapping[str, Any]], Awaitable[Any]]) -> str:
    """The id of the Moonraker database the printer's history lives in.

    Moonraker writes its instance UUID into its database the first time it opens it and
    keeps it there (the ``moonraker`` namespace, readable by any client): it changes exactly
    when the job numbering starts again from 1 (a new database), and not when Moonraker is
    only restarted or upgraded. ``call`` is the printer's JSON-RPC call."""
    try:
        item = await call(
            "server.database.get_item", {"namespace": "moonraker", "key": "instance_id"}
        )
    except MoonrakerRpcError as exc:
        log.warning("Moonraker does not tell its instance id (%s); using %r", exc, UNKNOWN_INSTANCE)
        return UNKNOWN_INSTANCE
    value = item.get("value") if isinstance(item, Mapping) else None
    return str(value)[:64] if isinstance(value, str) and value else UNKNOWN_INSTANCE


async def backfill(
    page: HistoryPage, floor: int, limit: int = PAGE
) -> AsyncIterator[list[HistoryJob]]:
    """Moonraker's history newest first, one page at a time, down to the job numbered
    ``floor`` (included: the overlap with what is known, whose status may have changed).

    ``floor`` 0 reads everything: 5,000 jobs take ceil(5000 / limit) requests, as the
    page holding job 1 is the last. Jobs added meanwhile shift the pages: a job may then be
    read twice (harmless), never skipped."""
    start = 0
    while True:
        answer = await page(limit, start)
        raw = answer.get("jobs")
        raw = raw if isinstance(raw, list) else []
        jobs = [job for job in map(parse_job, raw) if job is not None]
        if jobs:
            yield jobs
        lowest = min((job.number for job in jobs), default=0)
        if len(raw) < limit or lowest <= max(floor, 1):
            return
        start += len(raw)


class HistoryStore:
    """The ``history_jobs`` table: idempotent writes, and the counts /metrics shows."""

    def __init__(self, engine: AsyncEngine) -> None:
        self._engine = engine

    async def upsert(self, rows: Sequence[tuple[str, str, HistoryJob]]) -> None:
        """Write ``(printer, instance, job)`` rows in one transaction: insert new jobs,
        update known ones, except that a finished job never returns to ``in_progress``.
        Each job is linked to the queue attempt whose upload name is its file name."""
        # One row per job, chosen by the rule the statement applies between rows: a later
        # copy wins, except that an in-progress copy never replaces a finished one.
        latest: dict[tuple[str, str, str], tuple[str, str, HistoryJob]] = {}
        for p, i, job in rows:
            known = latest.get((p, i, job.job_id))
            if known is None or job.status != IN_PROGRESS or known[2].status == IN_PROGRESS:
                latest[(p, i, job.job_id)] = (p, i, job)
        if not latest:
            return
        now = time.time()
        values = [_row(p, i, job, now) for p, i, job in latest.values()]

        async def work(conn: AsyncConnection) -> None:
            # One statement, compiled once and cached, run for every row (executemany):
            # a statement with a hundred rows spelled out takes ~50 ms to compile.
            await conn.execute(_upsert_statement(conn.dialect.name), values)

        await transaction(self._engine, work)

    async def floor(self, printer: str, instance: str) -> int:
        """Where the next backfill of this printer may stop: its oldest job still in
        progress here (it has finished since, most likely), else its newest job known;
        0 when none is known."""
        where = and_(history_jobs.c.printer == printer, history_jobs.c.instance == instance)
        ids = history_jobs.c.moonraker_job_id
        async with reading(self._engine) as conn:
            open_ids = (
                await conn.scalars(select(ids).where(where, history_jobs.c.status == IN_PROGRESS))
            ).all()
            # Zero-padded hex: the longest, then the largest, is the newest.
            newest = await conn.scalar(
                select(ids).where(where).order_by(func.length(ids).desc(), ids.desc()).limit(1)
            )
        numbers = [int(i, 16) for i in open_ids]
        if numbers:
            return min(numbers)
        return int(newest, 16) if newest else 0

    async def counts(self, printers: Sequence[str] | None = None) -> dict[tuple[str, str], int]:
        """Jobs per (printer, status), for every printer or the ones named."""
        query = select(history_jobs.c.printer, history_jobs.c.status, func.count()).group_by(
            history_jobs.c.printer, history_jobs.c.status
        )
        if printers is not None:
            query = query.where(history_jobs.c.printer.in_(printers))
        async with reading(self._engine) as conn:
            result = await conn.execute(query)
            return {(printer, status): int(n) for printer, status, n in result}


@functools.cache
def _upsert_statement(dialect: str) -> Any:
    """INSERT … ON CONFLICT DO UPDATE of one ``history_jobs`` row, in ``dialect``."""
    link = (
        select(attempts.c.id)
        .where(attempts.c.upload_name == bindparam("link_name"))
        .where(attempts.c.printer == bindparam("link_printer"))
        .order_by(attempts.c.id.desc())
        .limit(1)
        .scalar_subquery()
    )
    insert = postgresql.insert if dialect == "postgresql" else sqlite.insert
    stmt = insert(history_jobs).values(attempt_id=link)
    new, table = stmt.excluded, history_jobs.c
    return stmt.on_conflict_do_update(
        index_elements=[table.printer, table.instance, table.moonraker_job_id],
        set_={
            **{name: new[name] for name in _UPDATED},
            "attempt_id": func.coalesce(table.attempt_id, new.attempt_id),
        },
        where=or_(table.status == IN_PROGRESS, new.status != IN_PROGRESS),
    )


def _row(printer: str, instance: str, job: HistoryJob, now: float) -> dict[str, Any]:
    return {
        "printer": printer,
        "instance": instance,
        "moonraker_job_id": job.job_id,
        "filename": job.filename,
        "status": job.status,
        "moonraker_user": job.user,
        "start_time": job.start_time,
        "end_time": job.end_time,
        "print_duration": job.print_duration,
        "total_duration": job.total_duration,
        "filament_used": job.filament_used,
        "filament_g": job.filament_g,
        "material": job.material,
        "file_meta": dict(job.meta),
        "updated_at": now,
        "link_name": job.filename,
        "link_printer": printer,
    }
