"""The notifications at work: what happens in the fleet becomes messages on the channels
that want them, without ever slowing the fleet down.

The pipeline (the pure parts are N1's, storage and delivery N2's)::

    FleetService.listen ─► observe() ─► Detector ─┐
    tick (every ``tick`` s) ─► Detector.tick ─────┼─► NoiseFilter ─► route() per channel
    queue checks (every ``queue_poll`` s) ────────┘      (cooldown,      ─► webcam snapshot
                                                          storm folds)   ─► NotifyStore.record
                                                                         ─► Outbox (retries)

- The listener runs for every status update of every printer: it skips updates that touch
  nothing a notification reads (temperatures, positions), and feeds the detector only when
  the printer's :class:`Observation` changed. Everything else (channels, snapshots, the
  database) happens in a task of its own.
- Events are recorded in the order they happened; the snapshots they wait for are taken
  side by side. A failure anywhere here is logged and the next event goes on: a
  notification never disturbs the fleet.
- Stopping flushes what the noise filter still holds (a fold window not yet closed) to
  the database, so a restart loses no event: the outbox sends it after the next start.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Mapping
from datetime import UTC, datetime
from typing import Final

import httpx
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.aio import cancel_and_wait
from kybercore.errors import ChannelNotFound, KyberCoreError
from kybercore.fleet.service import FleetService
from kybercore.fleet.sessions import FleetPrinter, Interest
from kybercore.jobs.service import QueueService
from kybercore.moonraker.events import Notification, SessionEvent, StatusDelta
from kybercore.notify.detector import Detector, Observation, observe
from kybercore.notify.models import FleetEvent, NoiseSettings, PrinterRef
from kybercore.notify.noise import NoiseFilter
from kybercore.notify.outbox import Outbox
from kybercore.notify.queue_checks import QueueChecks
from kybercore.notify.records import Channel, Delivery
from kybercore.notify.rules import Route, route
from kybercore.notify.snapshot import take_snapshot
from kybercore.notify.store import NotifyStore

log = logging.getLogger(__name__)

WATCHED_OBJECTS: Final = ("print_stats", "webhooks", "filament_switch_sensor",
                          "filament_motion_sensor")  # fmt: skip
"""Status objects an :class:`Observation` reads; an update touching none is skipped."""
INTEREST: Final = Interest(
    {"print_stats": frozenset({"state", "filename", "message", "info"}), "webhooks": None},
    prefixes=WATCHED_OBJECTS[2:],
)
"""The deltas the fleet passes on: those that can change an :class:`Observation` (not
``print_duration`` and the like, which every update carries)."""
READS_AT_ONCE: Final = 2
"""Events reading the channels from the database at once: a bulk pause of 1,000 printers
emits 1,000 events in one go, and their reads must not take every pooled connection (the
pool's timeout then lost events, and held up the fleet's own writes)."""
STOP_GRACE: Final = 5.0
"""Seconds :meth:`NotifyService.stop` gives the events under way to reach the database."""

Prepared = tuple[FleetEvent, bytes | None, dict[int, Route]]


class NotifyService:
    """Detects the fleet's events and hands them to the channels' outbox."""

    def __init__(
        self,
        fleet: FleetService,
        queue: QueueService,
        engine: AsyncEngine,
        http: httpx.AsyncClient,
        *,
        tick: float = 1.0,
        queue_poll: float = 15.0,
        outbox_options: Mapping[str, float] | None = None,
    ) -> None:
        """``tick``: seconds between offline-grace checks and fold-window releases;
        ``queue_poll``: seconds between queue checks; ``outbox_options`` go to
        :class:`Outbox` (its retry timing)."""
        self.fleet = fleet
        self.queue = queue
        self.store = NotifyStore(engine)
        self.outbox = Outbox(self.store, http, **(outbox_options or {}))
        self.settings = NoiseSettings()
        self.ticks = 0
        """Ticks completed (tests wait on it rather than on the clock)."""
        self.checks = QueueChecks(fleet, queue)
        self._http = http
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
        await self._use(await self.store.settings())
        await self.outbox.start()
        for printer in self.fleet.sessions.all():
            self._observe(printer)
        self._unlisten = self.fleet.listen(self._on_event, INTEREST)
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
        return await self.outbox.wait_outcome(pending[0], wait)

    async def apply_settings(self, settings: NoiseSettings) -> None:
        """Store new noise settings and use them from now on."""
        await self.store.save_settings(settings)
        await self._use(settings)

    async def _use(self, settings: NoiseSettings) -> None:
        self.settings = settings
        self._detector.update(settings)
        self._noise.update(settings)

    # -- detection ---------------------------------------------------------------------

    def _on_event(self, printer_id: str, event: SessionEvent) -> None:
        """The fleet's listener: cheap, and never raising into the fleet."""
        if isinstance(event, Notification):
            return
        if isinstance(event, StatusDelta) and not any(
            name.startswith(WATCHED_OBJECTS) for name in event.delta
        ):
            return
        try:
            self._observe(self.fleet.sessions.get(printer_id))
        except Exception:
            log.exception("%s: notifications could not read this change", printer_id)

    def _observe(self, printer: FleetPrinter) -> None:
        observation = observe(printer.live)
        printer_id = printer.config.id
        if self._seen.get(printer_id) == observation:
            return
        self._seen[printer_id] = observation
        ref = PrinterRef.of(printer.config)
        for event in self._detector.observe(ref, observation, time.monotonic(), _utcnow()):
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
        present = {printer.config.id for printer in self.fleet.sessions.all()}
        for gone in [pid for pid in self._seen if pid not in present]:
            del self._seen[gone]
            self._detector.forget(gone)
        for event in self._detector.tick(now, at):
            self._push(event)
        for event in self._noise.release(now):
            self._emit(event)

    async def _queue_watcher(self) -> None:
        warned = False
        while True:
            try:
                for event in await self.checks.run(self.settings, time.monotonic(), _utcnow()):
                    self._push(event)
                warned = False
            except Exception as exc:
                if not warned:  # a database that is down says so once, not every round
                    log.warning("notifications: cannot check the queue: %s", exc)
                warned = True
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
        if self._wants_snapshot(event, channels, routes):
            snapshot = await self._snapshot(event)
        return event, snapshot, routes

    @staticmethod
    def _wants_snapshot(
        event: FleetEvent, channels: list[Channel], routes: Mapping[int, Route]
    ) -> bool:
        return event.printer is not None and any(
            routes.get(c.id) == "deliver" and c.rules.attach_snapshot for c in channels
        )

    async def _snapshot(self, event: FleetEvent) -> bytes | None:
        assert event.printer is not None
        try:
            printer = self.fleet.sessions.get(event.printer.id)
        except KyberCoreError:
            return None
        if printer.client is None or printer.live.connection != "online":
            return None  # an offline printer's webcam is as far away as its Moonraker
        return await take_snapshot(printer.client, printer.config.moonraker_url, self._http)

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
