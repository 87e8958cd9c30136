"""The notifications at work: what happens in the fleet becomes messages on the channels
that want them, without ever slowing the fleet down.

The pipeline (the pure parts are N1's, storage and delivery N2's)::

    NotifyPrinters.listen ─► Observation ─► Detector ┐
    tick (every ``tick`` s) ─► Detector.tick ────────┼─► NoiseFilter ─► route() per channel
    queue checks (every ``queue_poll`` s) ───────────┘      (cooldown,      ─► webcam snapshot
                                                             storm folds)   ─► NotifyStore.record
                                                                            ─► Outbox (retries)

The printers are read through :class:`~kybercore.notify.printers.NotifyPrinters`: this
process's sessions in ``kybercore serve``, the views on a front on NATS. There, every front
has a service for the API, and only the front holding the dispatcher role runs it (one
notifier at a time); see ``kybercore.scale.front_notify``.

- The listener runs for every change of a printer that may matter (the printers skip
  temperatures and positions), and feeds the detector only when the printer's
  :class:`Observation` changed. Everything else (channels, snapshots, the
  database) happens in a task of its own.
- Events are recorded in the order they happened; the snapshots they wait for are taken
  side by side. A failure anywhere here is logged and the next event goes on: a
  notification never disturbs the fleet.
- Stopping flushes what the noise filter still holds (a fold window not yet closed) to
  the database, so a restart loses no event: the outbox sends it after the next start.
- Starting again (on a front, taking the role back) is a restart: what was known of the
  printers and the queue is forgotten, and their state then is the new baseline.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Mapping
from datetime import UTC, datetime
from typing import Final, Protocol

import httpx
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.aio import cancel_and_wait
from kybercore.db.outage import Outage
from kybercore.errors import ChannelNotFound
from kybercore.jobs.service import QueueService
from kybercore.notify.detector import Detector, Observation
from kybercore.notify.models import FleetEvent, NoiseSettings
from kybercore.notify.noise import NoiseFilter
from kybercore.notify.outbox import Outbox
from kybercore.notify.printers import NotifyPrinters, Observed
from kybercore.notify.queue_checks import QueueChecks
from kybercore.notify.records import Channel, Delivery
from kybercore.notify.rules import Route, route
from kybercore.notify.store import NotifyStore

log = logging.getLogger(__name__)

READS_AT_ONCE: Final = 2
"""Events reading the channels from the database at once: a bulk pause of 1,000 printers
emits 1,000 events in one go, and their reads must not take every pooled connection (the
pool's timeout then lost events, and held up the fleet's own writes)."""
STOP_GRACE: Final = 5.0
"""Seconds :meth:`NotifyService.stop` gives the events under way to reach the database."""

Prepared = tuple[FleetEvent, bytes | None, dict[int, Route]]


class Peers(Protocol):
    """The other processes serving the same notifications (fronts on NATS), of which one
    runs the notifier: what this one changed in the database that the running one must
    hear of."""

    async def recorded(self) -> None:
        """A delivery was recorded here (a test): the running outbox should send it now."""

    async def settings_saved(self) -> None:
        """New noise settings were saved here: the running service should use them."""


class NotifyService:
    """Detects the fleet's events and hands them to the channels' outbox."""

    def __init__(
        self,
        printers: NotifyPrinters,
        queue: QueueService,
        engine: AsyncEngine,
        http: httpx.AsyncClient,
        *,
        peers: Peers | None = None,
        tick: float = 1.0,
        queue_poll: float = 15.0,
        outbox_options: Mapping[str, float] | None = None,
    ) -> None:
        """``peers``: the other processes serving these notifications, if any (see
        :class:`Peers`); ``tick``: seconds between offline-grace checks and fold-window
        releases; ``queue_poll``: seconds between queue checks; ``outbox_options`` go to
        :class:`Outbox` (its retry timing)."""
        self.printers = printers
        self.queue = queue
        self.store = NotifyStore(engine)
        self.outbox = Outbox(self.store, http, **(outbox_options or {}))
        self.settings = NoiseSettings()
        self.ticks = 0
        """Ticks completed (tests wait on it rather than on the clock)."""
        self.checks = QueueChecks(printers, queue)
        self._peers = peers
        self._tick = tick
        self._queue_poll = queue_poll
        self._detector = Detector(self.settings)
        self._noise = NoiseFilter(self.settings)
        self._seen: dict[str, Observation] = {}
        self._reading = asyncio.Semaphore(READS_AT_ONCE)
        self._pipeline: asyncio.Queue[asyncio.Task[Prepared] | None] = asyncio.Queue()
        self._recording: asyncio.Task[None] | None = None
        self._loops: list[asyncio.Task[None]] = []
        self._unlisten: Callable[[], None] | None = None

    # -- lifecycle ---------------------------------------------------------------------

    async def start(self) -> None:
        """Load the settings, start the outbox (it sends what a previous run left), take
        every printer's state as the baseline (a restart is silent), start listening."""
        # Started again (a front taking the role back), nothing known before counts: the
        # printers and the queue may have changed meanwhile, unheard.
        self._detector = Detector(self.settings)
        self._noise = NoiseFilter(self.settings)
        self._seen = {}
        self.checks = QueueChecks(self.printers, self.queue)
        await self.reload_settings()
        await self.outbox.start()
        for printer in self.printers.all():
            self._observe(printer)
        self._unlisten = self.printers.listen(self._on_change)
        self._recording = asyncio.create_task(self._recorder(), name="notify-recorder")
        self._loops = [
            asyncio.create_task(self._ticker(), name="notify-tick"),
            asyncio.create_task(self._queue_watcher(), name="notify-queue"),
        ]

    async def stop(self) -> None:
        """Stop listening; record what is under way or still held for folding (given
        :data:`STOP_GRACE` seconds); stop the outbox."""
        if self._unlisten is not None:
            self._unlisten()
            self._unlisten = None
        for task in self._loops:
            await cancel_and_wait(task)
        self._loops.clear()
        recording, self._recording = self._recording, None
        if recording is not None:
            try:
                # Fold windows end now: what they hold is recorded rather than lost.
                later = time.monotonic() + self.settings.fold_window_s + 1
                for event in self._noise.release(later):
                    self._emit(event)
            except Exception:
                log.exception("notifications: could not flush the events held for folding")
            self._pipeline.put_nowait(None)
            await asyncio.wait({recording}, timeout=STOP_GRACE)
            await cancel_and_wait(recording)
            while not self._pipeline.empty():  # what the grace did not cover
                await cancel_and_wait(self._pipeline.get_nowait())
        await self.outbox.stop()

    # -- what the API asks -------------------------------------------------------------

    async def send_test(self, channel_id: int, user: str, wait: float = 10.0) -> Delivery:
        """Send a test message to one channel (enabled or not, whatever its rules) and
        answer its delivery once the first attempt is over, or as it stands after
        ``wait`` seconds."""
        channel = await self.store.channel(channel_id)
        params = {"channel": channel.name, "user": user}
        event = FleetEvent("test", _utcnow(), None, params)
        pending = await self.store.record(event, None, {channel.id: "deliver"})
        if not pending:  # removed meanwhile
            raise ChannelNotFound(channel_id)
        self.outbox.wake()
        if self._peers is not None:
            await self._peers.recorded()
        return await self.outbox.wait_outcome(pending[0], wait)

    async def apply_settings(self, settings: NoiseSettings) -> None:
        """Store new noise settings and use them from now on (and have the running service
        use them, when that is another process's)."""
        await self.store.save_settings(settings)
        await self._use(settings)
        if self._peers is not None:
            await self._peers.settings_saved()

    async def reload_settings(self) -> None:
        """Use the noise settings saved last (another process may have saved them)."""
        await self._use(await self.store.settings())

    async def _use(self, settings: NoiseSettings) -> None:
        self.settings = settings
        self._detector.update(settings)
        self._noise.update(settings)

    # -- detection ---------------------------------------------------------------------

    def _on_change(self, printer_id: str) -> None:
        """The printers' listener: cheap, and never raising into the fleet."""
        try:
            self._observe(self.printers.get(printer_id))
        except Exception:
            log.exception("%s: notifications could not read this change", printer_id)

    def _observe(self, printer: Observed) -> None:
        observation = printer.observation
        printer_id = printer.ref.id
        if self._seen.get(printer_id) == observation:
            return
        self._seen[printer_id] = observation
        now, at = time.monotonic(), _utcnow()
        for event in self._detector.observe(printer.ref, observation, now, at):
            self._push(event)

    def _push(self, event: FleetEvent) -> None:
        for passed in self._noise.push(event, time.monotonic()):
            self._emit(passed)

    async def _ticker(self) -> None:
        while True:
            await asyncio.sleep(self._tick)
            try:
                self._tick_once()
            except Exception:
                log.exception("notifications: the periodic check failed; going on")
            self.ticks += 1

    def _tick_once(self) -> None:
        now, at = time.monotonic(), _utcnow()
        present = self.printers.ids()  # every second: observing 5,000 printers is not free
        for gone in [pid for pid in self._seen if pid not in present]:
            del self._seen[gone]
            self._detector.forget(gone)
        for event in self._detector.tick(now, at):
            self._push(event)
        for event in self._noise.release(now):
            self._emit(event)

    async def _queue_watcher(self) -> None:
        outage = Outage(
            log, "check the queue for notifications", "its alerts wait until it can"
        )  # a database that is down says so once, not every round
        while True:
            try:
                for event in await self.checks.run(self.settings, time.monotonic(), _utcnow()):
                    self._push(event)
            except Exception as exc:
                outage.failed(exc)
            else:
                outage.ended()
            await asyncio.sleep(self._queue_poll)

    # -- delivery ----------------------------------------------------------------------

    def _emit(self, event: FleetEvent) -> None:
        """Route and snapshot ``event`` now, in a task; the recorder stores the events in
        the order they were emitted."""
        self._pipeline.put_nowait(asyncio.create_task(self._prepare(event)))

    async def _prepare(self, event: FleetEvent) -> Prepared:
        async with self._reading:
            channels = [c for c in await self.store.channels() if c.enabled]
        local = datetime.now().time()  # quiet hours are the server's local time
        routes = {c.id: route(c.rules, event, local) for c in channels}
        routes = {cid: how for cid, how in routes.items() if how != "skip"}
        snapshot = None
        if event.printer is not None and self._wants_snapshot(channels, routes):
            snapshot = await self.printers.snapshot(event.printer.id)
        return event, snapshot, routes

    @staticmethod
    def _wants_snapshot(channels: list[Channel], routes: Mapping[int, Route]) -> bool:
        return any(routes.get(c.id) == "deliver" and c.rules.attach_snapshot for c in channels)

    async def _recorder(self) -> None:
        while (prepared := await self._pipeline.get()) is not None:
            try:
                event, snapshot, routes = await prepared
                if routes:
                    await self.store.record(event, snapshot, routes)
                    self.outbox.wake()
            except Exception:
                log.exception("notifications: an event could not be recorded; going on")


def _utcnow() -> datetime:
    return datetime.now(UTC)
