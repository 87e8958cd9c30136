"""Reading the ledger's job history: filtered pages for ``GET /api/history`` and every
matching row for ``GET /api/history.csv``, each job joined with the queue attempt that
printed it (file hash, queue times, plate verdict) when there is one.
"""

from __future__ import annotations

import csv
import io
from collections.abc import AsyncIterator, Iterable, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any, Final

from sqlalchemy import (
    ColumnElement,
    Float,
    Select,
    and_,
    case,
    func,
    literal,
    null,
    or_,
    select,
)
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.db import reading
from kybercore.jobs.tables import attempts, jobs, queue_events
from kybercore.ledger.tables import history_jobs

COLUMNS: Final = (
    "printer", "moonraker_job_id", "filename", "sha256", "job_id", "attempt_id", "status",
    "queued_at", "started_at", "ended_at", "cleared_at", "verdict", "cause", "print_seconds",
    "filament_mm", "filament_g", "user",
)  # fmt: skip
"""A history row's fields, in the CSV's column order."""
CSV_BATCH: Final = 500
CLEARED: Final = "gate_cleared"
"""The queue event that records a plate's verdict (its time is the row's ``cleared_at``)."""


@dataclass(frozen=True)
class HistoryFilter:
    """Which jobs to list; None matches everything. ``file`` matches part of the file
    name (any case); ``start``/``end`` (epoch seconds) bound the job's start time."""

    printer: str | None = None
    status: str | None = None
    file: str | None = None
    user: str | None = None
    start: float | None = None
    end: float | None = None


NOBODY: Final = ("", "_TRUSTED_USER_", "_API_KEY_USER_")
"""What Moonraker records as a job's user when it knows no person: a trusted address, its
API key (its ``authorization`` component's names)."""


def _user() -> ColumnElement[Any]:
    # Who queued it, for a queued job; who Moonraker says started it, otherwise.
    started_by = history_jobs.c.moonraker_user
    person = case((started_by.in_(NOBODY), null()), else_=started_by)
    return func.coalesce(jobs.c.created_by, person)


def _query(where: HistoryFilter) -> Select[Any]:
    h = history_jobs.c
    conditions: list[ColumnElement[bool]] = []
    if where.printer is not None:
        conditions.append(h.printer == where.printer)
    if where.status is not None:
        conditions.append(h.status == where.status)
    if where.file:
        pattern = where.file.lower().replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_")
        conditions.append(func.lower(h.filename).like(f"%{pattern}%", escape="\\"))
    if where.user is not None:
        conditions.append(_user() == where.user)
    if where.start is not None:
        conditions.append(h.start_time >= literal(where.start, Float))
    if where.end is not None:
        conditions.append(h.start_time < literal(where.end, Float))
    joined = history_jobs.outerjoin(attempts, attempts.c.id == h.attempt_id).outerjoin(
        jobs, jobs.c.id == attempts.c.job_id
    )
    cleared = (
        select(func.max(queue_events.c.at))
        .where(queue_events.c.attempt_id == h.attempt_id, queue_events.c.kind == CLEARED)
        .scalar_subquery()
    )
    fields = (
        h.printer, h.moonraker_job_id, h.filename, jobs.c.file_sha256.label("sha256"),
        attempts.c.job_id, h.attempt_id, h.status, jobs.c.created_at.label("queued_at"),
        h.start_time, h.end_time, cleared.label("cleared_at"), attempts.c.verdict,
        attempts.c.cause, h.print_duration, h.filament_used, h.filament_g,
        _user().label("user"), h.id,
    )  # fmt: skip
    return select(*fields).select_from(joined).where(*conditions)


async def page(
    engine: AsyncEngine, where: HistoryFilter, limit: int, offset: int
) -> tuple[int, list[dict[str, Any]]]:
    """How many jobs match, and the ``limit`` after ``offset``, newest first."""
    query = _query(where)
    async with reading(engine) as conn:
        total = await conn.scalar(select(func.count()).select_from(query.subquery()))
        result = await conn.execute(
            query.order_by(history_jobs.c.start_time.desc(), history_jobs.c.id.desc())
            .limit(limit)
            .offset(offset)
        )
        return int(total or 0), [_row(r) for r in result]


async def every_row(engine: AsyncEngine, where: HistoryFilter) -> AsyncIterator[dict[str, Any]]:
    """Every matching job, newest first, read in batches (a keyset, not offsets: a batch
    costs the same at the end of 100,000 jobs as at the start)."""
    h = history_jobs.c
    after: tuple[float, int] | None = None
    while True:
        query = _query(where)
        if after is not None:
            start, row_id = after
            query = query.where(
                or_(h.start_time < start, and_(h.start_time == start, h.id < row_id))
            )
        query = query.order_by(h.start_time.desc(), h.id.desc()).limit(CSV_BATCH)
        async with reading(engine) as conn:
            batch = (await conn.execute(query)).all()
        for record in batch:
            yield _row(record)
        if len(batch) < CSV_BATCH:
            return
        after = (batch[-1].start_time, batch[-1].id)


def csv_text(rows: Iterable[Mapping[str, Any]], header: bool = False) -> str:
    """Rows as CSV lines (with the header line first when asked)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\r\n")
    if header:
        writer.writerow(COLUMNS)
    for row in rows:
        writer.writerow(["" if row[c] is None else row[c] for c in COLUMNS])
    return out.getvalue()


def _row(record: Any) -> dict[str, Any]:
    return {
        "printer": record.printer,
        "moonraker_job_id": record.moonraker_job_id,
        "filename": record.filename,
        "sha256": record.sha256,
        "job_id": record.job_id,
        "attempt_id": record.attempt_id,
        "status": record.status,
        "queued_at": iso(record.queued_at),
        "started_at": iso(record.start_time),
        "ended_at": iso(record.end_time),
        "cleared_at": iso(record.cleared_at),
        "verdict": record.verdict,
        "cause": record.cause or None,
        "print_seconds": round(record.print_duration, 1),
        "filament_mm": round(record.filament_used, 1),
        "filament_g": None if record.filament_g is None else round(record.filament_g, 2),
        "user": record.user,
    }


def iso(value: float | datetime | None) -> str | None:
    """A time as ISO-8601 UTC (``2026-03-01T10:00:00Z``); naive datetimes are UTC."""
    if value is None:
        return None
    moment = value if isinstance(value, datetime) else datetime.fromtimestamp(float(value), UTC)
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    return moment.astimezone(UTC).isoformat(timespec="seconds").replace("+00:00", "Z")
