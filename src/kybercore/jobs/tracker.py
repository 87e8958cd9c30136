"""Outcomes of the queue's prints: every attempt on a printer is followed to its real end.

A printing attempt is known on the printer by its unique ``upload_name``: Klippy's
``print_stats.filename`` while it prints, and the ``filename`` of its job in Moonraker's
history (bound by ``notify_history_changed``, or looked up). What the printer shows decides:

* ``print_stats`` naming our file says it all: printing, paused, complete, cancelled,
  error; Klippy shut down under a print that was running means it failed.
* When it no longer names our file (Klippy restarted, another print started, KyberCore was
  away), Moonraker's history says how the print ended.

The tracker settles a printer's attempt after every status change that matters, after
every (re)subscription (each reconnect and each Klippy restart brings a snapshot), at
start-up, and on a slow safety tick. An attempt left ``pending/uploading/starting`` by an
earlier KyberCore process is settled here too, by asking the printer whether the start
happened. Settling one printer is serialized; nothing is polled fast.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Final

from kybercore.core.numbers import finite_number
from kybercore.errors import ActionRejected, KyberCoreError
from kybercore.jobs.models import Attempt, AttemptState
from kybercore.jobs.printers import Change, QueuePrinters, Shown
from kybercore.jobs.store import JobStore

log = logging.getLogger(__name__)

RESTARTED: Final = "KyberCore restarted before the start was confirmed"
NOT_STARTING: Final = frozenset({"pending", "uploading"})
"""Live states in which no start was sent to the printer yet."""


@dataclass(frozen=True)
class Outcome:
    """What the printer says about one attempt: still running, or how it ended."""

    state: AttemptState
    reason: str = ""
    print_seconds: float | None = None

    @property
    def ended(self) -> bool:
        """Whether the print is over."""
        return self.state not in ("printing", "paused")


def seen(shown: Shown, upload_name: str) -> Outcome | None:
    """What the printer shows about the print of ``upload_name``; None when it does not
    show that print (another file, none, or Klippy not there to tell)."""
    if shown.filename != upload_name or shown.klippy_state not in ("ready", "shutdown"):
        return None
    state, seconds, message = shown.state, shown.print_duration, shown.message
    if state in ("printing", "paused", "error") and shown.klippy_state == "shutdown":
        return Outcome("failed", shut_down(shown), seconds)
    if state == "printing":
        return Outcome("printing")
    if state == "paused":
        return Outcome("paused")
    if state == "complete":
        return Outcome("completed", print_seconds=seconds)
    if state == "cancelled":
        return Outcome("cancelled", message or "The print was cancelled on the printer.", seconds)
    if state == "error":
        return Outcome("failed", f"Klipper stopped the print: {message or 'error'}", seconds)
    return None


def shut_down(shown: Shown) -> str:
    """Why a print Klipper shut down under failed: the first line of Klippy's message (else
    ``print_stats``' message)."""
    why = shown.klippy_message.strip()
    why = why.splitlines()[0] if why else shown.message or "no message"
    return f"Klipper shut down mid-print: {why}"


def still_shut_down(shown: Shown, job: Mapping[str, Any]) -> bool:
    """Whether the history ``job`` ended in the shutdown the printer still shows: Klippy is
    shut down with the job's file still named (no print and no restart since)."""
    return (
        job.get("status") == "klippy_shutdown"
        and shown.klippy_state == "shutdown"
        and shown.filename == job.get("filename")
    )


