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
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator, Mapping
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import httpx
from nats.aio.msg import Msg
from nats.aio.subscription import Subscription

from kybercore.fleet.service import FleetService
from kybercore.jobs.service import QueueService
from kybercore.jobs.store import JobStore
from kybercore.scale.front import FrontFleet
from kybercore.scale.jobfiles import SharedJobFiles
from kybercore.scale.leader import Leadership
from kybercore.scale.queue import FrontPrinters
from kybercore.scale.wire import dumps, loads

log = logging.getLogger(__name__)

CHANGED_SUBJECT: Final = "kc.queue.changed"
ROLE: Final = "dispatcher"


@dataclass(frozen=True)
class Front:
    """What ``kybercore front`` hands the app (:class:`kybercore.api.app.Front`): the fleet
    followed from NATS, the queue's printers reached by command, and the queue shared."""

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

    @asynccontextmanager
    async def serving(self, fleet: FleetService, queue: QueueService) -> AsyncIterator[None]:
        """Share the queue and contend for the dispatcher role while the app serves."""
        assert isinstance(fleet, FrontFleet)
        shared = FrontQueue(fleet, queue, name=self.name, ttl=self.ttl)
        await shared.start()
        try:
            yield
        finally:
            await shared.stop()


class FrontQueue:
    """One front's part in the queue; see the module docstring."""

    def __init__(self, fleet: FrontFleet, queue: QueueService, *, name: str, ttl: float) -> None:
        """``name``: this front's, unique among them; ``ttl``: of the dispatcher role."""
        self._fleet = fleet
        self._queue = queue
        self.name = name
        self.leadership = Leadership(
            fleet.nc, ROLE, name, ttl=ttl, on_gain=queue.start, on_loss=queue.stop
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
