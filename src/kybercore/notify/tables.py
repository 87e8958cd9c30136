"""The notifications' tables, as SQLAlchemy Core: what migration ``0004_notify`` creates.

``notify_events`` keeps every event that was routed to at least one channel (its JSON, as
receivers get it, and the webcam snapshot until every delivery of it is settled);
``notify_deliveries`` is the outbox: one row per (event, channel), pending until the
receiver took it, retried with backoff, in order per (channel, printer). Deleting a channel
deletes its deliveries; the events stay as history.
"""

from __future__ import annotations

from typing import Final

from sqlalchemy import (
    JSON,
    Boolean,
    CheckConstraint,
    Column,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    MetaData,
    String,
    Table,
    Text,
)

from kybercore.db import UTCDateTime

metadata: Final = MetaData()

STATUSES: Final = ("pending", "delivered", "failed", "quiet_hours")
"""A delivery's states: ``pending`` until sent or given up; ``quiet_hours`` is recorded and
never sent."""

notify_channels: Final = Table(
    "notify_channels",
    metadata,
    Column("id", Integer, primary_key=True),
    Column("name", String(100), nullable=False),
    Column("kind", String(16), nullable=False),
    # An Apprise URL holds its service's token: like the secret, never shown whole.
    Column("target", Text, nullable=False),
    Column("secret", String(200), nullable=True),
    Column("rules", JSON, nullable=False),
    Column("enabled", Boolean, nullable=False),
    Column("created_at", UTCDateTime, nullable=False),
    Column("created_by", String(200), nullable=False),
    Column("updated_at", UTCDateTime, nullable=False),
    Column("updated_by", String(200), nullable=False),
    CheckConstraint("kind IN ('webhook', 'apprise')", name="ck_notify_channels_kind"),
)

notify_events: Final = Table(
    "notify_events",
    metadata,
    Column("id", String(32), primary_key=True),  # the event's uuid4 hex
    Column("at", UTCDateTime, nullable=False),
    Column("kind", String(32), nullable=False),
    Column("printer_id", String(200), nullable=True),
    Column("payload", JSON, nullable=False),
    Column("snapshot", LargeBinary, nullable=True),
    Index("ix_notify_events_at", "at"),
)

notify_deliveries: Final = Table(
    "notify_deliveries",
    metadata,
    Column("id", Integer, primary_key=True),
    Column("event_id", String(32), ForeignKey("notify_events.id"), nullable=False),
    Column(
        "channel_id",
        Integer,
        ForeignKey("notify_channels.id", ondelete="CASCADE"),
        nullable=False,
    ),
    # The printer's id, '' for a fleet-wide event: the outbox keeps order per (channel, key).
    Column("printer_key", String(200), nullable=False),
    Column("status", String(16), nullable=False),
    Column("attempts", Integer, nullable=False),
    # When a pending row is next due; while it is being sent, the end of the sender's lease.
    Column("next_at", UTCDateTime, nullable=True),
    Column("last_error", Text, nullable=False),
    Column("response_code", Integer, nullable=True),
    Column("created_at", UTCDateTime, nullable=False),
    Column("delivered_at", UTCDateTime, nullable=True),
    CheckConstraint(
        "status IN ('pending', 'delivered', 'failed', 'quiet_hours')",
        name="ck_notify_deliveries_status",
    ),
    CheckConstraint("attempts >= 0", name="ck_notify_deliveries_attempts"),
    # The outbox's question: the oldest pending row of each (channel, printer).
    Index("ix_notify_deliveries_queue", "status", "channel_id", "printer_key", "id"),
    Index("ix_notify_deliveries_channel", "channel_id", "id"),
    Index("ix_notify_deliveries_event", "event_id"),
)

notify_settings: Final = Table(
    "notify_settings",
    metadata,
    Column("id", Integer, primary_key=True),
    Column("value", JSON, nullable=False),
    Column("updated_at", UTCDateTime, nullable=False),
    CheckConstraint("id = 1", name="ck_notify_settings_one_row"),
)
