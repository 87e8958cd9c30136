"""The job queue's tables, as SQLAlchemy Core sees them, and rows turned into models.

The schema's history is ``kybercore/db/migrations/versions``; these definitions must say
the same thing (``tests/db/test_migrations.py`` compares them with a migrated database).
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from typing import Any, Final, cast

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    CheckConstraint,
    Column,
    Double,
    ForeignKey,
    Index,
    Integer,
    MetaData,
    RowMapping,
    Select,
    String,
    Table,
    Text,
    func,
    select,
    text,
)

from kybercore.db import UTCDateTime
from kybercore.jobs.models import (
    LIVE,
    Attempt,
    AttemptState,
    Gate,
    GateState,
    Job,
    JobFile,
    JobState,
    PlateVerdict,
    Requirements,
)

metadata = MetaData()

_LIVE_SQL: Final = "state IN ({})".format(", ".join(f"'{s}'" for s in sorted(LIVE)))
# A copy is taken while an attempt of it is live, completed and waiting for its verdict,
# or cleared good (done); a bad verdict or a failure frees it.
_HOLDS_COPY_SQL: Final = (
    f"{_LIVE_SQL} OR (state = 'completed' AND (verdict IS NULL OR verdict = 'good'))"
)

jobs = Table(
    "jobs",
    metadata,
    Column("id", Integer, primary_key=True),
    Column("file_sha256", String(64), nullable=False),
    Column("file_name", String(255), nullable=False),
    Column("file_size", BigInteger, nullable=False),
    Column("file_meta", JSON, nullable=False),
    Column("quantity", Integer, nullable=False),
    Column("priority", Integer, nullable=False),
    Column("position", Double, nullable=False),
    Column("not_before", UTCDateTime, nullable=True),
    Column("requirements", JSON, nullable=False),
    Column("allow_mismatch", Boolean, nullable=False),
    Column("max_attempts", Integer, nullable=False),
    Column("state", String(16), nullable=False),
    Column("reason", Text, nullable=False),
    Column("done", Integer, nullable=False),
    Column("in_flight", Integer, nullable=False),
    Column("failures", Integer, nullable=False),
    Column("created_at", UTCDateTime, nullable=False),
    Column("created_by", String(200), nullable=False),
    CheckConstraint("state IN ('queued', 'blocked', 'done', 'cancelled')", name="ck_jobs_state"),
    CheckConstraint("quantity >= 1 AND max_attempts >= 1", name="ck_jobs_limits"),
    CheckConstraint(
        "done >= 0 AND in_flight >= 0 AND failures >= 0 AND done + in_flight <= quantity",
        name="ck_jobs_counters",
    ),
    Index("ix_jobs_state", "state"),
)

attempts = Table(
    "attempts",
    metadata,
    Column("id", Integer, primary_key=True),
    Column("job_id", Integer, ForeignKey("jobs.id"), nullable=False),
    Column("copy", Integer, nullable=False),
    Column("printer", String(200), nullable=False),
    Column("upload_name", String(300), nullable=False, unique=True),
    Column("state", String(16), nullable=False),
    Column("reason", Text, nullable=False),
    Column("moonraker_job_id", String(64), nullable=True),
    Column("verdict", String(8), nullable=True),
    Column("cause", Text, nullable=False),
    Column("by_user", String(200), nullable=False),
    Column("created_at", UTCDateTime, nullable=False),
    Column("started_at", UTCDateTime, nullable=True),
    Column("ended_at", UTCDateTime, nullable=True),
    Column("print_seconds", Double, nullable=False),
    CheckConstraint(
        "state IN ('pending', 'uploading', 'starting', 'printing', 'paused', "
        "'completed', 'failed', 'cancelled', 'failed_to_start')",
        name="ck_attempts_state",
    ),
    CheckConstraint("verdict IS NULL OR verdict IN ('good', 'bad')", name="ck_verdict"),
    CheckConstraint("copy >= 1", name="ck_attempts_copy"),
    Index("ix_attempts_job", "job_id"),
    Index("ix_attempts_printer", "printer"),
    # The last line under the store's conditional updates: one live attempt per printer,
    # one holder per copy, whatever races above.
    Index(
        "ux_attempts_live_printer",
        "printer",
        unique=True,
        sqlite_where=text(_LIVE_SQL),
        postgresql_where=text(_LIVE_SQL),
    ),
    Index(
        "ux_attempts_copy_holder",
        "job_id",
        "copy",
        unique=True,
        sqlite_where=text(_HOLDS_COPY_SQL),
        postgresql_where=text(_HOLDS_COPY_SQL),
    ),
)

gates = Table(
    "gates",
    metadata,
    Column("printer", String(200), primary_key=True),
    Column("state", String(16), nullable=False),
    Column("reason", Text, nullable=False),
    Column("since", UTCDateTime, nullable=False),
    Column("attempt_id", Integer, ForeignKey("attempts.id"), nullable=True, unique=True),
    Column("by_user", String(200), nullable=False),
    CheckConstraint(
        "state IN ('available', 'awaiting_clear', 'held', 'maintenance')", name="ck_gates_state"
    ),
)

queue_events = Table(
    "queue_events",
    metadata,
    Column("id", Integer, primary_key=True),
    Column("at", UTCDateTime, nullable=False),
    Column("kind", String(40), nullable=False),
    Column("job_id", Integer, ForeignKey("jobs.id"), nullable=True),
    Column("attempt_id", Integer, ForeignKey("attempts.id"), nullable=True),
    Column("printer", String(200), nullable=True),
    Column("by_user", String(200), nullable=False),
    Column("message", Text, nullable=False),
    Index("ix_queue_events_job", "job_id"),
)

settings = Table(
    "settings",
    metadata,
    Column("key", String(100), primary_key=True),
    Column("value", JSON, nullable=False),
    Column("updated_at", UTCDateTime, nullable=False),
    Column("by_user", String(200), nullable=False),
)


@dataclass(frozen=True)
class QueueEvent:
    """One entry of the queue's own history: who did what to which job, attempt, printer."""

    id: int
    at: datetime
    kind: str
    """``job_created``, ``attempt_reserved``, ``attempt_printing``, ``gate_cleared``…"""
    job_id: int | None
    attempt_id: int | None
    printer: str | None
    user: str
    message: str


