"""The job queue's printers on a front (``kybercore front``): :class:`FrontPrinters`.

A front holds no printer socket: each printer's Moonraker session lives in the ingest
worker that owns its slot. So the queue is split the way the rest of a front is:

- the dispatcher plans, and the tracker follows, from the front's copy of the views (the
  owners' patches, :mod:`.follow`): validation's facts are read back from a view
  (:func:`~kybercore.core.view.facts_of_view`), what a printer shows from the view's job,
  Klippy and heater fields, and news of a change from the patches as they are applied;
- what the queue does on a printer goes to its owner as a command (:mod:`.commands`),
  which does it with :class:`~kybercore.jobs.printers.FleetPrinters` over its own session,
  exactly as ``kybercore serve``'s queue would (:mod:`.ops`); a file crosses the broker's
  object store: to a printer first (:mod:`.uploads`), from one to be queued
  (:mod:`.jobfiles`).

Where a front's answers differ from :class:`FleetPrinters`' (the views are what browsers
get, not Moonraker's raw status), the method says so.
"""

from __future__ import annotations

import asyncio
import io
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Final

import nats.errors

from kybercore.core.numbers import finite_number
from kybercore.core.view import facts_of_view
from kybercore.errors import PrinterUnreachable
from kybercore.jobs.printers import (
    Change,
    Heat,
    OnChange,
    OnHistoryJob,
    QueuePrinter,
    Shown,
    heat_of,
)
from kybercore.scale.front import FrontFleet
from kybercore.scale.jobfiles import JobFileBucket

_STATE_KEYS: Final = frozenset({"connection", "klippy_state", "klippy_message"})
"""Top-level view fields whose change is a ``state`` change (Klippy's message with its state,
as webhooks' deltas are in :class:`FleetPrinters`)."""
_JOB_KEYS: Final = ("state", "filename")


def changes_of(patch: Mapping[str, Any] | None) -> list[Change]:
    """What a patch to a printer's view changed, as the queue hears it; a whole new view
    (None) is a ``state`` change, as a fresh snapshot is in one process."""
    if patch is None:
        return ["state"]
    found: list[Change] = []
    job = patch.get("job")
    if not _STATE_KEYS.isdisjoint(patch) or (
        isinstance(job, dict) and any(key in job for key in _JOB_KEYS)
    ):
        found.append("state")
    if "extruder" in patch or "bed" in patch:
        found.append("heaters")
    if "spool" in patch or "spoolman" in patch:  # the spool, or Spoolman's state
        found.append("spool")
    return found


def heaters_of(view: Mapping[str, Any]) -> dict[str, Any]:
    """The view's heaters under Klipper's object names, for the queue's heater rules
    (:func:`~kybercore.jobs.printers.heat_of`)."""
    return {"extruder": view.get("extruder") or {}, "heater_bed": view.get("bed") or {}}


def shown_of_view(view: Mapping[str, Any]) -> Shown:
    """What a printer's view shows the queue. Unlike :func:`~kybercore.jobs.printers.shown_of`
    on the live state: ``state`` is "" while Klippy is not ready (the view blanks it);
    ``print_duration`` is in whole seconds, 0 before a print; ``message`` falls back to the
    display's message (M117); ``klippy_message`` is the session's."""
    job: Mapping[str, Any] = view.get("job") or {}
    return Shown(
        connection=str(view.get("connection") or ""),
        klippy_state=str(view.get("klippy_state") or ""),
        klippy_message=str(view.get("klippy_message") or ""),
        filename=str(job.get("filename") or ""),
        state=str(job.get("state") or ""),
        print_duration=finite_number(job.get("print_duration")),
        message=str(job.get("message") or ""),
    )


