"""The ledger: every printer's job history, and each printer's state intervals.

Revision ID: 0002_ledger
Revises: 0001
Create Date: 2026-11-23

``history_jobs`` holds one row per (printer, Moonraker instance, Moonraker job id): the
unique constraint is what makes replayed and double-fed history harmless. Times are epoch
seconds in double precision, as Moonraker gives them.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0002_ledger"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    """Create the ledger's tables."""
    op.create_table(
        "history_jobs",
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("printer", sa.String(64), nullable=False),
        sa.Column("instance", sa.String(64), nullable=False),
        sa.Column("moonraker_job_id", sa.String(16), nullable=False),
        sa.Column("filename", sa.Text, nullable=False),
        sa.Column("status", sa.String(32), nullable=False),
        sa.Column("moonraker_user", sa.String(100), nullable=False, server_default=""),
        sa.Column("start_time", sa.Double, nullable=False),
        sa.Column("end_time", sa.Double, nullable=True),
        sa.Column("print_duration", sa.Double, nullable=False, server_default="0"),
        sa.Column("total_duration", sa.Double, nullable=False, server_default="0"),
        sa.Column("filament_used", sa.Double, nullable=False, server_default="0"),
        sa.Column("filament_g", sa.Double, nullable=True),
        sa.Column("material", sa.String(64), nullable=True),
        sa.Column("file_meta", sa.JSON, nullable=True),
        sa.Column(
            "attempt_id",
            sa.Integer,
            sa.ForeignKey("attempts.id", ondelete="SET NULL"),
            nullable=True,
        ),
        sa.Column("updated_at", sa.Double, nullable=False),
        sa.UniqueConstraint("printer", "instance", "moonraker_job_id", name="uq_history_jobs_job"),
    )
    op.create_index("ix_history_jobs_start", "history_jobs", ["start_time"])
    op.create_index("ix_history_jobs_printer_start", "history_jobs", ["printer", "start_time"])
    op.create_index("ix_history_jobs_attempt", "history_jobs", ["attempt_id"])

    op.create_table(
        "printer_states",
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("printer", sa.String(64), nullable=False),
        sa.Column("state", sa.String(32), nullable=False),
        sa.Column("started_at", sa.Double, nullable=False),
        sa.Column("ended_at", sa.Double, nullable=True),
    )
    op.create_index("ix_printer_states_printer_open", "printer_states", ["printer", "ended_at"])
    op.create_index("ix_printer_states_started", "printer_states", ["started_at"])


def downgrade() -> None:
    """Drop them (the ledger's data with them)."""
    op.drop_table("printer_states")
    op.drop_table("history_jobs")
