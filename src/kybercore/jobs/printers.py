"""The fleet as the job queue sees it: each printer's facts and what it shows, news of
its changes, and the few things the queue does on a printer.

The dispatcher and the tracker use only :class:`QueuePrinters`, so the same queue runs in
one process and on NATS:

- :class:`FleetPrinters` (``kybercore serve``, and tests): this process's Moonraker
  sessions and clients;
- :class:`kybercore.scale.queue.FrontPrinters` (``kybercore front``): the front's copy of
  the views, with each printer's owner doing the work by command.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, Literal, NamedTuple, Protocol

from kybercore.core.numbers import finite_number
from kybercore.core.validation import PrinterFacts
from kybercore.core.view import LivePrinter, facts
from kybercore.errors import MoonrakerRpcError
from kybercore.fleet.service import FleetService
from kybercore.fleet.sessions import Interest
from kybercore.jobs.heating import is_heating
from kybercore.moonraker.events import (
    ConnectionChanged,
    KlippyChanged,
    Notification,
    SessionEvent,
    StatusDelta,
    StatusSnapshot,
)
from kybercore.moonraker.objects import Status
from kybercore.registry.models import PrinterConfig

Change = Literal["state", "heaters", "spool"]
"""What changed on a printer: ``state`` (its connection, Klippy's state, the print's state
or file; a fresh snapshot), ``heaters`` (a temperature or a target) or ``spool`` (its
Spoolman spool, or that spool's weight)."""
OnChange = Callable[[str, Change], None]
OnHistoryJob = Callable[[str, str, str], None]
"""``(printer id, file name, Moonraker history job id)``: a job appeared in its history."""

HISTORY_WINDOW: Final = 50
"""Jobs of Moonraker's history searched (newest first) for an attempt's upload name."""


@dataclass(frozen=True, slots=True)
class Shown:
    """What a printer shows that decides the queue's prints on it."""

    connection: str
    klippy_state: str
    klippy_message: str
    """Why Klippy is not ready (its first line matters), else ""."""
    filename: str
    """``print_stats.filename``: the file printed now or last."""
    state: str
    """``print_stats.state``: standby, printing, paused, complete, cancelled or error."""
    print_duration: float | None
    message: str
    """``print_stats.message``: why a print stopped."""


class Heat(NamedTuple):
    """A printer's heaters, as the heating budget weighs them. Apart from :class:`Shown`
    because it is read on every temperature update (a NamedTuple: cheap to build)."""

    heating: bool
    """Heating toward a target (see :func:`kybercore.jobs.heating.is_heating`)."""
    target_set: bool
    """A heater has a target above 0."""


@dataclass(frozen=True, slots=True)
class QueuePrinter:
    """A printer as the planner weighs it."""

    config: PrinterConfig
    facts: PrinterFacts
    heating: bool


class QueuePrinters(Protocol):
    """The printers the queue plans for, follows and starts prints on."""

    def all(self) -> list[QueuePrinter]:
        """Every configured printer, as it stands now."""

    def shown(self, printer_id: str) -> Shown:
        """What the printer shows now; UnknownPrinter when it is not configured."""

    def heat(self, printer_id: str) -> Heat:
        """What the printer's heaters do now; UnknownPrinter when it is not configured."""

    def listen(self, on_change: OnChange) -> Callable[[], None]:
        """Call ``on_change`` on each change that matters; returns the way to stop."""

    def listen_history(self, on_job: OnHistoryJob) -> Callable[[], None]:
        """Call ``on_job`` when a printer's Moonraker history gains a job (where that is
        heard at all; the tracker looks a job up by name otherwise)."""

    async def upload(self, printer_id: str, name: str, path: Path) -> None:
        """Upload the file at ``path`` to the printer as ``name`` (without starting it)."""

    async def start(self, printer_id: str, name: str) -> None:
        """Ask the printer to print ``name``. PrinterUnreachable: it may or may not have."""

    async def cancel(self, printer_id: str) -> None:
        """Cancel the printer's print."""

    async def history_job(
        self, printer_id: str, upload_name: str, job_id: str | None
    ) -> dict[str, Any] | None:
        """Moonraker's history job of ``upload_name``: by id when bound, else the newest
        one of that name (upload names are unique per attempt); None when there is none."""

    async def download(self, printer_id: str, path: str) -> bytes:
        """A G-code file from the printer's ``gcodes/``."""


# The deltas that make a change: print state and file, Klippy (webhooks), the heaters.
_INTEREST: Final = Interest(
    {
        "print_stats": frozenset({"state", "filename"}),
        "webhooks": None,
        "extruder": None,
        "heater_bed": None,
    }
)


def shown_of(live: LivePrinter) -> Shown:
    """What a printer's live state shows the queue."""
    status = live.status
    stats = status.get("print_stats", {})
    why = status.get("webhooks", {}).get("state_message") or live.klippy_message
    return Shown(
        connection=live.connection,
        klippy_state=live.klippy_state,
        klippy_message=str(why or ""),
        filename=str(stats.get("filename") or ""),
        state=str(stats.get("state") or ""),
        print_duration=finite_number(stats.get("print_duration")),
        message=str(stats.get("message") or ""),
    )


def heat_of(status: Status) -> Heat:
    """What the heaters in ``status`` (Klipper's object names) do."""
    return Heat(is_heating(status), target_set(status))


def target_set(status: Status) -> bool:
    """Whether a heater of the printer has a target above 0."""
    return any(
        (finite_number(status.get(heater, {}).get("target")) or 0) > 0
        for heater in ("extruder", "heater_bed")
    )


class FleetPrinters:
    """The queue's printers in this process: :class:`FleetService`'s sessions."""

    def __init__(self, fleet: FleetService) -> None:
        self._fleet = fleet

    def all(self) -> list[QueuePrinter]:
        """Every configured printer, as it stands now."""
        return [
            QueuePrinter(p.config, facts(p.config, p.live), is_heating(p.live.status))
            for p in self._fleet.sessions.all()
        ]

    def shown(self, printer_id: str) -> Shown:
        """What the printer shows now."""
        return shown_of(self._fleet.sessions.get(printer_id).live)

    def heat(self, printer_id: str) -> Heat:
        """What the printer's heaters do now."""
        return heat_of(self._fleet.sessions.get(printer_id).live.status)

    def listen(self, on_change: OnChange) -> Callable[[], None]:
        """Call ``on_change`` on each change that matters; returns the way to stop."""

        def hear(printer_id: str, event: SessionEvent) -> None:
            if isinstance(event, StatusSnapshot | ConnectionChanged | KlippyChanged):
                on_change(printer_id, "state")
            elif isinstance(event, StatusDelta):
                delta = event.delta
                stats = delta.get("print_stats", {})
                if "state" in stats or "filename" in stats or "webhooks" in delta:
                    on_change(printer_id, "state")
                if "extruder" in delta or "heater_bed" in delta:
                    on_change(printer_id, "heaters")

        stop_listening = self._fleet.listen(hear, _INTEREST)
        stop_watching = self._fleet.sessions.watch_spools(lambda p: on_change(p, "spool"))

        def stop() -> None:
            stop_listening()
            stop_watching()

        return stop

    def listen_history(self, on_job: OnHistoryJob) -> Callable[[], None]:
        """Call ``on_job`` on each ``notify_history_changed`` naming a job and its id."""

        def hear(printer_id: str, event: SessionEvent) -> None:
            if not isinstance(event, Notification) or event.method != "notify_history_changed":
                return
            change = event.params[0] if event.params and isinstance(event.params[0], dict) else {}
            job = change.get("job")
            if isinstance(job, dict):
                name, job_id = job.get("filename"), job.get("job_id")
                if isinstance(name, str) and isinstance(job_id, str):
                    on_job(printer_id, name, job_id)

        return self._fleet.listen(hear, Interest({}))

    async def upload(self, printer_id: str, name: str, path: Path) -> None:
        """Upload the file at ``path`` as ``name``."""
        client = self._fleet.client(printer_id)
        handle = await asyncio.to_thread(path.open, "rb")
        try:
            await client.upload(name, handle)
        finally:
            await asyncio.to_thread(handle.close)

    async def start(self, printer_id: str, name: str) -> None:
        """Ask the printer to print ``name``."""
        await self._fleet.client(printer_id).print_start(name)

    async def cancel(self, printer_id: str) -> None:
        """Cancel the printer's print."""
        await self._fleet.client(printer_id).print_cancel()

    async def history_job(
        self, printer_id: str, upload_name: str, job_id: str | None
    ) -> dict[str, Any] | None:
        """Moonraker's history job of ``upload_name`` (see :class:`QueuePrinters`)."""
        client = self._fleet.client(printer_id)
        if job_id:
            try:
                return await client.history_job(job_id)
            except MoonrakerRpcError as exc:
                if exc.rpc_code != 404:
                    raise
        listing = await client.history_list(HISTORY_WINDOW)
        jobs = listing.get("jobs")
        for job in jobs if isinstance(jobs, list) else []:
            if isinstance(job, dict) and job.get("filename") == upload_name:
                return job
        return None

    async def download(self, printer_id: str, path: str) -> bytes:
        """A G-code file from the printer."""
        return await self._fleet.client(printer_id).download(path)
