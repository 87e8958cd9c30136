"""The fleet ledger over HTTP: ``/api/history`` (paged, filtered), ``/api/history.csv``
(every matching job) and ``/api/stats`` (aggregates per printer, file, material or day).

Everything is read from KyberCore's database: no request here reaches a printer.
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from datetime import datetime
from typing import Annotated, Any, Final, Literal

from fastapi import APIRouter, Depends, Query
from fastapi.responses import StreamingResponse
from pydantic import BaseModel, Field

from kybercore.api.deps import VIEWER, Database
from kybercore.api.models import ERROR_RESPONSES
from kybercore.ledger import records, stats

router = APIRouter()

CSV_NAME: Final = "kybercore-history.csv"


class HistoryRow(BaseModel):
    """One job a printer ran, joined with the queue attempt that sent it (if any).
    Times are ISO-8601 UTC."""

    printer: str
    moonraker_job_id: str
    filename: str
    sha256: str | None
    job_id: int | None
    attempt_id: int | None
    status: str
    queued_at: str | None
    started_at: str
    ended_at: str | None
    cleared_at: str | None
    verdict: str | None
    cause: str | None
    print_seconds: float
    filament_mm: float
    filament_g: float | None
    user: str | None


class HistoryPage(BaseModel):
    """``total`` jobs match; ``items`` is the page asked for, newest first."""

    total: int
    items: list[HistoryRow]


class StatsRow(BaseModel):
    """One group's figures over the window."""

    key: str
    jobs: dict[str, int]
    success_rate: float | None
    print_hours: float
    utilisation: float | None
    filament_mm: float
    filament_g: float | None
    failure_causes: dict[str, int]


class StatsAnswer(BaseModel):
    """Statistics per group; ``from``/``to`` is the window, ISO-8601 UTC."""

    group_by: str
    from_: str = Field(alias="from")
    to: str
    rows: list[StatsRow]


async def history_filter(
    printer: Annotated[str | None, Query(max_length=64)] = None,
    status: Annotated[str | None, Query(max_length=32)] = None,
    file: Annotated[str | None, Query(max_length=255, description="part of the name")] = None,
    user: Annotated[str | None, Query(max_length=100)] = None,
    start: Annotated[datetime | None, Query(alias="from")] = None,
    end: Annotated[datetime | None, Query(alias="to")] = None,
) -> records.HistoryFilter:
    """The filters ``/api/history`` and ``/api/history.csv`` share. A coroutine: FastAPI
    runs a class or plain-function dependency in its thread pool."""
    return records.HistoryFilter(
        printer=printer,
        status=status,
        file=file,
        user=user,
        start=None if start is None else stats.epoch(start),
        end=None if end is None else stats.epoch(end),
    )


Filters = Annotated[records.HistoryFilter, Depends(history_filter)]


@router.get(
    "/api/history", response_model=HistoryPage, responses=ERROR_RESPONSES, dependencies=[VIEWER]
)
async def history(
    database: Database,
    where: Filters,
    limit: Annotated[int, Query(ge=1, le=500)] = 50,
    offset: Annotated[int, Query(ge=0, le=10**9)] = 0,
) -> dict[str, Any]:
    """Jobs every printer ran, newest first, filtered by printer, status, file, user and
    start time (``from`` inclusive, ``to`` exclusive)."""
    total, items = await records.page(database, where, limit, offset)
    return {"total": total, "items": items}


@router.get(
    "/api/history.csv",
    responses={200: {"content": {"text/csv": {}}}, **ERROR_RESPONSES},
    response_class=StreamingResponse,
    dependencies=[VIEWER],
)
async def history_csv(database: Database, where: Filters) -> StreamingResponse:
    """Every matching job as CSV, one row per job, with a header row."""

    async def lines() -> AsyncIterator[str]:
        yield records.csv_text([], header=True)
        batch: list[dict[str, Any]] = []
        async for row in records.every_row(database, where):
            batch.append(row)
            if len(batch) == records.CSV_BATCH:
                yield records.csv_text(batch)
                batch = []
        yield records.csv_text(batch)

    return StreamingResponse(
        lines(),
        media_type="text/csv; charset=utf-8",
        headers={"Content-Disposition": f'attachment; filename="{CSV_NAME}"'},
    )


@router.get(
    "/api/stats", response_model=StatsAnswer, responses=ERROR_RESPONSES, dependencies=[VIEWER]
)
async def statistics(
    database: Database,
    group_by: Literal["printer", "file", "material", "day"] = "printer",
    start: Annotated[datetime | None, Query(alias="from")] = None,
    end: Annotated[datetime | None, Query(alias="to")] = None,
) -> dict[str, Any]:
    """Jobs by outcome, success rate, print hours, utilisation, filament and failure causes
    per printer, file, material or UTC day, over ``from``..``to`` (default: the last 30
    days). Utilisation is printing time over observed time less maintenance and disabled
    printers; null for files and materials."""
    begin, stop = stats.window(start, end)
    rows = await stats.statistics(database, group_by, begin, stop)
    return {
        "group_by": group_by,
        "from": records.iso(begin),
        "to": records.iso(stop),
        "rows": rows,
    }
