"""Notifications in the database: channels, recorded events and their outbox, settings.

An event and its deliveries are written in one transaction (:meth:`NotifyStore.record`), so
what was decided is never half-kept; the outbox (:mod:`kybercore.notify.outbox`) then sends
every ``pending`` delivery, and survives restarts because its queue is these rows.

Order per printer: :meth:`NotifyStore.due` hands out only the oldest pending delivery of each
(channel, printer), so a printer's events reach a channel in the order they happened, and a
delivery that keeps failing holds the later ones of its printer back until it is delivered
or given up (``failed``). Each row handed out is claimed for a lease (its ``next_at`` moved
past the send's longest time): no other outbox, in this process or another one on the same
database, sends it meanwhile; one that died mid-send leaves it to be sent again when the
lease ends (receivers dedupe on the event id).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from datetime import UTC, datetime, timedelta
from typing import Any, Final

from sqlalchemy import Select, select, update
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.ext.asyncio import AsyncConnection, AsyncEngine

from kybercore.db import transaction
from kybercore.errors import ChannelNotFound, FileNotFound
from kybercore.notify.models import FleetEvent, NoiseSettings
from kybercore.notify.records import (
    Channel,
    ChannelKind,
    Delivery,
    DueDelivery,
    settings_from,
    to_channel,
    to_delivery,
)
from kybercore.notify.rules import ChannelRules, Route
from kybercore.notify.store_outbox import claim, next_due, release, settle
from kybercore.notify.tables import (
    notify_channels,
    notify_deliveries,
    notify_events,
    notify_settings,
)

LEASE: Final = 120.0
"""Seconds a claimed delivery stays the claimer's: longer than any one send may take."""
_CHANGEABLE: Final = frozenset({"name", "target", "secret", "rules", "enabled"})

c = notify_channels.c
d = notify_deliveries.c
e = notify_events.c


def _now() -> datetime:
    return datetime.now(UTC)