class FrontPrinters:
    """The queue's printers on a front: the front's views, and the owners' work by command
    (see the module docstring)."""

    def __init__(self, fleet: FrontFleet) -> None:
        self._fleet = fleet

    def all(self) -> list[QueuePrinter]:
        """Every printer of the registry as the front knows it now. One no owner has
        reported yet shows ``connecting``, one whose owner went silent ``stale``: the
        planner starts nothing on either."""
        printers = []
        for config in self._fleet.configs():
            view = self._fleet.current_view(config.id)
            heating = heat_of(heaters_of(view)).heating
            printers.append(QueuePrinter(config, facts_of_view(config, view), heating))
        return printers

    def shown(self, printer_id: str) -> Shown:
        """What the printer's view shows now (see :func:`shown_of_view`); UnknownPrinter
        when it is not in the registry."""
        return shown_of_view(self._fleet.current_view(printer_id))

    def heat(self, printer_id: str) -> Heat:
        """What the printer's heaters do in its view (temperatures rounded to 0.1 °C)."""
        return heat_of(heaters_of(self._fleet.current_view(printer_id)))

    def listen(self, on_change: OnChange) -> Callable[[], None]:
        """Call ``on_change`` for each change of a view that matters (see
        :func:`changes_of`), as the front applies it; returns the way to stop."""

        def hear(printer_id: str, patch: dict[str, Any] | None) -> None:
            for change in changes_of(patch):
                on_change(printer_id, change)

        return self._fleet.watch(hear)

    def listen_history(self, on_job: OnHistoryJob) -> Callable[[], None]:
        """Nothing to hear: a front gets the views, not Moonraker's notifications, so the
        tracker finds each job in the history by its upload name (:meth:`history_job`)."""
        return _nothing

    async def upload(self, printer_id: str, name: str, path: Path) -> None:
        """Stream the file to the printer's owner through the broker, which uploads it (not
        started); the owner's error is raised (TransferFailed: nothing reached the printer;
        OutcomeUnknown: the file may or may not be there)."""
        handle = await asyncio.to_thread(path.open, "rb")
        try:
            await self._fleet.upload(printer_id, name, handle)
        finally:
            await asyncio.to_thread(handle.close)

    async def start(self, printer_id: str, name: str) -> None:
        """Have the printer's owner start ``name``. PrinterUnreachable: it may or may not
        have started (OutcomeUnknown, a PrinterUnreachable: the owner went silent; the
        broker away); OwnerMoving (one too) says nothing was sent."""
        await self._ask(printer_id, "print_start", name=name)

    async def cancel(self, printer_id: str) -> None:
        """Have the printer's owner cancel its print."""
        await self._ask(printer_id, "print_cancel")

    async def history_job(
        self, printer_id: str, upload_name: str, job_id: str | None
    ) -> dict[str, Any] | None:
        """Moonraker's history job of ``upload_name``, looked up by the printer's owner
        (see :class:`~kybercore.jobs.printers.QueuePrinters`)."""
        found: dict[str, Any] | None = await self._ask(
            printer_id, "history_job", upload_name=upload_name, job_id=job_id
        )
        return found

    async def download(self, printer_id: str, path: str) -> bytes:
        """The printer's file, by way of the broker's ``kc_jobfiles``: the owner downloads
        it there under its sha256 (see :mod:`.jobfiles`), and it is read back here, checked.
        In memory once, as :class:`FleetPrinters` has it; the queue then stores it, already
        shared. A file the printer does not have raises what it raises in ``serve``;
        TransferFailed when the broker did not take it or give it back."""
        shared = await self._ask(printer_id, "fetch_file", path=path)
        copy = io.BytesIO()
        await JobFileBucket(self._fleet.nc).fetch(str(shared["sha256"]), copy)
        return copy.getvalue()  # the buffer itself, not a copy of it

    async def _ask(self, printer_id: str, op: str, **args: Any) -> Any:
        try:
            return await self._fleet.command(printer_id, op, **args)
        except nats.errors.Error as exc:
            # The broker connection failed under the command (closed, draining): whether the
            # owner got it is unknown, as after any lost connection to a printer.
            raise PrinterUnreachable(
                f"the NATS broker failed while asking the printer's KyberCore worker "
                f"({type(exc).__name__}): whether '{op}' ran is unknown.",
                printer=printer_id,
            ) from exc


def _nothing() -> None:
    """Stops nothing."""
