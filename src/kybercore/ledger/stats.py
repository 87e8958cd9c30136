"""Fleet statistics over a time window, computed by the database (SQLite or PostgreSQL).

Per group (a printer, a file, a material or a UTC day): jobs by outcome, success rate,
print hours, filament, failure causes from the plate-clear verdicts, and, per printer and
per day, utilisation from the state timeline.

- A job belongs to the window its start time falls in.
- ``success_rate`` = completed jobs not cleared ``bad`` ÷ finished jobs (every status but
  ``in_progress``); None when none finished.
- ``utilisation`` = printing time ÷ (observed time − maintenance − disabled), where the
  observed time is what the timeline covers of the window (the time KyberCore was not
  running is unknown, so it is left out rather than counted as idle). ``disabled`` is the
  offline-by-plan time: printers switched off in printers.json. None for files and
  materials, and when there is no time to divide by.
"""

from __future__ import annotations

import math
import time
from collections import Counter, defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any, Final, Literal

from sqlalchemy import (
    ColumnElement,
    Float,
    Select,
    String,
    and_,
    func,
    literal,
    or_,
    select,
    union_all,
)
from sqlalchemy.ext.asyncio import AsyncEngine
from sqlalchemy.ext.compiler import compiles
from sqlalchemy.sql.functions import GenericFunction

from kybercore.db import reading
from kybercore.errors import InvalidInput
from kybercore.jobs.tables import attempts, jobs
from kybercore.ledger.tables import history_jobs, printer_states

GroupBy = Literal["printer", "file", "material", "day"]
DAY: Final = 86400.0
MAX_DAYS: Final = 1000
"""A daily breakdown covers at most this many days (one row each)."""
UNKNOWN_MATERIAL: Final = "unknown"


@dataclass
class Group:
    """The statistics of one group, as ``GET /api/stats`` sends them."""

    key: str
    jobs: Counter[str] = field(default_factory=Counter)
    good: int = 0
    print_seconds: float = 0.0
    filament_mm: float = 0.0
    filament_g: float | None = None
    failure_causes: Counter[str] = field(default_factory=Counter)
    state_seconds: defaultdict[str, float] = field(default_factory=lambda: defaultdict(float))
    has_timeline: bool = False

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        finished = sum(n for status, n in self.jobs.items() if status != "in_progress")
        return {
            "key": self.key,
            "jobs": dict(self.jobs),
            "success_rate": round(self.good / finished, 4) if finished else None,
            "print_hours": round(self.print_seconds / 3600, 4),
            "utilisation": self._utilisation(),
            "filament_mm": round(self.filament_mm, 2),
            "filament_g": None if self.filament_g is None else round(self.filament_g, 2),
            "failure_causes": dict(self.failure_causes),
        }

    def _utilisation(self) -> float | None:
        if not self.has_timeline:
            return None
        seconds = self.state_seconds
        available = sum(seconds.values()) - seconds["maintenance"] - seconds["disabled"]
        return round(seconds["printing"] / available, 4) if available > 0 else None


def window(
    start: datetime | None, end: datetime | None, default_days: float = 30
) -> tuple[float, float]:
    """The window as epoch seconds: ``end`` defaults to now, ``start`` to 30 days before
    it. A time without a zone is UTC."""
    stop = epoch(end) if end is not None else time.time()
    begin = epoch(start) if start is not None else stop - default_days * DAY
    if begin >= stop:
        raise InvalidInput("'from' must be before 'to'. Swap them or widen the window.")
    return begin, stop


def epoch(moment: datetime) -> float:
    """Epoch seconds of ``moment``; a naive one is UTC (never the server's local time)."""
    return (moment if moment.tzinfo else moment.replace(tzinfo=UTC)).timestamp()


async def statistics(
    engine: AsyncEngine, group_by: GroupBy, begin: float, end: float, now: float | None = None
) -> list[dict[str, Any]]:
    """The rows of ``GET /api/stats`` for the window [``begin``, ``end``)."""
    now = time.time() if now is None else now
    days = _days(begin, end) if group_by == "day" else None
    timed = group_by in ("printer", "day")
    groups: dict[str, Group] = {key: Group(key, has_timeline=True) for key, _, _ in days or ()}

    def group(key: Any) -> Group:
        return groups.setdefault(str(key), Group(str(key), has_timeline=timed))

    async with reading(engine) as conn:
        for key, status, verdict, cause, n, seconds, mm, grams, weighed in await conn.execute(
            _jobs_query(group_by, begin, end, days)
        ):
            row = group(key)
            row.jobs[status] += n
            if status == "completed" and verdict != "bad":
                row.good += n
            row.print_seconds += seconds or 0.0
            row.filament_mm += mm or 0.0
            if weighed:
                row.filament_g = (row.filament_g or 0.0) + (grams or 0.0)
            if cause:
                row.failure_causes[str(cause)] += n
        if timed:
            query = _timeline_query(group_by, begin, end, min(now, end), days)
            for key, state, seconds in await conn.execute(query):
                group(key).state_seconds[state] += max(float(seconds or 0.0), 0.0)
    return [groups[key].as_dict() for key in sorted(groups)]


