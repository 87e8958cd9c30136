"""Which events a channel gets: its kinds, printers, locations and tags, and quiet hours.

Pure: :func:`route` judges one event for one channel at a given local time of day.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import time
from typing import Any, Final, Literal

from kybercore.notify.models import DEFAULT_EVENTS, EVENT_KINDS, EventKind, FleetEvent

Route = Literal["deliver", "skip", "quiet_hours"]
"""``skip``: not for this channel. ``quiet_hours``: for it, but recorded and not sent."""
Language = Literal["en", "es"]
Role = Literal["operator", "admin"]

_HHMM: Final = re.compile(r"^([01][0-9]|2[0-3]):[0-5][0-9]$")


def clock(text: str) -> time:
    """``"HH:MM"`` (24 h) as a time; ValueError if it is not one."""
    if not isinstance(text, str) or not _HHMM.match(text):
        raise ValueError(f"{text!r} is not a time of day as HH:MM, e.g. 22:30")
    return time(int(text[:2]), int(text[3:]))


@dataclass(frozen=True, slots=True)
class QuietHours:
    """A daily span, in the server's local time, when only critical events (if allowed)
    are sent. ``end`` before ``start`` wraps midnight; ``start`` equal to ``end`` is empty."""

    start: str
    end: str
    allow_critical: bool = True

    def __post_init__(self) -> None:
        clock(self.start)
        clock(self.end)

    def covers(self, local: time) -> bool:
        """Whether ``local`` falls in the span (start included, end excluded)."""
        start, end = clock(self.start), clock(self.end)
        moment = local.replace(second=0, microsecond=0, tzinfo=None)
        if start <= end:
            return start <= moment < end
        return moment >= start or moment < end


def _text(value: Any, what: str) -> str:
    if not isinstance(value, str):
        raise ValueError(f"{what} must be text")  # noqa: TRY004 -- see _flag
    return value


def _strings(value: Any, what: str) -> tuple[str, ...]:
    if not isinstance(value, list | tuple) or not all(isinstance(v, str) for v in value):
        raise ValueError(f"{what} must be a list of strings")
    return tuple(value)


def _choice(value: Any, options: tuple[str, ...], what: str) -> Any:
    if value not in options:
        raise ValueError(f"{what} must be one of {', '.join(options)}, not {value!r}")
    return value


@dataclass(frozen=True, slots=True)
class ChannelRules:
    """What one channel receives, and who may change it."""

    events: frozenset[EventKind] = DEFAULT_EVENTS
    printers: tuple[str, ...] = ()
    """Printer ids; empty = every printer."""
    locations: tuple[str, ...] = ()
    """Empty = every location."""
    tags: tuple[str, ...] = ()
    """Empty = any; else the printer has one of them."""
    quiet_hours: QuietHours | None = None
    language: Language = "en"
    attach_snapshot: bool = True
    min_role: Role = "admin"
    """The least role that may change or remove this channel."""

    def to_json(self) -> dict[str, Any]:
        """The rules as stored and as the API shows them (events in the dashboard's order)."""
        quiet = self.quiet_hours
        return {
            "events": [kind for kind in EVENT_KINDS if kind in self.events],
            "printers": list(self.printers),
            "locations": list(self.locations),
            "tags": list(self.tags),
            "quiet_hours": None
            if quiet is None
            else {"start": quiet.start, "end": quiet.end, "allow_critical": quiet.allow_critical},
            "language": self.language,
            "attach_snapshot": self.attach_snapshot,
            "min_role": self.min_role,
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> ChannelRules:
        """The rules :meth:`to_json` wrote; missing keys take their defaults. Event kinds
        this version does not know are dropped (rules stored by a newer one still load);
        anything else malformed raises ValueError."""
        events = data.get("events")
        return cls(
            events=DEFAULT_EVENTS
            if events is None
            else frozenset(k for k in EVENT_KINDS if k in _strings(events, "events")),
            printers=_strings(data.get("printers", []), "printers"),
            locations=_strings(data.get("locations", []), "locations"),
            tags=_strings(data.get("tags", []), "tags"),
            quiet_hours=_quiet_hours(data.get("quiet_hours")),
            language=_choice(data.get("language", "en"), ("en", "es"), "language"),
            attach_snapshot=_flag(data.get("attach_snapshot", True), "attach_snapshot"),
            min_role=_choice(data.get("min_role", "admin"), ("operator", "admin"), "min_role"),
        )


def _flag(value: Any, what: str) -> bool:
    # ValueError, not TypeError: to the caller this is one more malformed value in the data.
    if not isinstance(value, bool):
        raise ValueError(f"{what} must be true or false")  # noqa: TRY004
    return value


def _quiet_hours(value: Any) -> QuietHours | None:
    if value is None:
        return None
    if not isinstance(value, Mapping):
        raise ValueError("quiet_hours must be an object: start, end, allow_critical")  # noqa: TRY004
    return QuietHours(
        _text(value.get("start"), "quiet_hours.start"),
        _text(value.get("end"), "quiet_hours.end"),
        _flag(value.get("allow_critical", True), "quiet_hours.allow_critical"),
    )


def matches(rules: ChannelRules, event: FleetEvent) -> bool:
    """Whether ``event`` is for this channel (kind, printer, location, tags)."""
    if event.kind not in rules.events:
        return False
    printer = event.printer
    if printer is not None:
        return (
            (not rules.printers or printer.id in rules.printers)
            and (not rules.locations or printer.location in rules.locations)
            and (not rules.tags or any(tag in rules.tags for tag in printer.tags))
        )
    # A fleet-wide event: judged by what it says of itself (its location, its printers).
    location = event.params.get("location")
    if rules.locations and location is not None and location not in rules.locations:
        return False
    printers = event.params.get("printers")
    return not (
        rules.printers
        and isinstance(printers, list)
        and not any(printer_id in rules.printers for printer_id in printers)
    )


def route(rules: ChannelRules, event: FleetEvent, local: time) -> Route:
    """What this channel does with ``event`` at local time of day ``local``. Test events
    are always delivered."""
    if event.kind == "test":
        return "deliver"
    if not matches(rules, event):
        return "skip"
    quiet = rules.quiet_hours
    if quiet is None or not quiet.covers(local):
        return "deliver"
    return "deliver" if quiet.allow_critical and event.severity == "critical" else "quiet_hours"
