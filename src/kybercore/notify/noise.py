"""What of the detected events is news: cooldown, alerts paired with recoveries, folding.

Pure: the service pushes every event with the monotonic time (:meth:`NoiseFilter.push`) and
calls :meth:`NoiseFilter.release` about once a second; both return what goes out now.

- **Cooldown**: an event of one subject (its printer; else its job or location) and kind is
  told at most once per ``cooldown_s``, counted between the times they go *out*, so a
  held event cannot come out closer to the previous one than that.
- **Pairing**: a ``printer_recovered`` goes out only if the alert it ends (offline,
  Klippy's shutdown/error, or no worker reporting it) went out, alone or folded, and
  closes it. It has no
  cooldown of its own: there is at most one per alert, and alerts are cooled down, so a
  flapping printer sends one alert and one recovery per cooldown.
- **Folding**: ``printer_offline``, ``plate_waiting`` and ``printer_unreported`` are held
  ``fold_window_s`` from the first of their group (offline: per location; plates and
  unreported printers: the whole fleet, as a worker's printers stand in any room). When
  the window closes, more than ``storm_threshold`` offline printers of one location make
  one ``storm_offline``; several plates one ``plate_waiting``; several unreported printers
  (a worker died) one ``printer_unreported``. The recoveries of folded alerts are folded
  the same way (a storm's per location) into one ``printer_recovered``.
- ``test`` events always pass.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, Final

from kybercore.notify.models import EventKind, FleetEvent, NoiseSettings

_HELD: Final[frozenset[EventKind]] = frozenset(
    {"printer_offline", "plate_waiting", "printer_unreported"}
)
_ALERT_GROUP: Final[dict[EventKind, str]] = {
    "printer_offline": "connection",
    "klippy_shutdown": "klippy",
    "klippy_error": "klippy",
    "printer_unreported": "worker",
}
"""Alerts a ``printer_recovered`` ends; its ``params.what`` names the group."""
_HELD_ALERT: Final[dict[str, EventKind]] = {
    "connection": "printer_offline",
    "worker": "printer_unreported",
}
"""The held alert of each group, whose recovery waits for it to go out."""


def subject(event: FleetEvent) -> str:
    """Who an event is about, for its cooldown: the printer, else the job or location."""
    if event.printer is not None:
        return event.printer.id
    return str(event.params.get("job_id") or event.params.get("location") or "")


def recovery_group(event: FleetEvent) -> str:
    """The alert group a ``printer_recovered`` closes: ``klippy``, ``worker`` or
    ``connection``."""
    what = event.params.get("what")
    return what if what in ("klippy", "worker") else "connection"


@dataclass(slots=True)
class _Window:
    """Events held together until ``deadline``."""

    deadline: float
    events: list[FleetEvent] = field(default_factory=list)

    def holds(self, printer_id: str) -> bool:
        return any(subject(event) == printer_id for event in self.events)


# A window's group: (kind, location, alert group). Offline printers and a storm's
# recoveries fold per location, the rest fleet-wide (location None); the alert group keeps
# the recoveries of storms and of unreported printers apart.
_Group = tuple[EventKind, str | None, str]


class NoiseFilter:
    """Lets through what is news (see the module docstring)."""

    def __init__(self, settings: NoiseSettings) -> None:
        self._settings = settings
        self._out: dict[tuple[str, EventKind], float] = {}
        """(subject, kind) -> when it last went out (while held: when it is due)."""
        self._open: dict[tuple[str, str], bool] = {}
        """(printer id, alert group) -> whether the alert went out folded into a storm."""
        self._held: dict[_Group, _Window] = {}
        self._waiting: dict[tuple[str, str], FleetEvent] = {}
        """(printer id, alert group) -> a recovery whose alert is still held: sent after it."""

    def update(self, settings: NoiseSettings) -> None:
        """Use new settings from now on; held windows keep their deadlines."""
        self._settings = settings

    def push(self, event: FleetEvent, now: float) -> list[FleetEvent]:
        """Take in ``event`` at monotonic ``now``; return what goes out now."""
        if event.kind == "test":
            return [event]
        # What was due before comes first; with no fold window, what this holds is due too.
        out = self.release(now)
        if event.kind == "printer_recovered":
            out += self._recovered(event, now)
        else:
            out += self._alert(event, now)
        return [*out, *self.release(now)]

    def release(self, now: float) -> list[FleetEvent]:
        """The held events whose window closed by ``now``, folded."""
        out: list[FleetEvent] = []
        # Releasing a storm may hold its recoveries; with no fold window they are due at once.
        while due := [group for group, window in self._held.items() if window.deadline <= now]:
            for group in sorted(due, key=lambda g: self._held[g].deadline):
                window = self._held.pop(group)
                out.extend(self._fold(group, window, now))
        return out

    def _alert(self, event: FleetEvent, now: float) -> list[FleetEvent]:
        """Any event but a recovery: cooled down, then held or out."""
        key = (subject(event), event.kind)
        last = self._out.get(key)
        if last is not None and now < last + self._settings.cooldown_s:
            return []
        if event.kind not in _HELD:
            self._out[key] = now
            self._opened([event], folded=False)
            return [event]
        location = event.printer.location if event.printer else None
        group: _Group = (event.kind, location if event.kind == "printer_offline" else None, "")
        window = self._hold(group, now)
        if not window.holds(key[0]):
            window.events.append(event)
            self._out[key] = window.deadline
        return []

    def _hold(self, group: _Group, now: float) -> _Window:
        """The open window of ``group``, opened now if there is none."""
        return self._held.setdefault(group, _Window(now + self._settings.fold_window_s))

    def _opened(self, events: Iterable[FleetEvent], *, folded: bool) -> None:
        for event in events:
            group = _ALERT_GROUP.get(event.kind)
            if group is not None and event.printer is not None:
                self._open[(event.printer.id, group)] = folded

    def _recovered(self, event: FleetEvent, now: float) -> list[FleetEvent]:
        printer_id = subject(event)
        group = recovery_group(event)
        held = _HELD_ALERT.get(group)
        if any(g[0] == held and w.holds(printer_id) for g, w in self._held.items()):
            self._waiting[(printer_id, group)] = event
            return []
        folded = self._open.pop((printer_id, group), None)
        if folded is None:
            return []
        if not folded:
            return [event]
        location = event.printer.location if event.printer and group == "connection" else None
        self._hold(("printer_recovered", location, group), now).events.append(event)
        return []

    def _fold(self, group: _Group, window: _Window, now: float) -> list[FleetEvent]:
        kind, location, what = group
        events = window.events
        for event in events:  # out now, maybe later than the deadline it was counted from
            self._out[(subject(event), event.kind)] = now
        if kind in _HELD_ALERT.values():
            return self._fold_alerts(kind, location, events, now)
        if len(events) == 1:
            return events
        if kind == "printer_recovered":
            where = {"location": location} if what == "connection" else {}
            return [_folded(kind, events, **where, what=what)]
        # Plates fold fleet-wide; when they all stand in one place, say where.
        locations = {event.printer.location if event.printer else None for event in events}
        place = locations.pop() if len(locations) == 1 else None
        return [_folded(kind, events, **({"location": place} if place else {}))]

    def _fold_alerts(
        self, kind: EventKind, location: str | None, events: list[FleetEvent], now: float
    ) -> list[FleetEvent]:
        """A closed window of offline or unreported printers: folded (a storm; several
        unreported) or one by one; then the recoveries that waited for them."""
        storm = kind == "printer_offline"
        fold = len(events) > (self._settings.storm_threshold if storm else 1)
        self._opened(events, folded=fold)
        out = events
        if fold:
            out = [_folded("storm_offline", events, location=location) if storm
                   else _folded(kind, events)]  # fmt: skip
        group = _ALERT_GROUP[kind]
        for event in events:
            waiting = self._waiting.pop((subject(event), group), None)
            if waiting is not None:
                out = [*out, *self._recovered(waiting, now)]
        return out


def _folded(kind: EventKind, events: list[FleetEvent], **params: Any) -> FleetEvent:
    """One fleet-wide event standing for ``events`` (of several printers)."""
    printers = [event.printer for event in events if event.printer is not None]
    return FleetEvent(
        kind,
        events[0].at,
        None,
        {
            **params,
            "count": len(events),
            "printers": [printer.id for printer in printers],
            "names": [printer.name for printer in printers],
        },
    )
