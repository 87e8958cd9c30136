"""What notifications read of the printers: :class:`NotifyPrinters`, and
:class:`FleetNotifyPrinters`, its implementation over this process's sessions.

The notification service (:mod:`.service`) and the queue checks (:mod:`.queue_checks`) use
only the protocol, so the same service runs where the printers' sessions are
(``kybercore serve``) and on a front on NATS, which has the printers' views and reaches
each printer through its owner (``kybercore.scale.front_notify``), as the job queue does
with :class:`~kybercore.jobs.printers.QueuePrinters`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Final, Protocol

import httpx

from kybercore.errors import KyberCoreError
from kybercore.fleet.service import FleetService
from kybercore.fleet.sessions import FleetPrinter, Interest
from kybercore.moonraker.events import Notification, SessionEvent, StatusDelta
from kybercore.notify.detector import Observation, observe
from kybercore.notify.models import PrinterRef
from kybercore.notify.snapshot import take_snapshot

WATCHED_OBJECTS: Final = ("print_stats", "webhooks", "filament_switch_sensor",
                          "filament_motion_sensor")  # fmt: skip
"""Status objects an :class:`Observation` reads; an update touching none is skipped."""
INTEREST: Final = Interest(
    {"print_stats": frozenset({"state", "filename", "message", "info"}), "webhooks": None},
    prefixes=WATCHED_OBJECTS[2:],
)
"""The deltas the fleet passes on: those that can change an :class:`Observation` (not
``print_duration`` and the like, which every update carries)."""

OnChange = Callable[[str], None]
"""Told the id of a printer whose observation may have changed."""


@dataclass(frozen=True, slots=True)
class Observed:
    """A printer as notifications see it now."""

    ref: PrinterRef
    observation: Observation


class NotifyPrinters(Protocol):
    """The printers, as notifications read them."""

    def all(self) -> list[Observed]:
        """Every printer of the fleet, as it stands now."""

    def ids(self) -> set[str]:
        """The ids of every printer of the fleet (without observing each one)."""

    def get(self, printer_id: str) -> Observed:
        """One printer as it stands now; a KyberCoreError (UnknownPrinter) when the fleet
        has no such printer."""

    def listen(self, on_change: OnChange) -> Callable[[], None]:
        """Call ``on_change`` when a printer's observation may have changed (quickly: it
        runs for the fleet's updates; it must not raise); returns the way to stop."""

    async def snapshot(self, printer_id: str) -> bytes | None:
        """A JPEG from the printer's first enabled webcam that gives one, or None (no
        webcam, the printer offline or unknown, any failure). Never raises."""


class FleetNotifyPrinters:
    """The printers in this process: :class:`FleetService`'s sessions."""

    def __init__(self, fleet: FleetService, http: httpx.AsyncClient) -> None:
        """``http``: the client the webcams' snapshots are fetched with."""
        self._fleet = fleet
        self._http = http

    def all(self) -> list[Observed]:
        """Every configured printer, as it stands now."""
        return [_observed(printer) for printer in self._fleet.sessions.all()]

    def ids(self) -> set[str]:
        """The ids of every configured printer."""
        return {printer.config.id for printer in self._fleet.sessions.all()}

    def get(self, printer_id: str) -> Observed:
        """One printer as it stands now (UnknownPrinter when it is not configured)."""
        return _observed(self._fleet.sessions.get(printer_id))

    def listen(self, on_change: OnChange) -> Callable[[], None]:
        """Call ``on_change`` for the session events that can change an observation:
        connection, Klippy and snapshots, and the deltas of :data:`WATCHED_OBJECTS`
        (temperatures and positions, most of the traffic, are skipped here)."""

        def hear(printer_id: str, event: SessionEvent) -> None:
            if isinstance(event, Notification):
                return
            if isinstance(event, StatusDelta) and not any(
                name.startswith(WATCHED_OBJECTS) for name in event.delta
            ):
                return
            on_change(printer_id)

        return self._fleet.listen(hear, INTEREST)

    async def snapshot(self, printer_id: str) -> bytes | None:
        """From the printer's webcams through its Moonraker (see :func:`take_snapshot`)."""
        try:
            printer = self._fleet.sessions.get(printer_id)
        except KyberCoreError:
            return None
        if printer.client is None or printer.live.connection != "online":
            return None  # an offline printer's webcam is as far away as its Moonraker
        return await take_snapshot(printer.client, printer.config.moonraker_url, self._http)


def _observed(printer: FleetPrinter) -> Observed:
    return Observed(PrinterRef.of(printer.config), observe(printer.live))
