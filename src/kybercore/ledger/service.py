"""The ledger at work: it listens to every printer's session and keeps the history, the
state timeline and the figures ``/metrics`` shows, without ever polling a printer for them.

- On every (re)connect of a printer, its history is caught up: Moonraker's instance id,
  then a backfill newest first down to the last job known (:func:`history.backfill`).
  Live ``notify_history_changed`` events are written in batches meanwhile; one that arrives
  before the instance id is known waits for it.
- Every ``tick`` seconds the printers' states go to the timeline; only changes are written.
- Every ``queue_poll`` seconds the queue's gates and depth are read, in one query each.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.aio import cancel_and_wait
from kybercore.db.outage import UNAVAILABLE, Outage, said
from kybercore.fleet.service import FleetService
from kybercore.fleet.sessions import FleetPrinter, Interest
from kybercore.ledger.figures import LoopLag, QueueReader, poll
from kybercore.ledger.history import (
    PAGE,
    HistoryJob,
    HistoryStore,
    backfill,
    jobs_of_notification,
    read_instance,
)
from kybercore.ledger.metrics import Snapshot
from kybercore.ledger.timeline import Timeline, printer_state
from kybercore.ledger.unwritten import NONE_LEFT, UnwrittenFile
from kybercore.moonraker.backoff import Backoff
from kybercore.moonraker.events import (
    ConnectionChanged,
    KlippyChanged,
    Notification,
    SessionEvent,
    StatusDelta,
    StatusSnapshot,
)

log = logging.getLogger(__name__)

# The only deltas _on_event reads: a print state changed (not temperatures, not positions).
_INTEREST: Final = Interest({"print_stats": frozenset({"state"})})

RETRY_SECONDS: Final = 1.0
"""How soon the job history is written again after the database did not answer."""
BACKFILLS_AT_ONCE: Final = 8
"""A thousand printers reconnecting after a restart catch up eight at a time."""

Row = tuple[str, str, HistoryJob]


@dataclass
class _Feed:
    """One printer's ingest: which Moonraker database it has, and its catch-up."""

    instance: str | None = None
    waiting: list[HistoryJob] = field(default_factory=list)
    """Live jobs heard before the instance id was read."""
    catch_up: asyncio.Task[None] | None = None
    was_online: bool = False


