"""The job queue on NATS: every front serves it, exactly one dispatches.

Fronts share the queue's database (PostgreSQL). Each runs a :class:`QueueService` for the
API, over :class:`kybercore.scale.queue.FrontPrinters` (the views it follows, and commands
to each printer's owner). Only the front holding the ``dispatcher`` role (:mod:`.leader`)
runs the dispatcher and the tracker: one planner weighs the whole fleet at once, so the
heating budget and the wear levelling stay fleet-wide, and one process settles how each
print ends. When that front stops or goes silent, another takes the role within the TTL and
settles the starts it left half done from the printers, as after a crash.

Every change a front commits is published on ``kc.queue.changed``; the other fronts pass it
on to their browsers, and the dispatching front plans again, as it does for its own.

The role's holder also runs the notifications (:mod:`.front_notify`): one notifier for the
fleet, started after the queue and stopped before it.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator, Mapping, Sequence
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, Protocol

import httpx
from nats.aio.msg import Msg
from nats.aio.subscription import Subscription
from sqlalchemy.ext.asyncio import AsyncEngine

from kybercore.fleet.service import FleetService
from kybercore.jobs.service import QueueService
from kybercore.jobs.store import JobStore
from kybercore.ledger.metrics import Source
from kybercore.notify.service import NotifyService
from kybercore.scale.front import FrontFleet
from kybercore.scale.front_metrics import FrontMetrics
from kybercore.scale.front_notify import FrontNotify, FrontNotifyPrinters, NatsPeers
from kybercore.scale.jobfiles import SharedJobFiles
from kybercore.scale.leader import Leadership
from kybercore.scale.queue import FrontPrinters
from kybercore.scale.wire import dumps, loads

log = logging.getLogger(__name__)

CHANGED_SUBJECT: Final = "kc.queue.changed"
ROLE: Final = "dispatcher"


class Duty(Protocol):
    """More work of the role's holder than the queue's (the notifier)."""

    async def start(self) -> None:
        """Start it (the role was taken)."""

    async def stop(self) -> None:
        """Stop it (the role was lost or handed back); also when it did not start."""


@dataclass(frozen=True)
class Front:
    """What ``kybercore front`` hands the app (:class:`kybercore.api.app.Front`): the fleet
    followed from NATS, the queue's printers reached by command, the queue and the
    notifications shared, and the metrics' figures."""

    nats_url: str
    slots: int
    printers_file: Path
    """Imported into an empty registry bucket at start."""
    name: str
    """This front's, unique among the fronts."""
    ttl: float
    """Of the dispatcher role: a silent front's successor dispatches within about it."""

    def fleet(self, http: httpx.AsyncClient) -> FleetService:
        """The fleet as this front follows it."""
        return FrontFleet(self.nats_url, http, slots=self.slots, printers_file=self.printers_file)

    def queue(
        self, fleet: FleetService, store: JobStore, folder: Path, options: Mapping[str, Any]
    ) -> QueueService:
        """The queue as this front serves it: printers reached by command, files shared."""
        assert isinstance(fleet, FrontFleet)
        files = SharedJobFiles(folder, fleet.nc)
        return QueueService(fleet, store, files, printers=FrontPrinters(fleet), **options)

    def notify(
        self,
        fleet: FleetService,
        queue: QueueService,
        engine: AsyncEngine,
        http: httpx.AsyncClient,
        options: Mapping[str, Any],
    ) -> NotifyService:
        """The notifications as this front serves them: printers read from its views, and
        what it changes told to the front running them (:mod:`.front_notify`)."""
        assert isinstance(fleet, FrontFleet)
        printers = FrontNotifyPrinters(fleet)
        return NotifyService(printers, queue, engine, http, peers=NatsPeers(fleet), **options)

    @asynccontextmanager
    async def metrics(self, fleet: FleetService, engine: AsyncEngine) -> AsyncIterator[Source]:
        """The figures of this front's ``/metrics`` (:mod:`.front_metrics`), read in the
        background from its views and the shared database while the app serves."""
        assert isinstance(fleet, FrontFleet)
        figures = FrontMetrics(fleet, engine)
        await figures.start()
        try:
            yield figures
        finally:
            await figures.stop()

    @asynccontextmanager
    async def serving(
        self, fleet: FleetService, queue: QueueService, notify: NotifyService
    ) -> AsyncIterator[None]:
        """Share the queue and the notifications, and contend for the dispatcher role
        (dispatching and notifying while held), while the app serves."""
        assert isinstance(fleet, FrontFleet)
        notifying = FrontNotify(fleet, notify)
        shared = FrontQueue(fleet, queue, name=self.name, ttl=self.ttl, duties=(notify,))
        await notifying.start()
        try:
            await shared.start()
            try:
                yield
            finally:
                await shared.stop()
        finally:
            await notifying.stop()


class FrontQueue:
    """One front's part in the queue; see the module docstring."""

    def __init__(
        self,
        fleet: FrontFleet,
        queue: QueueService,
        *,
        name: str,
        ttl: float,
        duties: Sequence[Duty] = (),
    ) -> None:
        """``name``: this front's, unique among them; ``ttl``: of the dispatcher role;
        ``duties``: more work of the role's holder, started after the queue, in order, and
        stopped before it, in reverse."""
        self._fleet = fleet
        self._queue = queue
        self._duties = (queue, *duties)
        self.name = name
        self.leadership = Leadership(
            fleet.nc, ROLE, name, ttl=ttl, on_gain=self._gain, on_loss=self._lose
        )
        self._subscription: Subscription | None = None
        self._sending: set[asyncio.Task[None]] = set()

    async def start(self) -> None:
        """Share changes with the other fronts and contend for the dispatcher role."""
        # In place of the service's own listener, which it still calls: this one also
        # tells the other fronts.
        self._queue.store.listen(self._committed)
        self._subscription = await self._fleet.nc.subscribe(CHANGED_SUBJECT, cb=self._heard)
        await self.leadership.start()

    async def stop(self) -> None:
        """Stop dispatching (handing the role back) and sharing."""
        await self.leadership.stop()
        if self._subscription is not None:
            await self._subscription.unsubscribe()
        await asyncio.gather(*self._sending, return_exceptions=True)

    async def _gain(self) -> None:
        # One that fails to start fails the gain: the leadership stops them all (_lose)
        # and hands the role back, to be tried again.
        for duty in self._duties:
            await duty.start()

    async def _lose(self) -> None:
        for duty in reversed(self._duties):
            try:
                await duty.stop()
            except Exception:  # the others must stop all the same
                log.exception("%s: a duty of the %s role failed to stop", self.name, ROLE)

    def _committed(self, kind: str, payload: dict[str, Any]) -> None:
        self._queue.changed(kind, payload)
        body = dumps({"front": self.name, "kind": kind, "payload": payload})
        task = asyncio.create_task(self._fleet.nc.publish(CHANGED_SUBJECT, body))
        self._sending.add(task)
        task.add_done_callback(self._sending.discard)

    async def _heard(self, msg: Msg) -> None:
        body = loads(msg.data)
        if body.get("front") != self.name:
            self._queue.changed(str(body["kind"]), dict(body["payload"]))
