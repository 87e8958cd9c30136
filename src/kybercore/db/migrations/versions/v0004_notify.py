"""Notifications: channels, the events sent to them, the outbox of deliveries, settings.

Revision ID: 0004_notify
Revises: 0003_audit
Create Date: 2026-11-24

``notify_deliveries`` is a persisted outbox: a row is written in the same transaction as
its event and stays ``pending`` until the receiver took it, so a restart loses nothing.
Deleting a channel deletes its deliveries (ON DELETE CASCADE); the events stay.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0004_notify"
down_revision = "0003_audit"
branch_labels = None
depends_on = None


def _when(name: str, *, nullable: bool = False) -> sa.Column[object]:
    return sa.Column(name, sa.DateTime(timezone=True), nullable=nullable)


def upgrade() -> None:
    """Create the notifications' tables."""
    op.create_table(
        "notify_channels",
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("name", sa.String(100), nullable=False),
        sa.Column("kind", sa.String(16), nullable=False),
        sa.Column("target", sa.Text, nullable=False),
        sa.Column("secret", sa.String(200), nullable=True),
        sa.Column("rules", sa.JSON, nullable=False),
        sa.Column("enabled", sa.Boolean, nullable=False),
        _when("created_at"),
        sa.Column("created_by", sa.String(200), nullable=False),
        _when("updated_at"),
        sa.Column("updated_by", sa.String(200), nullable=False),
        sa.CheckConstraint("kind IN ('webhook', 'apprise')", name="ck_notify_channels_kind"),
    )

    op.create_table(
        "notify_events",
        sa.Column("id", sa.String(32), primary_key=True),
        _when("at"),
        sa.Column("kind", sa.String(32), nullable=False),
        sa.Column("printer_id", sa.String(200), nullable=True),
        sa.Column("payload", sa.JSON, nullable=False),
        sa.Column("snapshot", sa.LargeBinary, nullable=True),
    )
    op.create_index("ix_notify_events_at", "notify_events", ["at"])

    op.create_table(
        "notify_deliveries",
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("event_id", sa.String(32), sa.ForeignKey("notify_events.id"), nullable=False),
        sa.Column(
            "channel_id",
            sa.Integer,
            sa.ForeignKey("notify_channels.id", ondelete="CASCADE"),
            nullable=False,
        ),
        sa.Column("printer_key", sa.String(200), nullable=False),
        sa.Column("status", sa.String(16), nullable=False),
        sa.Column("attempts", sa.Integer, nullable=False),
        _when("next_at", nullable=True),
        sa.Column("last_error", sa.Text, nullable=False),
        sa.Column("response_code", sa.Integer, nullable=True),
        _when("created_at"),
        _when("delivered_at", nullable=True),
        sa.CheckConstraint(
            "status IN ('pending', 'delivered', 'failed', 'quiet_hours')",
            name="ck_notify_deliveries_status",
        ),
        sa.CheckConstraint("attempts >= 0", name="ck_notify_deliveries_attempts"),
    )
    op.create_index(
        "ix_notify_deliveries_queue",
        "notify_deliveries",
        ["status", "channel_id", "printer_key", "id"],
    )
    op.create_index("ix_notify_deliveries_channel", "notify_deliveries", ["channel_id", "id"])
    op.create_index("ix_notify_deliveries_event", "notify_deliveries", ["event_id"])

    op.create_table(
        "notify_settings",
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("value", sa.JSON, nullable=False),
        _when("updated_at"),
        sa.CheckConstraint("id = 1", name="ck_notify_settings_one_row"),
    )


def downgrade() -> None:
    """Drop them (the channels, their secrets and the delivery log with them)."""
    op.drop_table("notify_settings")
    op.drop_table("notify_deliveries")
    op.drop_table("notify_events")
    op.drop_table("notify_channels")
