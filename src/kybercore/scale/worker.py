"""``kybercore ingest``: a worker that owns a share of the fleet's printers on NATS.

It holds slots by lease (:mod:`.leases`), and for the printers of its slots it runs what
``kybercore serve`` runs for all of them: Moonraker sessions, live state, fused views and
validated actions (a :class:`FleetService`). Instead of browsers it has NATS:

- once per hub tick, one patch batch per slot on ``kc.s.<site>.<slot>.patch``, with the
  slot's epoch, a sequence number and how late the worker's event loop runs (an empty one
  each second as a heartbeat);
- the slot's full views on request at ``kc.s.<site>.<slot>.snap`` (a front that starts, or
  saw a gap or a new epoch);
- commands at ``kc.cmd.<printer id>``: acknowledged at once, then answered with the outcome
  (:mod:`.commands`).

A slot it stops owning is no longer published or acted for at once, but its printers'
Moonraker sessions are kept for a grace period: if the slot comes back (a broker blip),
nothing reconnects.

A worker started for a site holds that site's printers only; ``_`` is the default site in
subjects (:mod:`.slots`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections import defaultdict
from pathlib import Path
from typing import Any, Final

import httpx
import picows
from nats.aio.client import Client
from nats.aio.msg import Msg
from nats.aio.subscription import Subscription

from kybercore.aio import cancel_and_wait
from kybercore.errors import BrokerUnavailable
from kybercore.fleet.service import FleetService
from kybercore.ledger.figures import LoopLag
from kybercore.ledger.unwritten import UNWRITTEN
from kybercore.moonraker.link import Connect
from kybercore.registry.models import PrinterConfig
from kybercore.registry.store import PrinterRegistry
from kybercore.scale.commands import CommandRunner
from kybercore.scale.jobfiles import JobFileBucket
from kybercore.scale.last_read import LastRead
from kybercore.scale.leases import Leases
from kybercore.scale.registry import KvRegistry
from kybercore.scale.slots import DEFAULT_SITE, slot_of
from kybercore.scale.streams import StreamRelay
from kybercore.scale.uploads import Uploads
from kybercore.scale.wire import (
    command_subject,
    console_subject,
    dumps,
    patch_subject,
    slot_of_subject,
    snapshot_subject,
)
from kybercore.scale.worker_ledger import WorkerLedger

log = logging.getLogger(__name__)

HEARTBEAT_SECONDS: Final = 1.0
GRACE_SECONDS: Final = 30.0
"""How long the sessions of a lost slot stay open, in case it comes back."""
CHECK_SECONDS: Final = 0.25
"""How often ownership is looked at between lease rounds (fencing is noticed this fast)."""
REGISTRY_RETRY_SECONDS: Final = 2.0
"""How often a worker started on the printers it read last tries the registry again."""


class Worker:
    """One ingest worker; :meth:`start`, then :meth:`stop`."""

    def __init__(
        self,
        nc: Client,
        worker_id: str,
        http: httpx.AsyncClient,
        *,
        url: str,
        slots: int,
        ttl: float,
        folder: Path,
        site: str = DEFAULT_SITE,
        grace: float = GRACE_SECONDS,
        connect: Connect = picows.ws_connect,
        database: str | None = None,
        local_leases: bool = False,
    ) -> None:
        """``url``: the broker's (``nc``'s), for the lease renewals' own connection.
        ``site``: the worker holds the printers of this site only (:mod:`.slots`).
        ``folder`` keeps the worker's own/drop log (``leases.jsonl``) and the printers it
        last read from the registry (:mod:`.last_read`). With ``database``
        (the URL of the one the fronts read), the worker keeps the ledger of the printers it acts
        for: their job history and state timeline. ``local_leases``: its leases are kept in
        the JetStream of the server it connects to, a site's leaf node (:mod:`.leases`)."""
        self._nc = nc
        self.worker_id = worker_id
        self.slots = slots
        self.site = site
        self._grace = grace
        self.registry = KvRegistry(read_keys=True)
        self.last_read = LastRead(folder)
        # Never read: the worker's printers come from the bucket, applied by _reconcile.
        unused = PrinterRegistry(folder / "printers.json")
        self.service = FleetService(
            unused, http, connect=connect, on_publish=self._published, on_console=self._console
        )
        self.leases = Leases(
            nc, worker_id, url=url, slots=slots, ttl=ttl, site=site,
            log_path=folder / "leases.jsonl", on_change=self._lease_changed, local=local_leases,
        )  # fmt: skip
        self.commands = CommandRunner(
            self.service, self._epoch_of, uploads=Uploads(nc), jobfiles=JobFileBucket(nc),
            streams=StreamRelay(nc, self._epoch_of),
        )  # fmt: skip
        self.ledger = None
        if database is not None:
            self.ledger = WorkerLedger(
                self.service, database, owns=lambda pid: self._acting_for(self._slot(pid)),
                unwritten=folder / UNWRITTEN,
            )  # fmt: skip
        self._printers: list[PrinterConfig] = []
        self._applied: tuple[int, frozenset[int]] | None = None
        """(registry version, slots) the sessions were last made to match."""
        self._version = 0
        self._owned: dict[int, int] = {}
        self._kept: dict[int, float] = {}
        """Lost slots whose sessions stay open, until this monotonic() time."""
        self._handed: set[int] = set()
        """Slots released to a peer (a fair share): their sessions close at once."""
        self._seq: dict[int, int] = defaultdict(int)
        self._sent_at: dict[int, float] = {}
        self._snap_subs: dict[int, Subscription] = {}
        self._cmd_subs: dict[str, Subscription] = {}
        self._outbox: asyncio.Queue[tuple[str, bytes]] = asyncio.Queue()
        self._wake = asyncio.Event()
        self._lag = LoopLag()
        self._tasks: list[asyncio.Task[None]] = []

    async def start(self) -> None:
        """Open the buckets, start following the registry and claiming slots."""
        opened = await self._open_registry()
        if self.ledger is not None:  # before any slot is claimed: it may stop the start
            await self.ledger.start(restarted=await self.last_read.written())
        self.service.hub.start()
        await self.leases.start()
        self._tasks = [
            asyncio.create_task(self._follow_registry(opened), name="registry-watch"),
            asyncio.create_task(self.last_read.run(), name="registry-last-read"),
            asyncio.create_task(self._run(), name="worker-loop"),
            asyncio.create_task(self._send(), name="worker-publisher"),
            asyncio.create_task(self._lag.run(), name="worker-loop-lag"),
        ]

    async def stop(self) -> None:
        """Hand every slot back, close every session."""
        await self.leases.stop(release=True)
        for task in self._tasks:
            await cancel_and_wait(task)
        await self.commands.stop()
        if self.ledger is not None:
            await self.ledger.stop()
        await self.service.stop()

    # -- ownership -----------------------------------------------------------------------

    def _slot(self, printer_id: str) -> int:
        return slot_of(printer_id, self.slots)

    def _epoch_of(self, printer_id: str) -> int | None:
        return self.leases.epoch(self._slot(printer_id))

    def _lease_changed(self, slot: int, epoch: int | None, why: str) -> None:
        if why == "release":
            self._handed.add(slot)
        self._wake.set()

    async def _open_registry(self) -> bool:
        """Open the registry: True. When it cannot be read and this worker read it before
        (a site cut off from the hub, restarting a worker), start on the printers it read
        last instead of stopping: False."""
        try:
            await self.registry.open(self._nc)
        except (BrokerUnavailable, TimeoutError) as exc:
            last = await self.last_read.load()
            if last is None:
                raise
            log.warning(
                "%s: the printer registry cannot be read (%s); starting on the %d printers "
                "of site '%s' it read last (%s), and following the registry once it answers",
                self.worker_id, exc, len(last), self.site, self.last_read.path,
            )  # fmt: skip
            self._use(last)
            return False
        return True

    async def _follow_registry(self, opened: bool) -> None:
        if not opened:
            while not opened:
                await asyncio.sleep(REGISTRY_RETRY_SECONDS)
                with contextlib.suppress(BrokerUnavailable, TimeoutError):
                    await self.registry.open(self._nc)
                    opened = True
            log.info("%s: the printer registry answers again; following it", self.worker_id)
        await self.registry.watch(self._on_printers)

    def _on_printers(self, printers: list[PrinterConfig]) -> None:
        # Another site's printers are its own workers' (a printer moved to another site
        # leaves this worker's sessions, and its removal is published to the fronts).
        self._use([p for p in printers if p.site == self.site])
        self.last_read.keep(self._printers)

    def _use(self, printers: list[PrinterConfig]) -> None:
        self._printers = printers
        self._version += 1
        self._wake.set()

    async def _run(self) -> None:
        while True:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._wake.wait(), CHECK_SECONDS)
            self._wake.clear()
            try:
                await self._reconcile()
                await self._heartbeat()
            except Exception:  # one bad round must not stop the worker
                log.exception("%s: reconcile failed", self.worker_id)

    async def _reconcile(self) -> None:
        owned = self.leases.owned()  # fences what is too old
        now = time.monotonic()
        for slot in set(self._owned) - set(owned):
            # Kept open in case it comes back (a broker blip), unless it went to a peer that
            # connects its printers anyway: two sessions per printer would double the work.
            if slot not in self._handed:
                self._kept[slot] = now + self._grace
            if (sub := self._snap_subs.pop(slot, None)) is not None:
                await sub.unsubscribe()
        self._handed.clear()
        for slot in set(owned) - set(self._owned):
            self._kept.pop(slot, None)
            self._snap_subs[slot] = await self._nc.subscribe(
                snapshot_subject(slot, self.site), cb=self._on_snapshot_request
            )
        self._owned = owned
        self._kept = {s: until for s, until in self._kept.items() if until > now}
        mine = [p for p in self._printers if slot_of(p.id, self.slots) in owned]
        await self._follow_commands({p.id for p in mine})
        keep = set(owned) | set(self._kept)
        # Only on a change: applying renders and publishes every printer at once, and this
        # runs four times a second (at 1,000 printers that starved their connections).
        if self._applied != (self._version, frozenset(keep)):
            self._applied = (self._version, frozenset(keep))
            kept = [p for p in self._printers if slot_of(p.id, self.slots) in keep]
            self.service.sessions.apply(kept)

    async def _follow_commands(self, printer_ids: set[str]) -> None:
        # One subscription per owned printer: when no worker owns it, a command gets "no
        # responders" at once instead of waiting for a timeout.
        for printer_id in set(self._cmd_subs) - printer_ids:
            await self._cmd_subs.pop(printer_id).unsubscribe()
        for printer_id in printer_ids - set(self._cmd_subs):
            self._cmd_subs[printer_id] = await self._nc.subscribe(
                command_subject(printer_id), cb=self.commands.on_message
            )

    # -- publishing ----------------------------------------------------------------------

    def _published(
        self, patches: dict[str, Any], removed: set[str], events: list[dict[str, Any]]
    ) -> None:
        batches: dict[int, dict[str, Any]] = {}

        def batch(printer_id: str) -> dict[str, Any] | None:
            slot = slot_of(printer_id, self.slots)
            if slot not in batches:
                if not self._acting_for(slot):
                    return None  # not ours (any more): the owner publishes it
                batches[slot] = {"patches": {}, "removed": [], "events": []}
            return batches[slot]

        for printer_id, patch in patches.items():
            if (found := batch(printer_id)) is not None:
                found["patches"][printer_id] = patch
        for printer_id in removed:
            if (found := batch(printer_id)) is not None:
                found["removed"].append(printer_id)
        for event in events:
            about = event.get("printer")
            if isinstance(about, str) and (found := batch(about)) is not None:
                found["events"].append(event)
        for slot, body in batches.items():
            self._seq[slot] += 1
            self._queue(slot, body)

    def _acting_for(self, slot: int) -> bool:
        # Owned by lease and set up (command and snapshot subscriptions): a front that sees
        # the slot's printers fresh can act on them.
        return slot in self._owned and self.leases.epoch(slot) is not None

    def _queue(self, slot: int, body: dict[str, Any]) -> None:
        epoch = self.leases.epoch(slot)
        if epoch is None:
            return
        message = {**self._signature(slot, epoch), **body}
        self._sent_at[slot] = time.monotonic()
        self._outbox.put_nowait((patch_subject(slot, self.site), dumps(message)))

    async def _heartbeat(self) -> None:
        now = time.monotonic()
        for slot in self._owned:
            if now - self._sent_at.get(slot, 0.0) >= HEARTBEAT_SECONDS:
                self._queue(slot, {"patches": {}, "removed": [], "events": []})

    def _console(self, printer_id: str, message: str) -> None:
        if self._acting_for(slot_of(printer_id, self.slots)):
            body = dumps({"printer": printer_id, "message": message})
            self._outbox.put_nowait((console_subject(printer_id), body))

    async def _send(self) -> None:
        # One sender keeps a slot's batches in order on the wire.
        while True:
            subject, data = await self._outbox.get()
            try:
                await self._nc.publish(subject, data)
            except Exception as exc:  # broker away: fronts re-snapshot on the seq gap
                log.debug("%s: publish to %s failed: %s", self.worker_id, subject, exc)

    async def _on_snapshot_request(self, msg: Msg) -> None:
        slot = slot_of_subject(msg.subject).slot
        epoch = self.leases.epoch(slot)
        if epoch is None or slot not in self._owned:
            await msg.respond(dumps({"moving": True}))
            return
        views = {
            p.id: view
            for p in self._printers
            if slot_of(p.id, self.slots) == slot and (view := self.service.hub.view(p.id))
        }
        await msg.respond(dumps({**self._signature(slot, epoch), "views": views}))

    def _signature(self, slot: int, epoch: int) -> dict[str, Any]:
        # The loop's lag lets a front show how near its capacity each worker runs.
        return {
            "epoch": epoch,
            "seq": self._seq[slot],
            "worker": self.worker_id,
            "lag": round(self._lag.seconds, 3),
        }

    def owned(self) -> dict[int, int]:
        """``slot → epoch`` of the slots this worker acts for now."""
        return dict(self._owned)
