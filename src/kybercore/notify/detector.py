"""Events from one printer's live state: only its transitions are news.

Pure: the notification service calls :meth:`Detector.observe` with an :class:`Observation`
after every session event of a printer, and :meth:`Detector.tick` about once a second for
the offline grace period; times are passed in, so tests drive them.

What the detector remembers of a printer is what it last knew *for sure*: the print state
while Moonraker was online and Klippy ready (a state read while Klippy is not ready, or
kept from before a connection loss, is stale), and Klippy's state while Moonraker was
online (``disconnected`` and ``startup`` say nothing: every reconnect passes through them).
The first value learned of each is a baseline and emits nothing, so a KyberCore restart is
silent; and a reconnect is judged against the state before the loss, so a print that
finished meanwhile is told once and a finished one seen again is not told twice.

On NATS a printer may also go *unreported*: no KyberCore worker publishes it (all of them
down, or its slot held by none), so nothing about it can be known. Past
``unreported_grace_s`` that is told (``printer_unreported``), and its end too
(``printer_recovered``, ``what: worker``). Unlike an offline printer, one unreported from
the start counts: a front that never hears of a printer has lost sight of it all the same.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any, Final

from kybercore.core.view import LivePrinter, filament_runout
from kybercore.notify.models import EventKind, FleetEvent, NoiseSettings, PrinterRef

ACTIVE: Final = frozenset({"printing", "paused"})
_KLIPPY_ALERTS: Final[Mapping[str, EventKind]] = {
    "shutdown": "klippy_shutdown",
    "error": "klippy_error",
}
# Klippy states that say something; the others come and go with every (re)connect.
_KLIPPY_KNOWN: Final = frozenset({"ready", "shutdown", "error"})

Emit = Callable[..., None]
"""``emit(kind, **params)``: add an event about the observed printer."""


@dataclass(frozen=True, slots=True)
class Observation:
    """What notifications need of a printer's live state, read in one go."""

    connection: str
    """:attr:`LivePrinter.connection`: ``connecting|online|offline|auth_failed``."""
    klippy_state: str
    klippy_message: str
    print_state: str | None
    """``print_stats.state``; None when Klippy has not said."""
    filename: str | None
    print_message: str
    """``print_stats.message``: Klipper's error text when a print fails."""
    layer: int | None
    """``print_stats.info.current_layer`` (None unless the slicer reports layers)."""
    runout: bool
    """An enabled filament sensor reports no filament."""
    reported: bool = True
    """A KyberCore process reports the printer now: False only on a front, while no worker
    publishes its slot (the other fields are then its last report)."""


def _text(value: Any) -> str:
    return value if isinstance(value, str) else ""


def observe(live: LivePrinter) -> Observation:
    """The observation of a printer's live state (read defensively: any peer may lie)."""
    status = live.status
    stats = status.get("print_stats", {})
    info = stats.get("info")
    state = stats.get("state")
    return Observation(
        connection=live.connection,
        klippy_state=live.klippy_state,
        klippy_message=live.klippy_message,
        print_state=state if isinstance(state, str) and state else None,
        filename=_text(stats.get("filename")) or None,
        print_message=_text(stats.get("message")),
        layer=_layer(info.get("current_layer") if isinstance(info, dict) else None),
        runout=filament_runout(status),
    )


def observe_view(view: Mapping[str, Any]) -> Observation:
    """The observation read back from a printer's fused view
    (:func:`~kybercore.core.view.fuse`), for a process that has the views but not the live
    state (a front on NATS): what :func:`observe` gives for the live state the view was
    fused from, but for what the view does not keep apart:

    - ``print_state`` is None while Klippy is not ready (the view blanks the job's state);
      the detector reads the print state only once Klippy is ready, so its events are the
      same;
    - ``print_message`` falls back to the display's message (M117) when Klipper's
      ``print_stats.message`` is empty, as the view's ``job.message`` does; Klipper sets the
      latter when a print fails, the one case an event quotes it;
    - a ``print_stats.filename`` that is not text reads as its text.
    """
    job: Mapping[str, Any] = view.get("job") or {}
    return Observation(
        connection=_text(view.get("connection")),
        klippy_state=_text(view.get("klippy_state")),
        klippy_message=_text(view.get("klippy_message")),
        print_state=_text(job.get("state")) or None,
        filename=_text(job.get("filename")) or None,
        print_message=_text(job.get("message")),
        layer=_layer(job.get("layer")),
        runout=view.get("runout") is True,
    )


def _layer(value: Any) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) else None


@dataclass(slots=True)
class _Track:
    """What the detector knows of one printer."""

    online: bool
    print_state: str | None = None
    filename: str | None = None
    klippy: str | None = None
    first_layer_armed: bool = False
    lost_at: float | None = None
    """When the connection was lost with no alert told (for the grace period)."""
    unreported_at: float | None = None
    """When no worker reported it any more, with no alert told (for its grace period)."""
    alerts: set[str] = field(default_factory=set)
    """Alerts told and not yet recovered: ``connection``, ``klippy``, ``worker``."""