class LedgerService:
    """History ingest, state timeline and metrics figures for one fleet."""

    def __init__(
        self,
        fleet: FleetService,
        engine: AsyncEngine,
        *,
        page: int = PAGE,
        tick: float = 1.0,
        queue_poll: float = 2.0,
        owns: Callable[[str], bool] | None = None,
        unwritten: Path | None = None,
    ) -> None:
        """``owns(printer_id)``: whether this ledger writes for the printer now (an ingest
        worker on NATS: the printers of the slots it holds; the others' sessions may still
        be open for a grace period). None: every printer of ``fleet``, and the intervals
        a previous run left open are ended at start (one process writes them all).
        ``unwritten``: the file that keeps the state changes a stop could not write, for
        the next start (:mod:`.unwritten`); None: they are lost."""
        self.fleet = fleet
        self.engine = engine
        self.history = HistoryStore(engine)
        self.timeline = Timeline(engine)
        self.job_counts: dict[tuple[str, str], int] = {}
        """Jobs per (printer, Moonraker status), as written: /metrics reads it."""
        self.reconnects: Counter[str] = Counter()
        self._queue = QueueReader(engine)
        self._lag = LoopLag()
        self.backfill_requests = 0
        """``/server/history/list`` requests made (a test counts them)."""
        self._page = page
        self._tick = tick
        self._queue_poll = queue_poll
        self._feeds: dict[str, _Feed] = {}
        self._live: list[Row] = []
        self._wake = asyncio.Event()
        self._writing = asyncio.Lock()
        self._backfills = asyncio.Semaphore(BACKFILLS_AT_ONCE)
        self._tasks: list[asyncio.Task[None]] = []
        self._unlisten: Any = None
        self._owns = owns
        self._unwritten = None if unwritten is None else UnwrittenFile(unwritten, self.timeline)

    # -- lifecycle ---------------------------------------------------------------------

    async def start(self) -> None:
        """Write what a previous run's stop could not, close what it left open, load the
        counts, start listening."""
        if self._unwritten is not None:
            await self._unwritten.take_back()
        if self._owns is None:
            # With several writers, an open interval may be another's: the next change
            # of its printer ends it, whoever writes it.
            await self.timeline.recover()
        self.job_counts = await self.history.counts()
        self._unlisten = self.fleet.listen(self._on_event, _INTEREST)
        queue = poll(self._queue.read, self._queue_poll, "the queue's gates and depth")
        for work, name in (
            (self._writer(), "ledger-writer"),
            (self._sweeper(), "ledger-timeline"),
            (queue, "ledger-queue"),
            (self._lag.run(), "ledger-loop-lag"),
        ):
            self._tasks.append(asyncio.create_task(work, name=name))
        # Printers online before we listened: their (re)connect was not heard.
        for printer in self._mine():
            if printer.live.connection == "online":
                self._connected(printer.config.id)

    async def stop(self) -> None:
        """Stop listening; write what was heard; end the open state intervals."""
        if self._unlisten is not None:
            self._unlisten()
            self._unlisten = None
        for feed in self._feeds.values():
            await cancel_and_wait(feed.catch_up)
        for task in self._tasks:
            await cancel_and_wait(task)
        self._tasks.clear()
        try:
            await self.flush()
            await self.timeline.close()
            if self._unwritten is not None:
                await self._unwritten.written()
        except UNAVAILABLE as exc:
            pending = self.timeline.pending
            kept = "the state changes do not" if pending else NONE_LEFT
            if self._unwritten is not None:
                kept = await self._unwritten.keep_at_stop()
            log.warning(
                "stopping with %d jobs heard and %d state changes seen not written (%s); "
                "the jobs come back from the printers' Moonraker history at the next start, "
                "%s",
                len(self._live), pending, said(exc), kept,
            )  # fmt: skip

    async def flush(self) -> None:
        """Write the live jobs and state changes heard so far, now."""
        await self._write_live()
        self._sweep()
        await self.timeline.flush()

    def metrics(self) -> Snapshot:
        """What ``/metrics`` shows now (a copy: format it anywhere)."""
        return Snapshot(
            views=self.fleet.views(),
            states=dict(self.timeline.current),
            jobs=self.job_counts,  # replaced, never changed in place
            queue=self._queue.figures,
            reconnects=dict(self.reconnects),
            browsers=self.fleet.hub.client_count,
            loop_lag=self._lag.seconds,
        )

    def caught_up(self, printer_id: str) -> bool:
        """Whether the printer's history was read since it last connected."""
        feed = self._feeds.get(printer_id)
        task = None if feed is None else feed.catch_up
        return task is not None and task.done() and not task.cancelled()

    # -- what the sessions tell ----------------------------------------------------------

    def _on_event(self, printer_id: str, event: SessionEvent) -> None:
        if self._owns is not None and not self._owns(printer_id):
            return  # another worker writes it (its sweep catches up when it comes back)
        if isinstance(event, Notification):
            if event.method == "notify_history_changed":
                self._heard_jobs(printer_id, jobs_of_notification(event.params))
            return
        if isinstance(event, ConnectionChanged):
            if event.connection == "online":
                self._connected(printer_id)
            else:
                feed = self._feeds.setdefault(printer_id, _Feed())
                feed.instance = None
                if feed.catch_up is not None:
                    feed.catch_up.cancel()
        elif isinstance(event, StatusDelta) and "state" not in event.delta.get("print_stats", {}):
            return  # temperatures and positions: no state change
        elif not isinstance(event, KlippyChanged | StatusDelta | StatusSnapshot):
            return
        with contextlib.suppress(KeyError):
            self._observe(self.fleet.sessions.get(printer_id))

    def _heard_jobs(self, printer_id: str, heard: list[HistoryJob]) -> None:
        feed = self._feeds.setdefault(printer_id, _Feed())
        if feed.instance is None:
            feed.waiting.extend(heard)
            return
        self._live.extend((printer_id, feed.instance, job) for job in heard)
        self._wake.set()

    def _connected(self, printer_id: str) -> None:
        feed = self._feeds.setdefault(printer_id, _Feed())
        if feed.was_online:
            self.reconnects[printer_id] += 1
        feed.was_online = True
        feed.instance = None
        if feed.catch_up is not None:
            feed.catch_up.cancel()
        feed.catch_up = asyncio.create_task(
            self._catch_up(printer_id, feed), name=f"ledger-catch-up:{printer_id}"
        )

    async def _catch_up(self, printer_id: str, feed: _Feed) -> None:
        """Read the instance id, then backfill; retried with backoff until it works or the
        printer goes offline (its next connect starts again)."""
        backoff = Backoff(base=1.0, cap=60.0)
        while True:
            try:
                async with self._backfills:
                    await self._backfill(printer_id, feed)
            except Exception as exc:
                log.warning("%s: cannot read the job history yet, retrying: %s", printer_id, exc)
            else:
                return
            await asyncio.sleep(backoff.next_delay(0.0))

    async def _backfill(self, printer_id: str, feed: _Feed) -> None:
        client = self.fleet.sessions.get(printer_id).client
        if client is None:
            return
        if feed.instance is None:
            feed.instance = await read_instance(client.call)
            self._live.extend((printer_id, feed.instance, job) for job in feed.waiting)
            feed.waiting.clear()
            self._wake.set()
        instance = feed.instance

        async def page(limit: int, start: int) -> dict[str, Any]:
            self.backfill_requests += 1
            return await client.history_list(limit, start)

        floor = await self.history.floor(printer_id, instance)
        async for found in backfill(page, floor, self._page):
            await self._write([(printer_id, instance, job) for job in found])

    # -- writing -------------------------------------------------------------------------

    async def _writer(self) -> None:
        outage = Outage(
            log, "write the job history",
            "the job history heard meanwhile is kept and written once it can",
        )  # fmt: skip
        while True:
            await self._wake.wait()
            self._wake.clear()
            try:
                await self._write_live()
            except UNAVAILABLE as exc:
                outage.failed(exc)
                await asyncio.sleep(RETRY_SECONDS)
                self._wake.set()
            else:
                outage.ended()

    async def _write_live(self) -> None:
        """Write the live jobs heard so far. The batch is taken under the lock, so when
        this returns every job heard before the call is in the table, including a batch
        the writer task had taken and was still writing."""
        async with self._writing:
            batch, self._live = self._live, []
            try:
                await self._upsert(batch)
            except BaseException:
                self._live[:0] = batch
                raise

    async def _write(self, rows: Sequence[Row]) -> None:
        async with self._writing:
            await self._upsert(rows)

    async def _upsert(self, rows: Sequence[Row]) -> None:
        """Write ``rows`` and refresh their printers' counts; the caller holds the lock."""
        if not rows:
            return
        await self.history.upsert(rows)
        printers = sorted({printer for printer, _, _ in rows})
        counts = await self.history.counts(printers)
        kept = {key: n for key, n in self.job_counts.items() if key[0] not in printers}
        self.job_counts = kept | counts

    # -- timeline ------------------------------------------------------------------------

    def _observe(self, printer: FleetPrinter, at: float | None = None) -> None:
        live, pid = printer.live, printer.config.id
        print_state = str(live.status.get("print_stats", {}).get("state") or "")
        gate = self._queue.gates.get(pid)
        state = printer_state(live.connection, live.klippy_state, print_state, gate)
        self.timeline.observe(pid, state, at)

    def _mine(self) -> list[FleetPrinter]:
        printers = self.fleet.sessions.all()
        if self._owns is None:
            return printers
        return [p for p in printers if self._owns(p.config.id)]

    def _sweep(self) -> None:
        now = time.time()
        printers = self._mine()
        for printer in printers:
            self._observe(printer, now)
            pid = printer.config.id
            if pid not in self._feeds and printer.live.connection == "online":
                # Online before it was ours (a worker took its slot over): catch up now.
                self._connected(pid)
        present = {p.config.id for p in printers}
        self.timeline.forget([pid for pid in self.timeline.current if pid not in present], now)
        for pid in [pid for pid in self._feeds if pid not in present]:
            feed = self._feeds.pop(pid)
            if feed.catch_up is not None:
                feed.catch_up.cancel()

    async def _sweeper(self) -> None:
        outage = Outage(
            log, "write the printers' states",
            "the state changes seen meanwhile are kept and written once it can",
        )  # fmt: skip
        while True:
            await asyncio.sleep(self._tick)
            self._sweep()
            try:
                await self.timeline.flush()
            except UNAVAILABLE as exc:
                outage.failed(exc)
                if self._unwritten is not None:
                    await self._unwritten.keep()
            else:
                outage.ended()
                if self._unwritten is not None:
                    await self._unwritten.written()
