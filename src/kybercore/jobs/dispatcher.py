"""The dispatch loop: plan when something changed, reserve, then start each copy for real.

A planning round runs when something that can change a decision happens: a printer's print
state, Klippy or connection changed, a printer stopped (or started) heating, its Spoolman
spool changed (another one set active, or its weight read after a print), a job, a gate
or the queue changed (:meth:`Dispatcher.wake`), plus a slow tick for ``not_before`` times.
Nothing is polled fast, and rounds start at least ``round_gap`` apart: the wakes in between
make one round. A round asks :func:`kybercore.jobs.rules.plan` what to start where,
and reserves each assignment in the store (atomic: losing a race to another loop or
process only means someone else dispatched that copy).

Each reserved attempt then runs in its own task: upload the stored file under the
attempt's unique name (no ``print`` flag), start it, and wait until Klippy's
``print_stats`` shows ``printing`` that very file. Moonraker answering "ok" (or an upload
answering 201) is never taken for a start: a start not seen within ``start_within`` seconds
is ``failed_to_start``, which holds the printer with the reason and sends the copy back to
the queue, to be retried elsewhere.

The heating budget counts the printers heating now plus the starts in progress: a start
counts from its reservation until the printer is seen heating (or, for a file that does not
heat, until it prints), so a round never starts more than the budget allows before the
first temperatures arrive.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from functools import partial
from typing import Final

from kybercore.aio import cancel_and_wait
from kybercore.core.numbers import finite_number
from kybercore.db.outage import Outage
from kybercore.errors import ActionRejected, KyberCoreError, PrinterUnreachable
from kybercore.jobs.files import JobFiles
from kybercore.jobs.models import Attempt, Gate, Job
from kybercore.jobs.printers import Change, QueuePrinter, QueuePrinters
from kybercore.jobs.rules import Memo, Plan, PrinterSnapshot, placeable, plan, power_group
from kybercore.jobs.store import JobStore
from kybercore.jobs.tracker import Tracker, seen

log = logging.getLogger(__name__)

TICK_SECONDS: Final = 30.0
"""The slow tick: ``not_before`` times come due, and a safety check of every print."""
ROUND_GAP_SECONDS: Final = 0.5
"""Rounds start at least this far apart. While a job waits, any printer's state change
wakes a round, and a round reads every printer (~10 ms at 5,000, hundreds when all are
free): a farm's changes, a few a second and thousands in a bulk pause, would otherwise
keep planning back to back. Half a second is nothing next to a print's start."""
RETRY_SECONDS: Final = 5.0
"""After a round failed (the database away), the next one waits this long."""
USAGE_DAYS: Final = 30
"""Wear-levelling counts the print time of the last USAGE_DAYS days."""
_EPOCH: Final = datetime(1970, 1, 1, tzinfo=UTC)