def from_history(job: Mapping[str, Any], shown: Shown | None = None) -> Outcome:
    """The outcome a Moonraker history job records. Ended by the shutdown ``shown`` still
    shows, it carries Klippy's message, as :func:`seen` words it: a front's view blanks the
    print's state while Klippy is not ready, so there the history tells the print was cut
    short, and the view still has Klippy's message."""
    status = str(job.get("status", ""))
    seconds = finite_number(job.get("print_duration"))
    if shown is not None and still_shut_down(shown, job):
        return Outcome("failed", shut_down(shown), seconds)
    if status == "in_progress":
        return Outcome("printing")
    if status == "completed":
        return Outcome("completed", print_seconds=seconds)
    if status == "cancelled":
        return Outcome("cancelled", "The print was cancelled on the printer.", seconds)
    reasons = {
        "error": "Klipper stopped the print with an error (Moonraker's history).",
        "klippy_shutdown": "Klipper shut down mid-print (Moonraker's history).",
        "klippy_disconnect": "Klipper disconnected mid-print (Moonraker's history).",
        "interrupted": "Moonraker restarted during the print and cannot tell how it "
        "ended; check the part before clearing the plate.",
        "server_exit": "Moonraker stopped during the print and cannot tell how it ended; "
        "check the part before clearing the plate.",
    }
    return Outcome("failed", reasons.get(status, f"Moonraker's history says '{status}'."), seconds)