def requirements_json(requirements: Requirements) -> dict[str, Any]:
    """``requirements`` as stored (JSON)."""
    return {
        "material": requirements.material,
        "nozzle": requirements.nozzle,
        "model": requirements.model,
        "tags": list(requirements.tags),
        "printer": requirements.printer,
    }


def select_jobs() -> Select[Any]:
    """``jobs`` rows with what :func:`to_job` also reads: how many of each job's copies
    were printed and wait for their plate's verdict (an attempt ``completed``, no
    verdict), counted from the attempts rather than kept beside ``in_flight``."""
    a = attempts.c
    printed = (
        select(func.count())
        .where(a.job_id == jobs.c.id, a.state == "completed", a.verdict.is_(None))
        .scalar_subquery()
    )
    return select(jobs, printed.label("awaiting_clear"))


def to_job(row: RowMapping) -> Job:
    """A row of :func:`select_jobs` as a :class:`Job`."""
    wanted = row["requirements"]
    return Job(
        id=row["id"],
        file=JobFile(
            sha256=row["file_sha256"],
            name=row["file_name"],
            size=row["file_size"],
            meta=row["file_meta"],
        ),
        quantity=row["quantity"],
        priority=row["priority"],
        position=row["position"],
        not_before=row["not_before"],
        requirements=Requirements(
            material=wanted.get("material"),
            nozzle=wanted.get("nozzle"),
            model=wanted.get("model"),
            tags=tuple(wanted.get("tags", ())),
            printer=wanted.get("printer"),
        ),
        allow_mismatch=row["allow_mismatch"],
        max_attempts=row["max_attempts"],
        state=cast(JobState, row["state"]),
        reason=row["reason"],
        done=row["done"],
        in_flight=row["in_flight"],
        awaiting_clear=row["awaiting_clear"],
        failures=row["failures"],
        created_at=row["created_at"],
        created_by=row["created_by"],
    )


def to_attempt(row: RowMapping) -> Attempt:
    """An ``attempts`` row as an :class:`Attempt`."""
    return Attempt(
        id=row["id"],
        job_id=row["job_id"],
        copy=row["copy"],
        printer=row["printer"],
        upload_name=row["upload_name"],
        state=cast(AttemptState, row["state"]),
        reason=row["reason"],
        moonraker_job_id=row["moonraker_job_id"],
        verdict=cast(PlateVerdict | None, row["verdict"]),
        cause=row["cause"],
        user=row["by_user"],
        created_at=row["created_at"],
        started_at=row["started_at"],
        ended_at=row["ended_at"],
        print_seconds=row["print_seconds"],
    )


def to_gate(row: RowMapping) -> Gate:
    """A ``gates`` row as a :class:`Gate`."""
    return Gate(
        printer=row["printer"],
        state=cast(GateState, row["state"]),
        reason=row["reason"],
        since=row["since"],
        attempt_id=row["attempt_id"],
        user=row["by_user"],
    )


def to_event(row: RowMapping) -> QueueEvent:
    """A ``queue_events`` row as a :class:`QueueEvent`."""
    return QueueEvent(
        id=row["id"],
        at=row["at"],
        kind=row["kind"],
        job_id=row["job_id"],
        attempt_id=row["attempt_id"],
        printer=row["printer"],
        user=row["by_user"],
        message=row["message"],
    )
