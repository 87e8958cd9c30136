"""The vocabulary of notifications: event kinds, their severity, events, noise settings.

Pure data. A :class:`FleetEvent` is what happened (one printer, or a fold of several); it
travels as JSON (:meth:`FleetEvent.to_json`) to webhooks and into the store.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any, Final, Literal, get_args
from uuid import uuid4

from kybercore.registry.models import PrinterConfig

EventKind = Literal[
    "print_started", "print_completed", "print_failed", "print_cancelled", "print_paused",
    "first_layer_done", "printer_offline", "printer_recovered", "klippy_shutdown",
    "klippy_error", "plate_waiting", "job_blocked", "storm_offline", "printer_unreported",
    "test",
]  # fmt: skip
EVENT_KINDS: Final[tuple[EventKind, ...]] = get_args(EventKind)
"""Every kind, in the order the dashboard lists them."""
DEFAULT_EVENTS: Final[frozenset[EventKind]] = frozenset(EVENT_KINDS) - {
    "first_layer_done",
    "test",
}
"""What a new channel receives: everything but the optional first layer (and tests, which
are always delivered)."""

Severity = Literal["info", "warning", "critical"]
_CRITICAL: Final = ("print_failed", "printer_offline", "klippy_shutdown", "klippy_error",
                    "storm_offline", "printer_unreported")  # fmt: skip
_WARNING: Final = ("print_paused", "plate_waiting", "job_blocked", "print_cancelled")
SEVERITY: Final[Mapping[EventKind, Severity]] = {
    kind: "critical" if kind in _CRITICAL else "warning" if kind in _WARNING else "info"
    for kind in EVENT_KINDS
}
"""Critical events pass quiet hours that allow them."""


def event_kind(value: object) -> EventKind:
    """``value`` as an :data:`EventKind`; ValueError if it is none."""
    for kind in EVENT_KINDS:
        if value == kind:
            return kind
    raise ValueError(f"unknown event kind {value!r}; one of {', '.join(EVENT_KINDS)}")


@dataclass(frozen=True, slots=True)
class PrinterRef:
    """The printer an event is about, as it was configured when the event happened."""

    id: str
    name: str
    location: str | None
    tags: tuple[str, ...]

    @classmethod
    def of(cls, config: PrinterConfig) -> PrinterRef:
        """The reference to a configured printer (an empty location is none)."""
        return cls(config.id, config.name, config.location or None, tuple(config.tags))

    def to_json(self) -> dict[str, Any]:
        """``{"id", "name", "location", "tags"}``."""
        return {"id": self.id, "name": self.name, "location": self.location,
                "tags": list(self.tags)}  # fmt: skip

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> PrinterRef:
        """The reference :meth:`to_json` wrote."""
        location = data.get("location")
        return cls(
            str(data["id"]),
            str(data["name"]),
            str(location) if location is not None else None,
            tuple(str(tag) for tag in data.get("tags") or ()),
        )


def _utc_text(at: datetime) -> str:
    return at.astimezone(UTC).isoformat().replace("+00:00", "Z")


@dataclass(frozen=True, slots=True)
class FleetEvent:
    """Something that happened in the fleet and may be worth telling someone."""

    kind: EventKind
    at: datetime
    """When it happened: UTC, timezone-aware."""
    printer: PrinterRef | None
    """None for folded and fleet-wide events (their printers are in ``params``)."""
    params: Mapping[str, Any]
    """JSON-ready details: filename, message, reason, count, printers (ids), names,
    location, job_id, job_name, minutes, layer, was, what ..."""
    id: str = field(default_factory=lambda: uuid4().hex)

    @property
    def severity(self) -> Severity:
        """How urgent this kind of event is."""
        return SEVERITY[self.kind]

    def to_json(self) -> dict[str, Any]:
        """The event as webhooks receive it and the store keeps it."""
        return {
            "id": self.id,
            "type": self.kind,
            "at": _utc_text(self.at),
            "severity": self.severity,
            "printer": self.printer.to_json() if self.printer else None,
            "data": dict(self.params),
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> FleetEvent:
        """The event :meth:`to_json` wrote; ValueError (or KeyError) if it is not one."""
        at = datetime.fromisoformat(str(data["at"]))
        if at.tzinfo is None:
            raise ValueError(f"event time {data['at']!r} has no timezone")
        printer = data.get("printer")
        return cls(
            kind=event_kind(data["type"]),
            at=at.astimezone(UTC),
            printer=PrinterRef.from_json(printer) if printer is not None else None,
            params=dict(data.get("data") or {}),
            id=str(data["id"]),
        )


UNREPORTED_GRACE_S: Final = 30.0
"""Seconds a printer may go unreported by every KyberCore worker before it is told. A front
marks a slot stale after 2 s of silence; a slot handed over between live workers is back
within a second or two, one whose worker died within TTL + TTL/3 plus a reconnect (≤ 10 s
promised at TTL 3, so about 14 s at the workers' default TTL of 6 s): twice that is no
normal failover."""


@dataclass(frozen=True, slots=True)
class NoiseSettings:
    """How much the farm may say. Plain data: the API validates with its own model."""

    cooldown_s: float = 300.0
    """The same event of the same printer is told at most once in this many seconds."""
    fold_window_s: float = 20.0
    """Offline, plate-waiting and unreported events are held this long, to be folded."""
    storm_threshold: int = 3
    """More than this many printers of one location offline within the fold window make
    one storm_offline message."""
    offline_grace_s: float = 0.0
    """> 0: a printer offline longer than this is told even if it was idle. 0: an idle
    printer switched off is not news."""
    plate_wait_s: float = 1800.0
    """A plate awaiting clear longer than this makes a plate_waiting event."""
    job_blocked_s: float = 600.0
    """A queued job blocked longer than this makes a job_blocked event."""
    unreported_grace_s: float = UNREPORTED_GRACE_S
    """> 0: a printer no KyberCore worker has reported for longer than this (on NATS) makes
    a printer_unreported event. 0: never."""
