"""What the queue needs a person for: plates left waiting to be cleared, and queued jobs
that no printer takes.

Read every ``queue_poll`` seconds by :class:`~kybercore.notify.service.NotifyService`,
from the queue's own answers (its gates, its jobs, :meth:`QueueService.why`); each finding
is a :class:`FleetEvent` once per episode:

- ``plate_waiting``: a printer's gate has been ``awaiting_clear`` longer than
  ``plate_wait_s`` (once per print that left it so: ``Gate.since``).
- ``job_blocked``: a queued job with copies left has made no progress (no copy started,
  done or failed) for ``job_blocked_s`` and :meth:`QueueService.why` names no printer that
  is merely busy or next in line: every printer is ruled out (wrong material, offline,
  held, a plate to clear…). Also a job the queue itself moved to ``blocked`` (it failed
  ``max_attempts`` times), at once. A paused queue, or a job waiting for its start time,
  is the operator's choice, never news.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import Any, Final

from kybercore.errors import KyberCoreError
from kybercore.jobs.models import Gate, Job
from kybercore.jobs.reasons import WhyLine
from kybercore.jobs.service import QueueService
from kybercore.notify.models import FleetEvent, NoiseSettings, PrinterRef
from kybercore.notify.printers import NotifyPrinters

log = logging.getLogger(__name__)

WAITING_ITS_TURN: Final = frozenset({
    # a printer that will take it by itself, in time
    "assigned", "eligible", "ranked_lower", "taken_by_job", "printer_busy",
    "printer_starting", "waiting_for_power",
    # the job as a whole: held back on purpose, or nothing left to start
    "queue_paused", "not_before", "no_copies_left", "job_done", "job_cancelled",
})  # fmt: skip
"""Reasons of :meth:`QueueService.why` that mean "it waits its turn", not "it is stuck"."""
WHY_PER_ROUND: Final = 20
"""At most this many jobs asked :meth:`QueueService.why` per round (each runs a planning
round); the others are asked at the next one."""
REASON_LINES: Final = 4
"""Lines of the reason a job_blocked event quotes ("+N more" after them)."""


@dataclass
class _Watch:
    """A queued job's progress as last seen, and since when it has not moved."""

    progress: tuple[int, int, int]
    since: float
    told: bool = False


class QueueChecks:
    """Plates waiting and jobs blocked, once per episode each."""

    def __init__(self, printers: NotifyPrinters, queue: QueueService) -> None:
        self._printers = printers
        self._queue = queue
        self._plates: dict[str, datetime] = {}
        """Printers whose waiting plate was told, with that gate's ``since``."""
        self._jobs: dict[int, _Watch] = {}
        self._blocked: set[int] | None = None
        """Jobs in the queue's ``blocked`` state at the last round (None: no round yet)."""
        self.rounds = 0
        """Rounds completed (tests wait on it)."""

    async def run(self, settings: NoiseSettings, now: float, at: datetime) -> list[FleetEvent]:
        """One round: the events found (``now`` monotonic seconds, ``at`` UTC)."""
        events = await self._plates_waiting(settings, at)
        events += await self._jobs_blocked(settings, now, at)
        self.rounds += 1
        return events

    # -- plates ------------------------------------------------------------------------

    async def _plates_waiting(self, settings: NoiseSettings, at: datetime) -> list[FleetEvent]:
        gates = await self._queue.gates()
        waiting = {p: g for p, g in gates.items() if g.state == "awaiting_clear"}
        self._plates = {p: s for p, s in self._plates.items() if p in waiting}
        events = []
        for printer_id, gate in waiting.items():
            minutes = (at - gate.since).total_seconds() / 60
            if minutes * 60 < settings.plate_wait_s or self._plates.get(printer_id) == gate.since:
                continue
            ref = self._ref(printer_id)
            if ref is None:
                continue
            self._plates[printer_id] = gate.since
            params = {"minutes": int(minutes), "since": _iso(gate.since)}
            params |= await self._job_of(gate)
            events.append(FleetEvent("plate_waiting", at, ref, params))
        return events

    async def _job_of(self, gate: Gate) -> dict[str, Any]:
        """The job whose print waits on the plate: its id and file name, when known."""
        if gate.attempt_id is None:
            return {}
        try:
            attempt = await self._queue.store.attempt(gate.attempt_id)
            job = await self._queue.job(attempt.job_id)
        except KyberCoreError:
            return {}
        return {"job_id": job.id, "job_name": job.file.name}

    def _ref(self, printer_id: str) -> PrinterRef | None:
        try:
            return self._printers.get(printer_id).ref
        except KyberCoreError:
            return None  # a gate of a printer no longer in printers.json

    # -- jobs --------------------------------------------------------------------------

    async def _jobs_blocked(
        self, settings: NoiseSettings, now: float, at: datetime
    ) -> list[FleetEvent]:
        jobs = await self._queue.jobs()
        events = self._newly_blocked(jobs, at)
        if await self._queue.paused():
            self._jobs.clear()
            return events
        stale = []
        watched = {}
        for job in jobs:
            if job.state != "queued" or job.left <= 0:
                continue
            if job.not_before is not None and job.not_before > at:
                continue
            progress = (job.done, job.in_flight, job.failures)
            watch = self._jobs.get(job.id)
            if watch is None or watch.progress != progress:
                watch = _Watch(progress, now)
            watched[job.id] = watch
            if not watch.told and now - watch.since >= settings.job_blocked_s:
                stale.append((job, watch))
        self._jobs = watched
        for job, watch in stale[:WHY_PER_ROUND]:
            lines = await self._queue.why(job.id)
            if not lines or any(line.code in WAITING_ITS_TURN for line in lines):
                continue
            watch.told = True
            minutes = int((now - watch.since) // 60)
            events.append(_blocked(job, at, _reason(lines, "en"), _reason(lines, "es"), minutes))
        return events

    def _newly_blocked(self, jobs: Sequence[Job], at: datetime) -> list[FleetEvent]:
        """Jobs the queue blocked since the last round (none on the first: a restart of
        KyberCore is silent)."""
        blocked = {job.id: job for job in jobs if job.state == "blocked"}
        before, self._blocked = self._blocked, set(blocked)
        if before is None:
            return []
        return [
            _blocked(job, at, job.reason, job.reason, None)
            for job_id, job in blocked.items()
            if job_id not in before
        ]


def _blocked(
    job: Job, at: datetime, reason: str, reason_es: str, minutes: int | None
) -> FleetEvent:
    params: dict[str, Any] = {
        "job_id": job.id, "job_name": job.file.name, "state": job.state,
        "reason": reason, "reason_es": reason_es, "left": job.left,
    }  # fmt: skip
    if minutes is not None:
        params["minutes"] = minutes
    return FleetEvent("job_blocked", at, None, params)


def _reason(lines: Sequence[WhyLine], language: str) -> str:
    """``printer-1: PETG loaded, job needs PLA; printer-2: offline (+3 more)``."""
    texts = [f"{line.subject}: {line.es if language == 'es' else line.en}" for line in lines]
    shown = "; ".join(texts[:REASON_LINES])
    more = len(texts) - REASON_LINES
    if more > 0:
        shown += f" (+{more} más)" if language == "es" else f" (+{more} more)"
    return shown


def _iso(moment: datetime) -> str:
    return moment.isoformat(timespec="seconds").replace("+00:00", "Z")