class Dispatcher:
    """Plans and starts the queue's copies on the fleet's printers."""

    def __init__(
        self,
        printers: QueuePrinters,
        store: JobStore,
        files: JobFiles,
        tracker: Tracker,
        *,
        heating_budget: int | None = 3,
        start_within: float = 60.0,
        tick: float = TICK_SECONDS,
        round_gap: float = ROUND_GAP_SECONDS,
        clock: Callable[[], datetime] = lambda: datetime.now(UTC),
    ) -> None:
        self._printers = printers
        self._store = store
        self._files = files
        self._tracker = tracker
        self.heating_budget = heating_budget
        self.start_within = start_within
        self._tick = tick
        self._round_gap = round_gap
        self._clock = clock
        self._wake = asyncio.Event()
        self._planning = asyncio.Lock()
        self._loop_task: asyncio.Task[None] | None = None
        self._stop_listening: Callable[[], None] | None = None
        self._runs: dict[str, asyncio.Task[None]] = {}
        """Printer -> the task starting an attempt there."""
        self._running: dict[int, str] = {}
        """Attempt id -> its printer, while its start runs."""
        self._warming: dict[str, float] = {}
        """Printers that started a file that heats but were not seen heating yet, with the
        loop time after which they stop counting against the budget."""
        self._heating: dict[str, bool] = {}
        self._starts_seen: dict[str, tuple[str, asyncio.Event, bool]] = {}
        """Printer -> (upload name, set once print_stats shows it, whether it showed that
        name before the start)."""
        self.memo = Memo()
        """Validation verdicts kept between rounds (the planner's cache)."""
        self._nothing_queued = False
        """The last round found no job to place: heater changes need not be followed."""

    # -- lifecycle ---------------------------------------------------------------------

    def start(self) -> None:
        """Listen to the printers and run the loop."""
        self._stop_listening = self._printers.listen(self._hear)
        self._loop_task = asyncio.create_task(self._loop(), name="queue-dispatcher")
        self.wake()

    async def stop(self) -> None:
        """Stop planning and abandon the starts in progress (the next start of KyberCore
        settles them from the printers, as after a crash)."""
        if self._stop_listening is not None:
            self._stop_listening()
            self._stop_listening = None
        await cancel_and_wait(self._loop_task)
        self._loop_task = None
        runs = list(self._runs.values())
        for task in runs:
            task.cancel()
        await asyncio.gather(*runs, return_exceptions=True)

    def wake(self) -> None:
        """Something changed: plan again soon (many wakes make one round)."""
        self._wake.set()

    async def abandon(self, attempt_id: int) -> None:
        """Stop starting ``attempt_id`` (its job was cancelled); no-op when not starting.
        The attempt stays as it was: the caller ends it."""
        printer = self._running.get(attempt_id)
        task = self._runs.get(printer) if printer is not None else None
        if task is not None:
            await cancel_and_wait(task)

    # -- the loop ----------------------------------------------------------------------

    async def _loop(self) -> None:
        loop = asyncio.get_running_loop()
        outage = Outage(log, "plan the queue", f"it tries again every {RETRY_SECONDS:g} s")
        while True:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._wake.wait(), self._tick)
            if not self._wake.is_set():
                self._tracker.check_all()  # the slow tick: nothing may stay "printing"
            self._wake.clear()
            started = loop.time()
            try:
                await self.round()
            except KyberCoreError as exc:  # the database away, mostly: said once per kind
                outage.failed(exc)
                await asyncio.sleep(RETRY_SECONDS)
                self.wake()
            except Exception:
                log.exception("queue: planning failed; retrying in %g s", RETRY_SECONDS)
                await asyncio.sleep(RETRY_SECONDS)
                self.wake()
            else:
                outage.ended()
            await asyncio.sleep(started + self._round_gap - loop.time())

    def now(self) -> datetime:
        """The time the planner judges ``not_before`` by."""
        return self._clock()

    def usage_since(self) -> datetime:
        """Where the print time wear-levelling counts starts."""
        return self._clock() - timedelta(days=USAGE_DAYS)

    async def round(self) -> Plan:
        """One planning round: plan, reserve, start. Returns the plan it followed."""
        now = self._clock()
        jobs = await self._store.jobs()
        self._nothing_queued = not any(placeable(job) for job in jobs)
        if self._nothing_queued:
            # The plan is empty whatever the printers say: skip reading every printer
            # (a round is woken by any printer's state change, and farms run 5,000).
            return Plan([])
        gates = await self._store.gates()
        usage = await self._store.usage(self.usage_since())
        paused = await self._store.queue_paused()
        tried = await self._store.attempts_per_printer(
            [job.id for job in jobs if job.failures and job.state == "queued"]
        )
        printers = self.snapshots(gates, usage)
        # In a worker thread: a round is ~10 ms at 5,000 printers, but hundreds of ms when
        # every printer is free (bench/dispatch.py), too long to hold the event loop. The
        # lock keeps the memo to one round at a time.
        async with self._planning:
            decided = await asyncio.to_thread(
                partial(
                    plan,
                    jobs,
                    printers,
                    heating_budget=self.heating_budget,
                    starting=self.starting(),
                    now=now,
                    paused=paused,
                    attempts_per_printer=tried,
                    memo=self.memo,
                )
            )
        by_id = {job.id: job for job in jobs}
        for assignment in decided.assignments:
            if assignment.printer in self._runs:
                continue
            attempt = await self._store.reserve(assignment.job_id, assignment.printer)
            if attempt is None:
                continue  # another loop or process won that copy or printer
            for warning in assignment.warnings:
                log.warning("job %d on %s despite: %s", attempt.job_id, attempt.printer, warning)
            self._launch(attempt, by_id[assignment.job_id])
        return decided

    def snapshots(
        self, gates: dict[str, Gate], usage: dict[str, tuple[float, datetime | None]]
    ) -> list[PrinterSnapshot]:
        """Every printer as the planner sees it now."""
        return [self._snapshot(p, gates, usage) for p in self._printers.all()]

    def _snapshot(
        self,
        printer: QueuePrinter,
        gates: dict[str, Gate],
        usage: dict[str, tuple[float, datetime | None]],
    ) -> PrinterSnapshot:
        config = printer.config
        seconds, last_used = usage.get(config.id, (0.0, None))
        return PrinterSnapshot(
            id=config.id,
            facts=printer.facts,
            gate=gates.get(config.id) or Gate(config.id, "available", "", _EPOCH, None, ""),
            tags=tuple(config.tags),
            power_group=power_group(config),
            heating=printer.heating,
            usage_seconds=seconds,
            last_used=last_used,
        )

    def starting(self) -> set[str]:
        """Printers whose start is in progress: they count against the heating budget."""
        loop_now = asyncio.get_running_loop().time()
        for printer_id, until in list(self._warming.items()):
            if until < loop_now:
                self._warming.pop(printer_id)
        return {*self._runs, *self._warming}

    # -- one attempt -------------------------------------------------------------------

    def _launch(self, attempt: Attempt, job: Job) -> None:
        self._tracker.driving(attempt)
        self._running[attempt.id] = attempt.printer
        task = asyncio.create_task(self._run(attempt, job), name=f"start:{attempt.upload_name}")
        self._runs[attempt.printer] = task

    async def _run(self, attempt: Attempt, job: Job) -> None:
        abandoned = False
        try:
            attempt = await self._upload_and_start(attempt, job)
        except ActionRejected as exc:
            # The store refused a step: the attempt ended meanwhile. Whoever ended it
            # owns what happens next.
            log.info("%s: attempt %d stopped: %s", attempt.printer, attempt.id, exc)
        except asyncio.CancelledError:
            abandoned = True  # stop() or abandon(): the caller settles the attempt
            raise
        except Exception as exc:
            log.exception("%s: starting attempt %d failed", attempt.printer, attempt.id)
            attempt = await self._failed_to_start(attempt, f"internal error ({exc!r})")
        finally:
            self._runs.pop(attempt.printer, None)
            self._running.pop(attempt.id, None)
            self._starts_seen.pop(attempt.printer, None)
            if not abandoned:
                self._tracker.follow(attempt)
                self.wake()

    async def _upload_and_start(self, attempt: Attempt, job: Job) -> Attempt:
        printer, name = attempt.printer, attempt.upload_name
        attempt = await self._store.advance(attempt.id, "uploading")
        try:
            path = await self._files.local(job.file.sha256)
            await self._printers.upload(printer, name, path)
        except (KyberCoreError, OSError) as exc:
            why = exc.message if isinstance(exc, KyberCoreError) else str(exc)
            return await self._failed_to_start(attempt, f"the upload to {printer} failed: {why}")
        attempt = await self._store.advance(attempt.id, "starting")
        started = asyncio.Event()
        # A printer may still show this very name from an earlier print (another database
        # numbered its jobs the same): then only a running print proves the start.
        shown = self._printers.shown(printer)
        self._starts_seen[printer] = (name, started, shown.filename == name)
        lost = ""
        try:
            await self._printers.start(printer, name)
        except PrinterUnreachable as exc:
            # It may have started or not: what the printer shows next decides.
            lost = f" (the connection was lost while starting: {exc.message})"
        except KyberCoreError as exc:
            why = f"{printer} refused the start: {exc.message}"
            return await self._failed_to_start(attempt, why)
        self._check_started(printer)
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(started.wait(), self.start_within)
        if not started.is_set():
            return await self._failed_to_start(
                attempt,
                f"{printer} accepted the start but was not printing '{name}' within "
                f"{self.start_within:g} s{lost}",
            )
        if _heats(job) and not self._printers.heat(printer).target_set:
            loop_now = asyncio.get_running_loop().time()
            self._warming[printer] = loop_now + self.start_within
        job_id = self._tracker.job_id(name)
        return await self._store.advance(attempt.id, "printing", moonraker_job_id=job_id)

    async def _failed_to_start(self, attempt: Attempt, reason: str) -> Attempt:
        log.warning("%s: attempt %d failed to start: %s", attempt.printer, attempt.id, reason)
        return await self._store.finish(attempt.id, "failed_to_start", reason=reason)

    # -- what the printers say ---------------------------------------------------------

    def _hear(self, printer_id: str, change: Change) -> None:
        if change == "state":
            self._check_started(printer_id)
            self.wake()
        elif change == "heaters":
            self._heaters_changed(printer_id)
        else:  # a fuller spool may let a job refused for want of filament go there
            self.wake()

    def _check_started(self, printer_id: str) -> None:
        expected = self._starts_seen.get(printer_id)
        if expected is None:
            return
        name, started, shown_before = expected
        outcome = seen(self._printers.shown(printer_id), name)
        if outcome is not None and not (shown_before and outcome.ended):
            started.set()

    def _heaters_changed(self, printer_id: str) -> None:
        if self.heating_budget is None:
            return
        if self._nothing_queued and printer_id not in self._warming:
            # No round would place a job: skip working out the heat of every temperature
            # update. A job queued wakes a round, which reads every printer's heat afresh.
            return
        heat = self._printers.heat(printer_id)
        if printer_id in self._warming and heat.target_set:
            del self._warming[printer_id]  # the printer's own heating counts from now on
            self.wake()
        if self._heating.get(printer_id) != heat.heating:
            self._heating[printer_id] = heat.heating
            self.wake()


def _heats(job: Job) -> bool:
    """Whether the job's file sets a temperature (by its slicer metadata)."""
    meta = job.file.meta
    return any(
        (finite_number(meta.get(key)) or 0) > 0
        for key in ("first_layer_extr_temp", "first_layer_bed_temp")
    )