def _days(begin: float, end: float) -> list[tuple[str, float, float]]:
    """The UTC days the window touches: ``(YYYY-MM-DD, start, end)``, clipped to it."""
    first = int(begin // DAY)
    last = math.ceil(end / DAY) - 1  # a window ending at midnight ends the day before
    if last - first + 1 > MAX_DAYS:
        raise InvalidInput(
            f"A daily breakdown covers at most {MAX_DAYS} days. Narrow 'from' and 'to'."
        )
    return [
        (
            datetime.fromtimestamp(day * DAY, UTC).date().isoformat(),
            max(day * DAY, begin),
            min((day + 1) * DAY, end),
        )
        for day in range(first, last + 1)
    ]


def _days_table(days: Sequence[tuple[str, float, float]]) -> Any:
    """The days as a derived table ``(day, d0, d1)``: a UNION ALL of literal rows, which
    both databases read (SQLite does not name the columns of a VALUES list)."""
    rows = [
        select(
            literal(key, String).label("day"),
            literal(d0, Float).label("d0"),
            literal(d1, Float).label("d1"),
        )
        for key, d0, d1 in days
    ]
    return (rows[0] if len(rows) == 1 else union_all(*rows)).subquery("days")


def _jobs_query(
    group_by: GroupBy, begin: float, end: float, days: Sequence[tuple[str, float, float]] | None
) -> Select[Any]:
    h = history_jobs.c
    key: ColumnElement[Any]
    joined = history_jobs.outerjoin(attempts, attempts.c.id == h.attempt_id)
    where = [h.start_time >= literal(begin, Float), h.start_time < literal(end, Float)]
    if group_by == "printer":
        key = h.printer
    elif group_by == "material":
        key = func.coalesce(h.material, UNKNOWN_MATERIAL)
    elif group_by == "file":
        # A queued job's copies each have their own upload name: group them under the
        # job's file name.
        joined = joined.outerjoin(jobs, jobs.c.id == attempts.c.job_id)
        key = func.coalesce(jobs.c.file_name, h.filename)
    else:
        assert days is not None
        table = _days_table(days)
        joined = joined.join(table, and_(h.start_time >= table.c.d0, h.start_time < table.c.d1))
        key = table.c.day
    return (
        select(
            key.label("key"),
            h.status,
            attempts.c.verdict,
            attempts.c.cause,
            func.count(),
            func.sum(h.print_duration),
            func.sum(h.filament_used),
            func.sum(h.filament_g),
            func.count(h.filament_g),
        )
        .select_from(joined)
        .where(*where)
        .group_by(key, h.status, attempts.c.verdict, attempts.c.cause)
    )


def _timeline_query(
    group_by: GroupBy,
    begin: float,
    end: float,
    now: float,
    days: Sequence[tuple[str, float, float]] | None,
) -> Select[Any]:
    s = printer_states.c
    stop = func.coalesce(s.ended_at, literal(now, Float))
    if group_by == "printer":
        lo, hi = literal(begin, Float), literal(end, Float)
        overlap = least(stop, hi) - greatest(s.started_at, lo)
        return (
            select(s.printer, s.state, func.sum(overlap))
            .where(s.started_at < hi, or_(s.ended_at.is_(None), s.ended_at > lo))
            .group_by(s.printer, s.state)
        )
    assert days is not None
    table = _days_table(days)
    overlap = least(stop, table.c.d1) - greatest(s.started_at, table.c.d0)
    return (
        select(table.c.day, s.state, func.sum(overlap))
        .select_from(
            printer_states.join(
                table,
                and_(s.started_at < table.c.d1, or_(s.ended_at.is_(None), s.ended_at > table.c.d0)),
            )
        )
        .where(s.started_at < literal(now, Float))
        .group_by(table.c.day, s.state)
    )


# GREATEST/LEAST in PostgreSQL; SQLite spells them as its many-argument MAX/MIN.
class greatest(GenericFunction[float]):
    """The largest argument."""

    type = Float()
    inherit_cache = True


class least(GenericFunction[float]):
    """The smallest argument."""

    type = Float()
    inherit_cache = True


@compiles(greatest, "sqlite")
def _greatest_sqlite(element: greatest, compiler: Any, **kw: Any) -> str:
    return f"MAX({compiler.process(element.clauses, **kw)})"


@compiles(least, "sqlite")
def _least_sqlite(element: least, compiler: Any, **kw: Any) -> str:
    return f"MIN({compiler.process(element.clauses, **kw)})"
