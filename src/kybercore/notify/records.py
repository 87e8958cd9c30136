"""What the notification store hands out: channels, deliveries and the outbox's due rows.

A channel's secret never leaves the store in these: :class:`Channel` says only whether
there is one, and :meth:`Channel.public` masks the target too (an Apprise URL carries its
service's token; a webhook URL may carry a password or a token in its query).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any, Final, Literal, cast
from urllib.parse import urlsplit, urlunsplit

from sqlalchemy import RowMapping

from kybercore.notify.models import EventKind, FleetEvent, NoiseSettings
from kybercore.notify.rules import ChannelRules
from kybercore.notify.texts import render

ChannelKind = Literal["webhook", "apprise"]
CHANNEL_KINDS: Final[tuple[ChannelKind, ...]] = ("webhook", "apprise")
DeliveryStatus = Literal["pending", "delivered", "failed", "quiet_hours"]
_SHOWN_TAIL: Final = 4
"""Characters of an Apprise URL shown at its end: enough to tell two channels apart."""


@dataclass(frozen=True, slots=True)
class Channel:
    """A place notifications go: a webhook URL or an Apprise URL, and its rules."""

    id: int
    name: str
    kind: ChannelKind
    target: str
    has_secret: bool
    rules: ChannelRules
    enabled: bool
    created_at: datetime
    created_by: str
    updated_at: datetime
    updated_by: str

    def public(self) -> dict[str, Any]:
        """The channel as the API shows it: target masked, never the secret."""
        return {
            "id": self.id,
            "name": self.name,
            "kind": self.kind,
            "target": mask_target(self.kind, self.target),
            "has_secret": self.has_secret,
            "rules": self.rules.to_json(),
            "enabled": self.enabled,
            "created_at": iso(self.created_at),
            "created_by": self.created_by,
            "updated_at": iso(self.updated_at),
            "updated_by": self.updated_by,
        }


@dataclass(frozen=True, slots=True)
class Delivery:
    """One event for one channel, and how sending it went."""

    id: int
    event_id: str
    channel_id: int
    channel_name: str
    kind: EventKind
    printer_id: str | None
    status: DeliveryStatus
    attempts: int
    next_at: datetime | None
    last_error: str
    response_code: int | None
    created_at: datetime
    delivered_at: datetime | None
    title: str
    """The event's title in the channel's language."""

    def to_json(self) -> dict[str, Any]:
        """The delivery as the API shows it (times in ISO 8601, UTC)."""
        return {
            "id": self.id,
            "event_id": self.event_id,
            "channel_id": self.channel_id,
            "channel_name": self.channel_name,
            "kind": self.kind,
            "printer_id": self.printer_id,
            "status": self.status,
            "attempts": self.attempts,
            "next_at": iso(self.next_at),
            "last_error": self.last_error,
            "response_code": self.response_code,
            "created_at": iso(self.created_at),
            "delivered_at": iso(self.delivered_at),
            "title": self.title,
        }


@dataclass(frozen=True, slots=True)
class DueDelivery:
    """A pending delivery the outbox is to send now (claimed for it: see
    :meth:`~kybercore.notify.store.NotifyStore.due`)."""

    id: int
    attempts: int
    created_at: datetime
    channel_id: int
    channel_kind: ChannelKind
    target: str
    secret: str | None
    rules: ChannelRules
    event: FleetEvent
    has_snapshot: bool


def mask_target(kind: ChannelKind, target: str) -> str:
    """``target`` safe to show: an Apprise URL as ``scheme://…`` and its last characters;
    a webhook URL without its user info, query and fragment."""
    if kind == "apprise":
        scheme, found, rest = target.partition("://")
        if not found:
            scheme, rest = "", target
        tail = rest[-_SHOWN_TAIL:] if len(rest) > 2 * _SHOWN_TAIL else ""
        return f"{scheme}://…{tail}"
    parts = urlsplit(target)
    host = parts.netloc.rpartition("@")[2]
    return urlunsplit((parts.scheme, host, parts.path, "", ""))


def iso(moment: datetime | None) -> str | None:
    """``2026-11-24T10:00:00.123Z``; None stays None."""
    if moment is None:
        return None
    return moment.astimezone(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def to_channel(row: RowMapping) -> Channel:
    """A ``notify_channels`` row as a :class:`Channel`."""
    return Channel(
        id=row["id"],
        name=row["name"],
        kind=cast(ChannelKind, row["kind"]),
        target=row["target"],
        has_secret=bool(row["secret"]),
        rules=ChannelRules.from_json(row["rules"]),
        enabled=bool(row["enabled"]),
        created_at=row["created_at"],
        created_by=row["created_by"],
        updated_at=row["updated_at"],
        updated_by=row["updated_by"],
    )


def to_delivery(row: RowMapping) -> Delivery:
    """A ``notify_deliveries`` row joined with its event (``kind``, ``printer_id``,
    ``payload``) and channel (``channel_name``, ``rules``), as a :class:`Delivery`."""
    try:
        language = ChannelRules.from_json(row["rules"]).language
        title, _body = render(FleetEvent.from_json(row["payload"]), language)
    except (KeyError, TypeError, ValueError):
        title = str(row["kind"])  # written by a newer KyberCore: the log still lists it
    return Delivery(
        id=row["id"],
        event_id=row["event_id"],
        channel_id=row["channel_id"],
        channel_name=row["channel_name"],
        kind=cast(EventKind, row["kind"]),
        printer_id=row["printer_id"],
        status=cast(DeliveryStatus, row["status"]),
        attempts=row["attempts"],
        next_at=row["next_at"],
        last_error=row["last_error"],
        response_code=row["response_code"],
        created_at=row["created_at"],
        delivered_at=row["delivered_at"],
        title=title,
    )


def to_due(row: RowMapping) -> DueDelivery:
    """A pending delivery joined with its channel (``kind``, ``target``, ``secret``,
    ``rules``) and event (``payload``, ``has_snapshot``), as a :class:`DueDelivery`."""
    return DueDelivery(
        id=row["id"],
        attempts=row["attempts"],
        created_at=row["created_at"],
        channel_id=row["channel_id"],
        channel_kind=cast(ChannelKind, row["kind"]),
        target=row["target"],
        secret=row["secret"],
        rules=ChannelRules.from_json(row["rules"]),
        event=FleetEvent.from_json(row["payload"]),
        has_snapshot=bool(row["has_snapshot"]),
    )


def settings_from(value: Mapping[str, Any]) -> NoiseSettings:
    """Noise settings as stored (JSON). Keys of a newer or older KyberCore are ignored;
    missing ones take their defaults."""
    known = {f.name for f in dataclasses.fields(NoiseSettings)}
    return NoiseSettings(**{k: v for k, v in value.items() if k in known})
