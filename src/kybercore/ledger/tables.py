"""The ledger's tables, as SQLAlchemy Core: what migration ``0002_ledger`` creates.

Times are epoch seconds (UTC) in double precision, as Moonraker gives them: the same
arithmetic (durations, overlaps, day buckets) then runs unchanged on SQLite and PostgreSQL.
The queue's own tables (:mod:`kybercore.jobs.tables`) the ledger only reads: a job's
attempt, file and verdict, the printers' gates, the queue's depth.
"""

from __future__ import annotations

from typing import Final

from sqlalchemy import (
    JSON,
    Column,
    Double,
    ForeignKey,
    Index,
    Integer,
    MetaData,
    String,
    Table,
    Text,
    UniqueConstraint,
)

from kybercore.jobs.tables import attempts

metadata: Final = MetaData()

history_jobs: Final = Table(
    "history_jobs",
    metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("printer", String(64), nullable=False),
    # Which Moonraker database the job id belongs to (see history.read_instance).
    Column("instance", String(64), nullable=False),
    Column("moonraker_job_id", String(16), nullable=False),
    Column("filename", Text, nullable=False),
    Column("status", String(32), nullable=False),
    Column("moonraker_user", String(100), nullable=False, server_default=""),
    Column("start_time", Double, nullable=False),
    Column("end_time", Double, nullable=True),
    Column("print_duration", Double, nullable=False, server_default="0"),
    Column("total_duration", Double, nullable=False, server_default="0"),
    # Millimetres of filament as Moonraker measured them; grams when the file's metadata
    # says what its filament weighs.
    Column("filament_used", Double, nullable=False, server_default="0"),
    Column("filament_g", Double, nullable=True),
    Column("material", String(64), nullable=True),
    Column("file_meta", JSON, nullable=True),
    # The queue attempt that printed it (its upload name is the file name), if any.
    Column(
        "attempt_id",
        Integer,
        ForeignKey(attempts.c.id, ondelete="SET NULL"),
        nullable=True,
    ),
    Column("updated_at", Double, nullable=False),
    UniqueConstraint("printer", "instance", "moonraker_job_id", name="uq_history_jobs_job"),
    Index("ix_history_jobs_start", "start_time"),
    Index("ix_history_jobs_printer_start", "printer", "start_time"),
    Index("ix_history_jobs_attempt", "attempt_id"),
)

printer_states: Final = Table(
    "printer_states",
    metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("printer", String(64), nullable=False),
    Column("state", String(32), nullable=False),
    Column("started_at", Double, nullable=False),
    Column("ended_at", Double, nullable=True),  # NULL while open: the current state
    Index("ix_printer_states_printer_open", "printer", "ended_at"),
    Index("ix_printer_states_started", "started_at"),
)
