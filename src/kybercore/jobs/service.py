"""The job queue as the API and the CLI use it: jobs, copies, printer gates, and the loop.

:class:`QueueService` composes the store (what is decided, in the database), the file
store (what is printed), the dispatcher (what starts where) and the tracker (how each
print ends). Every change goes out to the browsers as a ``{"type": "queue", ...}`` frame on
``/ws``, and every change that can let a copy start wakes the dispatcher.
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from datetime import datetime
from typing import Any, BinaryIO, Final

from kybercore.errors import ActionRejected, KyberCoreError
from kybercore.fleet.service import FleetService
from kybercore.jobs.dispatcher import Dispatcher
from kybercore.jobs.files import JobFiles
from kybercore.jobs.models import LIVE, Attempt, Gate, Job, NewJob, PlateVerdict, Requirements
from kybercore.jobs.printers import FleetPrinters, QueuePrinters
from kybercore.jobs.rules import PrinterSnapshot, WhyLine, never_printable, why
from kybercore.jobs.store import JobStore
from kybercore.jobs.tracker import Tracker

log = logging.getLogger(__name__)

Content = bytes | AsyncIterator[bytes] | BinaryIO
_STARTS_MOVING_ON: Final = frozenset({"attempt_reserved", *(f"attempt_{s}" for s in LIVE)})


class QueueService:
    """The fleet's job queue."""

    def __init__(
        self,
        fleet: FleetService,
        store: JobStore,
        files: JobFiles,
        *,
        printers: QueuePrinters | None = None,
        heating_budget: int | None = 3,
        start_within: float = 60.0,
    ) -> None:
        """``printers``: how the queue reaches the fleet's printers (default: this
        process's sessions, :class:`FleetPrinters`). ``heating_budget``: at most that many
        printers of one power group heating at once (None: no limit). ``start_within``:
        seconds a printer has, after accepting a start, to show it printing before the
        attempt is ``failed_to_start``."""
        self.fleet = fleet
        self.store = store
        self.files = files
        self.printers = printers or FleetPrinters(fleet)
        self.tracker = Tracker(self.printers, store, on_ended=self._wake)
        self.dispatcher = Dispatcher(
            self.printers,
            store,
            files,
            self.tracker,
            heating_budget=heating_budget,
            start_within=start_within,
        )
        store.listen(self.changed)

    # -- lifecycle ---------------------------------------------------------------------

    async def start(self) -> None:
        """Settle what an earlier run left unresolved, then start dispatching."""
        await self.tracker.start()
        self.dispatcher.start()

    async def stop(self) -> None:
        """Stop dispatching and tracking (the database keeps every state)."""
        await self.dispatcher.stop()
        await self.tracker.stop()

    def _wake(self) -> None:
        self.dispatcher.wake()

    def changed(self, kind: str, payload: dict[str, Any]) -> None:
        """The store committed a change (on NATS: here or in another front): tell the
        browsers, and plan again unless it was a start moving on (the dispatcher makes
        those, and frees nothing by them)."""
        self.fleet.hub.event({"type": "queue", "kind": kind, **payload})
        if payload.get("event") not in _STARTS_MOVING_ON:
            self.dispatcher.wake()

    # -- jobs --------------------------------------------------------------------------

    async def add_job(
        self,
        filename: str,
        content: Content,
        *,
        quantity: int = 1,
        priority: int = 0,
        not_before: datetime | None = None,
        requirements: Requirements | None = None,
        allow_mismatch: bool = False,
        max_attempts: int = 3,
        user: str,
    ) -> Job:
        """Store the file and queue ``quantity`` copies of it; refused when no configured
        printer could ever print it."""
        stored = await self.files.put(filename, content)
        new = NewJob(
            file=stored,
            quantity=quantity,
            priority=priority,
            not_before=not_before,
            requirements=requirements or Requirements(),
            allow_mismatch=allow_mismatch,
            max_attempts=max_attempts,
        )
        refusals = never_printable(new, await self._snapshots())
        if refusals:
            raise ActionRejected(
                "No printer of the fleet could ever print this job: "
                + " ".join(f"{line.subject}: {line.en}" for line in refusals)
                + " Change its requirements or add a printer that fits.",
                code="never_printable",
                reasons=[_reason(line, "block") for line in refusals],
            )
        return await self.store.create_job(new, user)

    async def add_job_from_printer(self, printer_id: str, path: str, **options: Any) -> Job:
        """Queue a file already on a printer (downloaded once, then stored here)."""
        content = await self.printers.download(printer_id, path)
        return await self.add_job(path.rsplit("/", 1)[-1], content, **options)

    async def jobs(self, include_finished: bool = False) -> list[Job]:
        """Jobs in queue order (priority, then position)."""
        return await self.store.jobs(include_finished)

    async def job(self, job_id: int) -> Job:
        """One job."""
        return await self.store.job(job_id)

    async def attempts(self, job_id: int | None = None) -> list[Attempt]:
        """A job's attempts (every job's when None)."""
        return await self.store.attempts(job_id)

    async def update_job(self, job_id: int, *, user: str, **changes: Any) -> Job:
        """Change a job's priority, quantity, not_before or max_attempts."""
        return await self.store.update_job(job_id, user=user, **changes)

    async def move_job(self, job_id: int, before: int | None, user: str) -> Job:
        """Put a job before another (None: last)."""
        return await self.store.move_job(job_id, before, user)

    async def requeue_job(self, job_id: int, user: str) -> Job:
        """A blocked job goes back to the queue, its failures forgotten."""
        return await self.store.requeue_job(job_id, user)

    async def cancel_job(self, job_id: int, user: str, confirm: bool = False) -> Job:
        """Cancel a job. With copies on printers, only when ``confirm``: their prints are
        cancelled on the printers too."""
        live = await self.store.attempts(job_id, live_only=True)
        if live and not confirm:
            raise ActionRejected(
                f"Job {job_id} has {len(live)} cop{'y' if len(live) == 1 else 'ies'} on "
                f"printers ({', '.join(a.printer for a in live)}): cancelling it cancels "
                "those prints. Send it again with confirm=true to go ahead.",
                code="confirmation_required",
                reasons=[_in_flight(a) for a in live],
            )
        job, live = await self.store.cancel_job(job_id, user, reason=f"cancelled by {user}")
        for attempt in live:
            await self._cancel_attempt(attempt, user)
        return job

    async def _cancel_attempt(self, attempt: Attempt, user: str) -> None:
        """Stop a live attempt of a cancelled job: a print running is cancelled on the
        printer (the tracker then ends the attempt as the printer says); one still
        starting ends here."""
        await self.dispatcher.abandon(attempt.id)
        attempt = await self.store.attempt(attempt.id)
        if not attempt.live:
            return
        try:
            shown = self.printers.shown(attempt.printer)
            if shown.filename == attempt.upload_name and shown.state in ("printing", "paused"):
                await self.printers.cancel(attempt.printer)
        except KyberCoreError as exc:
            log.warning("%s: could not cancel the job's print: %s", attempt.printer, exc)
        if attempt.state not in ("printing", "paused"):
            reason = f"Job cancelled by {user} before the print started."
            ended = await self.store.finish(attempt.id, "cancelled", reason=reason)
            self.tracker.follow(ended)

    # -- the queue ---------------------------------------------------------------------

    async def pause(self, user: str) -> None:
        """Start nothing new (prints running go on)."""
        await self.store.set_queue_paused(True, user)

    async def resume(self, user: str) -> None:
        """Dispatch again."""
        await self.store.set_queue_paused(False, user)

    async def paused(self) -> bool:
        """Whether the queue is paused."""
        return await self.store.queue_paused()

    # -- printers ----------------------------------------------------------------------

    async def clear(
        self, printer: str, verdict: PlateVerdict, cause: str = "", *, user: str
    ) -> Gate:
        """The plate is clear: ``good`` counts the copy, ``bad`` sends it back."""
        gate = await self.store.clear(printer, verdict, cause=cause, user=user)
        self._wake()
        return gate

    async def hold(self, printer: str, reason: str, user: str) -> Gate:
        """Keep the queue off a printer."""
        gate = await self.store.hold(printer, reason, user)
        self._wake()
        return gate

    async def release(self, printer: str, user: str) -> Gate:
        """Give a held printer (or one in maintenance) back to the queue."""
        gate = await self.store.release(printer, user)
        self._wake()
        return gate

    async def gates(self) -> dict[str, Gate]:
        """Every printer's gate (a printer with none yet is available)."""
        return await self.store.gates()

    async def why(self, job_id: int) -> list[WhyLine]:
        """Per printer (and for the queue and power groups), why the job is not running
        there right now."""
        job = await self.store.job(job_id)
        dispatcher = self.dispatcher
        return why(
            job,
            await self._snapshots(),
            queue=await self.store.jobs(),
            heating_budget=dispatcher.heating_budget,
            starting=dispatcher.starting(),
            now=dispatcher.now(),
            paused=await self.store.queue_paused(),
            attempts_per_printer=await self.store.attempts_per_printer([job_id]),
            memo=dispatcher.memo,
        )

    async def _snapshots(self) -> list[PrinterSnapshot]:
        gates = await self.store.gates()
        usage = await self.store.usage(self.dispatcher.usage_since())
        return self.dispatcher.snapshots(gates, usage)


def _reason(line: WhyLine, level: str) -> dict[str, str]:
    return {"code": line.code, "level": level, "en": f"{line.subject}: {line.en}",
            "es": f"{line.subject}: {line.es}"}  # fmt: skip


def _in_flight(attempt: Attempt) -> dict[str, str]:
    return {
        "code": "copy_in_flight",
        "level": "warn",
        "en": f"Copy {attempt.copy} is {attempt.state} on {attempt.printer}.",
        "es": f"La copia {attempt.copy} está {attempt.state} en {attempt.printer}.",
    }
