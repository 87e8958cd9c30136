"""The job queue: jobs, their attempts, printer gates, the queue's history and settings.

Revision ID: 0001
Revises:
Create Date: 2026-11-23

The two partial unique indexes on ``attempts`` are the last line of the queue's promises,
whatever a bug or a race in the code above does: at most one live attempt per printer, and
at most one attempt holding each copy of a job (live, completed and awaiting its verdict,
or cleared good).
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None

_LIVE = "state IN ('pending', 'uploading', 'starting', 'printing', 'paused')"
_HOLDS_COPY = f"{_LIVE} OR (state = 'completed' AND (verdict IS NULL OR verdict = 'good'))"


def _when(time: str, *, nullable: bool = False) -> sa.Column[object]:
    return sa.Column(time, sa.DateTime(timezone=True), nullable=nullable)


def upgrade() -> None:
    """Create the queue's tables."""
    op.create_table(
        "jobs",
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("file_sha256", sa.String(64), nullable=False),
        sa.Column("file_name", sa.String(255), nullable=False),
        sa.Column("file_size", sa.BigInteger, nullable=False),
        sa.Column("file_meta", sa.JSON, nullable=False),
        sa.Column("quantity", sa.Integer, nullable=False),
        sa.Column("priority", sa.Integer, nullable=False),
        sa.Column("position", sa.Double, nullable=False),
        _when("not_before", nullable=True),
        sa.Column("requirements", sa.JSON, nullable=False),
        sa.Column("allow_mismatch", sa.Boolean, nullable=False),
        sa.Column("max_attempts", sa.Integer, nullable=False),
        sa.Column("state", sa.String(16), nullable=False),
        sa.Column("reason", sa.Text, nullable=False),
        sa.Column("done", sa.Integer, nullable=False),
        sa.Column("in_flight", sa.Integer, nullable=False),
        sa.Column("failures", sa.Integer, nullable=False),
        _when("created_at"),
        sa.Column("created_by", sa.String(200), nullable=False),
        sa.CheckConstraint(
            "state IN ('queued', 'blocked', 'done', 'cancelled')", name="ck_jobs_state"
        ),
        sa.CheckConstraint("quantity >= 1 AND max_attempts >= 1", name="ck_jobs_limits"),
        sa.CheckConstraint(
            "done >= 0 AND in_flight >= 0 AND failures >= 0 AND done + in_flight <= quantity",
            name="ck_jobs_counters",
        ),
    )
    op.create_index("ix_jobs_state", "jobs", ["state"])

    op.create_table(
        "attempts",
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("job_id", sa.Integer, sa.ForeignKey("jobs.id"), nullable=False),
        sa.Column("copy", sa.Integer, nullable=False),
        sa.Column("printer", sa.String(200), nullable=False),
        sa.Column("upload_name", sa.String(300), nullable=False, unique=True),
        sa.Column("state", sa.String(16), nullable=False),
        sa.Column("reason", sa.Text, nullable=False),
        sa.Column("moonraker_job_id", sa.String(64), nullable=True),
        sa.Column("verdict", sa.String(8), nullable=True),
        sa.Column("cause", sa.Text, nullable=False),
        sa.Column("by_user", sa.String(200), nullable=False),
        _when("created_at"),
        _when("started_at", nullable=True),
        _when("ended_at", nullable=True),
        sa.Column("print_seconds", sa.Double, nullable=False),
        sa.CheckConstraint(
            "state IN ('pending', 'uploading', 'starting', 'printing', 'paused', "
            "'completed', 'failed', 'cancelled', 'failed_to_start')",
            name="ck_attempts_state",
        ),
        sa.CheckConstraint("verdict IS NULL OR verdict IN ('good', 'bad')", name="ck_verdict"),
        sa.CheckConstraint("copy >= 1", name="ck_attempts_copy"),
    )
    op.create_index("ix_attempts_job", "attempts", ["job_id"])
    op.create_index("ix_attempts_printer", "attempts", ["printer"])
    op.create_index(
        "ux_attempts_live_printer",
        "attempts",
        ["printer"],
        unique=True,
        sqlite_where=sa.text(_LIVE),
        postgresql_where=sa.text(_LIVE),
    )
    op.create_index(
        "ux_attempts_copy_holder",
        "attempts",
        ["job_id", "copy"],
        unique=True,
        sqlite_where=sa.text(_HOLDS_COPY),
        postgresql_where=sa.text(_HOLDS_COPY),
    )

    op.create_table(
        "gates",
        sa.Column("printer", sa.String(200), primary_key=True),
        sa.Column("state", sa.String(16), nullable=False),
        sa.Column("reason", sa.Text, nullable=False),
        _when("since"),
        sa.Column(
            "attempt_id", sa.Integer, sa.ForeignKey("attempts.id"), nullable=True, unique=True
        ),
        sa.Column("by_user", sa.String(200), nullable=False),
        sa.CheckConstraint(
            "state IN ('available', 'awaiting_clear', 'held', 'maintenance')",
            name="ck_gates_state",
        ),
    )

    op.create_table(
        "queue_events",
        sa.Column("id", sa.Integer, primary_key=True),
        _when("at"),
        sa.Column("kind", sa.String(40), nullable=False),
        sa.Column("job_id", sa.Integer, sa.ForeignKey("jobs.id"), nullable=True),
        sa.Column("attempt_id", sa.Integer, sa.ForeignKey("attempts.id"), nullable=True),
        sa.Column("printer", sa.String(200), nullable=True),
        sa.Column("by_user", sa.String(200), nullable=False),
        sa.Column("message", sa.Text, nullable=False),
    )
    op.create_index("ix_queue_events_job", "queue_events", ["job_id"])

    op.create_table(
        "settings",
        sa.Column("key", sa.String(100), primary_key=True),
        sa.Column("value", sa.JSON, nullable=False),
        _when("updated_at"),
        sa.Column("by_user", sa.String(200), nullable=False),
    )


def downgrade() -> None:
    """Drop them (the queue's data with them)."""
    for table in ("settings", "queue_events", "gates", "attempts", "jobs"):
        op.drop_table(table)