class NotifyStore:
    """The notifications' tables on one engine (SQLite or PostgreSQL)."""

    def __init__(self, engine: AsyncEngine, *, lease: float = LEASE) -> None:
        self._engine = engine
        self._lease = timedelta(seconds=lease)

    # -- channels ----------------------------------------------------------------------

    async def channels(self) -> list[Channel]:
        """Every channel, oldest first."""

        async def read(conn: AsyncConnection) -> list[Channel]:
            rows = await conn.execute(select(notify_channels).order_by(c.id))
            return [to_channel(row) for row in rows.mappings()]

        return await transaction(self._engine, read, write=False)

    async def channel(self, channel_id: int) -> Channel:
        """One channel; :class:`ChannelNotFound` when there is none."""

        async def read(conn: AsyncConnection) -> Channel:
            return await _channel(conn, channel_id)

        return await transaction(self._engine, read, write=False)

    async def secret(self, channel_id: int) -> str | None:
        """The channel's webhook secret (None without one); :class:`ChannelNotFound`."""

        async def read(conn: AsyncConnection) -> str | None:
            row = (await conn.execute(select(c.secret).where(c.id == channel_id))).first()
            if row is None:
                raise ChannelNotFound(channel_id)
            secret: str | None = row.secret
            return secret

        return await transaction(self._engine, read, write=False)

    async def add_channel(
        self,
        *,
        name: str,
        kind: ChannelKind,
        target: str,
        secret: str | None,
        rules: ChannelRules,
        enabled: bool,
        user: str,
    ) -> Channel:
        """Create a channel. The caller has validated the target and the rules."""

        async def insert(conn: AsyncConnection) -> Channel:
            now = _now()
            channel_id = await conn.scalar(
                notify_channels.insert()
                .values(
                    name=name,
                    kind=kind,
                    target=target,
                    secret=secret or None,
                    rules=rules.to_json(),
                    enabled=enabled,
                    created_at=now,
                    created_by=user,
                    updated_at=now,
                    updated_by=user,
                )
                .returning(c.id)
            )
            assert channel_id is not None
            return await _channel(conn, channel_id)

        return await transaction(self._engine, insert)

    async def update_channel(self, channel_id: int, *, user: str, **changes: Any) -> Channel:
        """Change a channel's ``name``, ``target``, ``secret`` (None or "" removes it),
        ``rules`` or ``enabled``; what is not given stays. :class:`ChannelNotFound`."""
        unknown = set(changes) - _CHANGEABLE
        if unknown:
            raise TypeError(f"a channel has no changeable {', '.join(sorted(unknown))}")
        values = dict(changes)
        if "rules" in values:
            values["rules"] = values["rules"].to_json()
        if "secret" in values:
            values["secret"] = values["secret"] or None

        async def change(conn: AsyncConnection) -> Channel:
            done = await conn.execute(
                update(notify_channels)
                .where(c.id == channel_id)
                .values(**values, updated_at=_now(), updated_by=user)
            )
            if done.rowcount == 0:
                raise ChannelNotFound(channel_id)
            return await _channel(conn, channel_id)

        return await transaction(self._engine, change)

    async def remove_channel(self, channel_id: int) -> None:
        """Delete a channel and its deliveries (its events stay); :class:`ChannelNotFound`."""

        async def remove(conn: AsyncConnection) -> None:
            done = await conn.execute(notify_channels.delete().where(c.id == channel_id))
            if done.rowcount == 0:
                raise ChannelNotFound(channel_id)

        await transaction(self._engine, remove)

    # -- events and the delivery log ---------------------------------------------------

    async def record(
        self, event: FleetEvent, snapshot: bytes | None, routes: Mapping[int, Route]
    ) -> list[int]:
        """Write ``event`` and, in the same transaction, one delivery per channel it was
        routed to: ``pending`` for "deliver", ``quiet_hours`` (kept, never sent) for
        "quiet_hours"; "skip" and channels deleted meanwhile get none. Returns the pending
        deliveries' ids, for the outbox. An event with no delivery is not kept; one
        recorded before is not recorded again."""
        wanted = {cid: route for cid, route in routes.items() if route != "skip"}
        if not wanted:
            return []

        async def write(conn: AsyncConnection) -> list[int]:
            if await conn.scalar(select(e.id).where(e.id == event.id)) is not None:
                return []
            existing = await conn.scalars(select(c.id).where(c.id.in_(sorted(wanted))))
            channels = sorted(existing)
            if not channels:
                return []
            sending = [cid for cid in channels if wanted[cid] == "deliver"]
            now = _now()
            await conn.execute(
                notify_events.insert().values(
                    id=event.id,
                    at=event.at,
                    kind=event.kind,
                    printer_id=event.printer.id if event.printer else None,
                    payload=event.to_json(),
                    # Kept only while a delivery may still send it.
                    snapshot=snapshot if sending else None,
                )
            )
            pending: list[int] = []
            for cid in channels:
                send = wanted[cid] == "deliver"
                delivery_id = await conn.scalar(
                    notify_deliveries.insert()
                    .values(
                        event_id=event.id,
                        channel_id=cid,
                        printer_key=event.printer.id if event.printer else "",
                        status="pending" if send else "quiet_hours",
                        attempts=0,
                        next_at=now if send else None,
                        last_error="",
                        response_code=None,
                        created_at=now,
                        delivered_at=None,
                    )
                    .returning(d.id)
                )
                if send and delivery_id is not None:
                    pending.append(delivery_id)
            return pending

        return await transaction(self._engine, write)

    async def deliveries(self, channel_id: int | None = None, limit: int = 100) -> list[Delivery]:
        """The newest deliveries first, of one channel or of all."""

        async def read(conn: AsyncConnection) -> list[Delivery]:
            query = _delivery_query().order_by(d.id.desc()).limit(limit)
            if channel_id is not None:
                query = query.where(d.channel_id == channel_id)
            return [to_delivery(row) for row in (await conn.execute(query)).mappings()]

        return await transaction(self._engine, read, write=False)

    async def delivery(self, delivery_id: int) -> Delivery:
        """One delivery; :class:`~kybercore.errors.FileNotFound` when there is none."""

        async def read(conn: AsyncConnection) -> Delivery:
            rows = await conn.execute(_delivery_query().where(d.id == delivery_id))
            found = rows.mappings().first()
            if found is None:
                raise FileNotFound(f"No notification delivery with id {delivery_id}.")
            return to_delivery(found)

        return await transaction(self._engine, read, write=False)

    # -- settings ----------------------------------------------------------------------

    async def settings(self) -> NoiseSettings:
        """The noise settings saved last, or the defaults."""

        async def read(conn: AsyncConnection) -> NoiseSettings:
            value = await conn.scalar(select(notify_settings.c.value))
            return NoiseSettings() if value is None else settings_from(value)

        return await transaction(self._engine, read, write=False)

    async def save_settings(self, settings: NoiseSettings) -> None:
        """Keep ``settings`` (the one settings row)."""
        values = {"value": dataclasses.asdict(settings), "updated_at": _now()}

        async def write(conn: AsyncConnection) -> None:
            dialect = postgresql if conn.dialect.name == "postgresql" else sqlite
            await conn.execute(
                dialect.insert(notify_settings)
                .values(id=1, **values)
                .on_conflict_do_update(index_elements=["id"], set_=values)
            )

        await transaction(self._engine, write)

    # -- the outbox's side ------------------------------------------------------------

    async def due(self, now: datetime, limit: int = 50) -> list[DueDelivery]:
        """Claim and return the deliveries to send now: pending, due by ``now``, and each the
        oldest pending one of its (channel, printer). Claimed rows are not due again until
        they are marked, or their lease ends."""
        until = now + self._lease
        return await transaction(self._engine, lambda conn: claim(conn, now, limit, until))

    async def next_due(self) -> datetime | None:
        """When the next delivery falls due (it may be past), or None when none is pending."""
        return await transaction(self._engine, next_due, write=False)

    async def snapshot(self, event_id: str) -> bytes | None:
        """The webcam snapshot kept with an event (None once every delivery is settled)."""

        async def read(conn: AsyncConnection) -> bytes | None:
            image: bytes | None = await conn.scalar(select(e.snapshot).where(e.id == event_id))
            return image

        return await transaction(self._engine, read, write=False)

    async def mark_delivered(self, delivery_id: int, code: int | None) -> None:
        """The receiver took it (the last error is kept, for the log)."""
        await self._settle(delivery_id, status="delivered", response_code=code, delivered_at=_now())

    async def mark_retry(
        self, delivery_id: int, error: str, code: int | None, next_at: datetime
    ) -> None:
        """This attempt failed; try again at ``next_at``."""
        await self._settle(
            delivery_id, status="pending", last_error=error, response_code=code, next_at=next_at
        )

    async def mark_failed(self, delivery_id: int, error: str, code: int | None) -> None:
        """Given up: it will not be sent, and no longer holds its printer's later ones."""
        await self._settle(delivery_id, status="failed", last_error=error, response_code=code)

    async def release(self, delivery_ids: list[int]) -> None:
        """Hand claimed deliveries back unsent, due now (an outbox stopping mid-send)."""
        if delivery_ids:
            now = _now()
            await transaction(self._engine, lambda conn: release(conn, delivery_ids, now))

    async def _settle(self, delivery_id: int, **values: Any) -> None:
        await transaction(self._engine, lambda conn: settle(conn, delivery_id, **values))


async def _channel(conn: AsyncConnection, channel_id: int) -> Channel:
    row = (await conn.execute(select(notify_channels).where(c.id == channel_id))).mappings()
    found = row.first()
    if found is None:
        raise ChannelNotFound(channel_id)
    return to_channel(found)


def _delivery_query() -> Select[Any]:
    return (
        select(
            notify_deliveries,
            c.name.label("channel_name"),
            c.rules,
            e.kind,
            e.printer_id,
            e.payload,
        )
        .join(notify_channels, c.id == d.channel_id)
        .join(notify_events, e.id == d.event_id)
    )