class Detector:
    """Turns each printer's observations into events (see the module docstring)."""

    def __init__(self, settings: NoiseSettings) -> None:
        self._settings = settings
        self._tracks: dict[str, _Track] = {}
        self._refs: dict[str, PrinterRef] = {}

    def update(self, settings: NoiseSettings) -> None:
        """Use new settings from now on (the grace periods of printers already counting too)."""
        self._settings = settings

    def forget(self, printer_id: str) -> None:
        """Drop what is known of a removed printer; if it comes back, it starts afresh."""
        self._tracks.pop(printer_id, None)
        self._refs.pop(printer_id, None)

    def observe(
        self, printer: PrinterRef, obs: Observation, now: float, at: datetime
    ) -> list[FleetEvent]:
        """The events this observation of ``printer`` makes, at monotonic ``now`` (for the
        grace period) and wall time ``at`` (UTC, aware; stamped on the events)."""
        self._refs[printer.id] = printer
        track = self._tracks.get(printer.id)
        online = obs.connection == "online"
        if track is None:
            # Nothing known yet: every value below is learned, none is a transition.
            self._tracks[printer.id] = track = _Track(online=online)
        events: list[FleetEvent] = []

        def emit(kind: EventKind, **params: Any) -> None:
            events.append(FleetEvent(kind, at, printer, params))

        if track.online and not online:
            self._lost(track, emit, now)
        elif online and not track.online:
            track.lost_at = None
            if "connection" in track.alerts:
                track.alerts.discard("connection")
                emit("printer_recovered", what="connection")
        track.online = online
        self._reported(track, obs.reported, emit, now)
        if online:
            self._klippy(track, obs, emit)
            if obs.klippy_state == "ready":
                self._print(track, obs, emit)
        return events

    def tick(self, now: float, at: datetime) -> list[FleetEvent]:
        """printer_offline for the printers offline longer than the offline grace period,
        printer_unreported for those unreported longer than theirs (each if set)."""
        offline_grace = self._settings.offline_grace_s
        unreported_grace = self._settings.unreported_grace_s
        events = []
        for printer_id, track in self._tracks.items():
            printer = self._refs[printer_id]
            lost, unreported = track.lost_at, track.unreported_at
            if lost is not None and 0 < offline_grace <= now - lost:
                track.lost_at = None
                track.alerts.add("connection")
                minutes = max(1, round((now - lost) / 60))
                events.append(FleetEvent("printer_offline", at, printer, {"minutes": minutes}))
            if unreported is not None and 0 < unreported_grace <= now - unreported:
                track.unreported_at = None
                track.alerts.add("worker")
                seconds = round(now - unreported)
                events.append(FleetEvent("printer_unreported", at, printer, {"seconds": seconds}))
        return events

    @staticmethod
    def _reported(track: _Track, reported: bool, emit: Emit, now: float) -> None:
        if not reported:
            if track.unreported_at is None and "worker" not in track.alerts:
                track.unreported_at = now
            return
        track.unreported_at = None
        if "worker" in track.alerts:
            track.alerts.discard("worker")
            emit("printer_recovered", what="worker")

    def _lost(self, track: _Track, emit: Emit, now: float) -> None:
        # A Klippy already down was told: losing the printer then (a power cycle to
        # recover it, most likely) is not a second alert.
        if track.print_state in ACTIVE and "klippy" not in track.alerts:
            track.alerts.add("connection")
            params = {"was": track.print_state}
            if track.filename:
                params["filename"] = track.filename
            emit("printer_offline", **params)
        elif "connection" not in track.alerts:
            track.lost_at = now

    def _klippy(self, track: _Track, obs: Observation, emit: Emit) -> None:
        state = obs.klippy_state
        if state not in _KLIPPY_KNOWN or state == track.klippy:
            return
        before, track.klippy = track.klippy, state
        if state in _KLIPPY_ALERTS and before == "ready":
            track.alerts.add("klippy")
            emit(_KLIPPY_ALERTS[state], message=obs.klippy_message)
        elif state == "ready" and "klippy" in track.alerts:
            track.alerts.discard("klippy")
            emit("printer_recovered", what="klippy")

    def _print(self, track: _Track, obs: Observation, emit: Emit) -> None:
        state, before = obs.print_state, track.print_state
        if state is None:
            return
        file = {"filename": obs.filename} if obs.filename else {}
        if state != before and before is not None:
            if state == "printing" and before not in ACTIVE:
                track.first_layer_armed = True
                emit("print_started", **file)
            elif before in ACTIVE and state == "complete":
                emit("print_completed", **file)
            elif before in ACTIVE and state == "error":
                emit("print_failed", **file, message=obs.print_message)
            elif before in ACTIVE and state == "cancelled":
                emit("print_cancelled", **file)
            elif before == "printing" and state == "paused":
                emit("print_paused", **file, reason="runout" if obs.runout else "unknown")
        if state == "printing" and obs.layer is not None:
            if obs.layer <= 1:
                track.first_layer_armed = True
            elif track.first_layer_armed:
                track.first_layer_armed = False
                emit("first_layer_done", **file, layer=obs.layer)
        elif state not in ACTIVE:
            track.first_layer_armed = False
        track.print_state, track.filename = state, obs.filename
