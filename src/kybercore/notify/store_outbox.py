"""The store's outbox side: claiming due deliveries, and settling them after a send.

Each function is the body of one transaction; :class:`~kybercore.notify.store.NotifyStore`
runs it. Order per printer lives in :func:`is_head`: only the oldest pending delivery of a
(channel, printer) is ever due, so a printer's events reach a channel in the order they
happened, and one that keeps failing holds the later ones back until it is delivered or
given up.
"""

from __future__ import annotations

import logging
from datetime import datetime
from typing import Any

from sqlalchemy import and_, exists, func, select, update
from sqlalchemy.ext.asyncio import AsyncConnection

from kybercore.notify.records import DueDelivery, to_due
from kybercore.notify.tables import notify_channels, notify_deliveries, notify_events

log = logging.getLogger(__name__)

c = notify_channels.c
d = notify_deliveries.c
e = notify_events.c


def is_head() -> Any:
    """SQL: the delivery is the oldest pending one of its (channel, printer)."""
    older = notify_deliveries.alias("older")
    return ~exists().where(
        and_(
            older.c.status == "pending",
            older.c.channel_id == d.channel_id,
            older.c.printer_key == d.printer_key,
            older.c.id < d.id,
        )
    )


async def claim(
    conn: AsyncConnection, now: datetime, limit: int, lease_until: datetime
) -> list[DueDelivery]:
    """The deliveries due at ``now`` (pending, ``next_at`` passed, each the head of its
    line), claimed until ``lease_until``. One whose event this KyberCore cannot read (a
    newer one wrote it) is failed on the spot instead of blocking its line for ever."""
    query = (
        select(
            d.id,
            d.attempts,
            d.created_at,
            d.channel_id,
            c.kind,
            c.target,
            c.secret,
            c.rules,
            e.payload,
            e.snapshot.is_not(None).label("has_snapshot"),
        )
        .join(notify_channels, c.id == d.channel_id)
        .join(notify_events, e.id == d.event_id)
        .where(d.status == "pending", d.next_at <= now, is_head())
        .order_by(d.id)
        .limit(limit)
    )
    rows = list((await conn.execute(query)).mappings())
    if not rows:
        return []
    # Only rows still due are taken: another outbox may have claimed one meanwhile
    # (PostgreSQL re-checks the condition after waiting for its row lock).
    claimed = set(
        await conn.scalars(
            update(notify_deliveries)
            .where(d.id.in_([row["id"] for row in rows]), d.status == "pending", d.next_at <= now)
            .values(next_at=lease_until)
            .returning(d.id)
        )
    )
    due = []
    for row in rows:
        if row["id"] not in claimed:
            continue
        try:
            due.append(to_due(row))
        except (KeyError, TypeError, ValueError) as exc:
            log.warning("Notification delivery %d: unreadable, given up (%s)", row["id"], exc)
            await settle(
                conn, row["id"], status="failed", response_code=None,
                last_error=f"KyberCore cannot read this event or channel ({exc}).",
            )  # fmt: skip
    return due


async def next_due(conn: AsyncConnection) -> datetime | None:
    """When the next head of a line falls due (it may be past); None when none is pending."""
    when: datetime | None = await conn.scalar(
        select(func.min(d.next_at)).where(d.status == "pending", is_head())
    )
    return when


async def settle(conn: AsyncConnection, delivery_id: int, **values: Any) -> None:
    """Count an attempt and write its outcome (``status`` and the columns it sets) on a
    pending delivery; nothing if it is gone (its channel was deleted) or settled already.
    Once no delivery of its event may still send it, the event's snapshot is dropped."""
    if values["status"] != "pending":
        values["next_at"] = None
    event_id = await conn.scalar(
        update(notify_deliveries)
        .where(d.id == delivery_id, d.status == "pending")
        .values(attempts=d.attempts + 1, **values)
        .returning(d.event_id)
    )
    if event_id is None or values["status"] == "pending":
        return
    still = exists().where(d.event_id == event_id, d.status == "pending")
    await conn.execute(
        update(notify_events)
        .where(e.id == event_id, e.snapshot.is_not(None), ~still)
        .values(snapshot=None)
    )


async def release(conn: AsyncConnection, delivery_ids: list[int], now: datetime) -> None:
    """Hand claimed deliveries back unsent, due at ``now``."""
    await conn.execute(
        update(notify_deliveries)
        .where(d.id.in_(delivery_ids), d.status == "pending")
        .values(next_at=now)
    )