class Tracker:
    """Follows the queue's attempts on the printers and settles how they end."""

    def __init__(
        self, printers: QueuePrinters, store: JobStore, *, on_ended: Callable[[], None]
    ) -> None:
        """``on_ended`` is called after an attempt ended (a printer may be free)."""
        self._printers = printers
        self._store = store
        self._on_ended = on_ended
        self._live: dict[str, Attempt] = {}
        """Each printer's live attempt (one at most: its gate holds it)."""
        self._driven: set[int] = set()
        """Attempts this process is starting now: the dispatcher settles those."""
        self._job_ids: dict[str, str] = {}
        """Moonraker history job ids heard in ``notify_history_changed``, by file name."""
        self._settling: dict[str, asyncio.Task[None]] = {}
        self._again: set[str] = set()
        self._stop_listening: list[Callable[[], None]] = []

    # -- lifecycle ---------------------------------------------------------------------

    async def start(self) -> None:
        """Load every unresolved attempt and settle each printer that can already tell."""
        self._stop_listening = [
            self._printers.listen(self._hear),
            self._printers.listen_history(self._heard_history),
        ]
        for attempt in await self._store.attempts(live_only=True):
            self._live[attempt.printer] = attempt
        self.check_all()

    async def stop(self) -> None:
        """Stop listening and settling (unresolved attempts stay in the store)."""
        for stop in self._stop_listening:
            stop()
        self._stop_listening = []
        tasks = list(self._settling.values())
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)

    # -- what the dispatcher tells ---------------------------------------------------

    def driving(self, attempt: Attempt) -> None:
        """The dispatcher reserved ``attempt`` and is starting it."""
        self._live[attempt.printer] = attempt
        self._driven.add(attempt.id)

    def follow(self, attempt: Attempt) -> None:
        """``attempt`` started (or the dispatcher gave it up): settle it from now on."""
        self._driven.discard(attempt.id)
        if attempt.live:
            self._live[attempt.printer] = attempt
        elif self._live.get(attempt.printer, attempt).id == attempt.id:
            self._live.pop(attempt.printer, None)
        self.kick(attempt.printer)

    def job_id(self, upload_name: str) -> str | None:
        """Moonraker's history id of the print of ``upload_name``, when heard."""
        return self._job_ids.get(upload_name)

    def check_all(self) -> None:
        """Settle every printer with an unresolved attempt (start-up and the slow tick)."""
        for printer_id in list(self._live):
            self.kick(printer_id)

    # -- events ------------------------------------------------------------------------

    def _hear(self, printer_id: str, change: Change) -> None:
        if change == "state" and printer_id in self._live:
            self.kick(printer_id)

    def _heard_history(self, printer_id: str, filename: str, job_id: str) -> None:
        attempt = self._live.get(printer_id)
        if attempt is None or filename != attempt.upload_name:
            return
        self._job_ids[filename] = job_id
        self.kick(printer_id)  # added: bind it; finished: settle it

    def kick(self, printer_id: str) -> None:
        """Settle the printer's attempt soon; one settling per printer at a time."""
        if printer_id in self._settling:
            self._again.add(printer_id)
            return
        task = asyncio.create_task(self._settle_loop(printer_id), name=f"settle:{printer_id}")
        self._settling[printer_id] = task

    async def _settle_loop(self, printer_id: str) -> None:
        try:
            while True:
                self._again.discard(printer_id)
                try:
                    await self._settle(printer_id)
                except KyberCoreError as exc:
                    # The printer went away mid-way (or the database refused): the next
                    # snapshot, event or tick tries again.
                    log.info("%s: cannot settle the queue's print yet: %s", printer_id, exc)
                except Exception:
                    log.exception("%s: settling the queue's print failed", printer_id)
                if printer_id not in self._again:
                    return
        finally:
            self._settling.pop(printer_id, None)

    # -- settling ----------------------------------------------------------------------

    async def _settle(self, printer_id: str) -> None:
        known = self._live.get(printer_id)
        if known is None or known.id in self._driven:
            return
        attempt = await self._store.attempt(known.id)
        if not attempt.live:
            self._forget(attempt)
            return
        if attempt.state in NOT_STARTING:
            # Left by an earlier process before it sent any start: nothing to ask.
            await self._end(attempt, Outcome("failed_to_start", RESTARTED))
            return
        try:
            shown = self._printers.shown(printer_id)
        except KyberCoreError:
            return  # removed from printers.json: kept until it comes back
        if shown.connection != "online" or shown.klippy_state not in ("ready", "shutdown"):
            return  # the next snapshot tells
        outcome = seen(shown, attempt.upload_name)
        job_id = attempt.moonraker_job_id or self._job_ids.get(attempt.upload_name)
        if outcome is None or (outcome.ended and not job_id):
            # Not shown: how did it end? Or ended unbound (its start was heard by an
            # earlier process): which history job was it?
            try:
                job = await self._printers.history_job(printer_id, attempt.upload_name, job_id)
            except KyberCoreError:
                if outcome is None:
                    raise
                job = None
            if job is not None:
                job_id = str(job.get("job_id") or "") or job_id
                unsaid = still_shut_down(shown, job) and not shown.klippy_message.strip()
                if outcome is None and unsaid:
                    # On a front, Klippy's message may come in a patch after its state's:
                    # that patch settles again (a restart does, if it never comes).
                    return
                outcome = outcome or from_history(job, shown)
        if outcome is None:
            outcome = (
                Outcome("failed_to_start", RESTARTED)
                if attempt.state == "starting"
                else Outcome(
                    "failed",
                    f"{printer_id} shows no trace of the print (neither running nor in "
                    "Moonraker's history); check the printer before clearing the plate.",
                )
            )
        await self._apply(attempt, outcome, job_id)

    async def _apply(self, attempt: Attempt, outcome: Outcome, job_id: str | None) -> None:
        if attempt.state == "starting" and outcome.state != "failed_to_start":
            # It did start (an earlier process sent the start): it is a print of ours.
            attempt = await self._store.advance(attempt.id, "printing", moonraker_job_id=job_id)
        if not outcome.ended:
            if outcome.state != attempt.state or (job_id and job_id != attempt.moonraker_job_id):
                attempt = await self._store.advance(
                    attempt.id, outcome.state, moonraker_job_id=job_id
                )
            self._live[attempt.printer] = attempt
            return
        await self._end(attempt, outcome, job_id)

    async def _end(self, attempt: Attempt, outcome: Outcome, job_id: str | None = None) -> None:
        try:
            ended = await self._store.finish(
                attempt.id,
                outcome.state,
                reason=outcome.reason,
                print_seconds=outcome.print_seconds,
                moonraker_job_id=job_id,
            )
        except ActionRejected as exc:
            # Someone else ended it first (a cancel, another process): theirs stands.
            log.info("%s: attempt %d already ended: %s", attempt.printer, attempt.id, exc)
            ended = await self._store.attempt(attempt.id)
        log.info(
            "%s: attempt %d (job %d) %s%s",
            attempt.printer, attempt.id, attempt.job_id, ended.state,
            f": {ended.reason}" if ended.reason else "",
        )  # fmt: skip
        self._forget(ended)
        self._on_ended()

    def _forget(self, attempt: Attempt) -> None:
        if self._live.get(attempt.printer, attempt).id == attempt.id:
            self._live.pop(attempt.printer, None)
        self._job_ids.pop(attempt.upload_name, None)
