"""Fan-out of fleet changes to browser clients, and the published fleet list.

Every printer update only marks the printer dirty. Ten times a second the hub renders the
dirty printers (in slices, so the event loop keeps serving requests and sockets meanwhile)
into one delta frame, serialized once and queued for every client, so the frame rate per
client stays bounded whatever the fleet size. A client that cannot keep up overflows its
bounded queue; the queue is then emptied and replaced by one fresh snapshot, so a slow
browser never slows the others and never misses state. ``GET /api/printers`` reads the same
published views (:meth:`Hub.fleet_json`), so reading the fleet never renders it.

A client may say which printers it shows (:meth:`Hub.watch`): it then gets full views of
those and slim summaries of the rest (:mod:`kybercore.fleet.frames`), with encodings shared
between clients, never made per client."""

from __future__ import annotations

import asyncio
import itertools
import logging
import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, Final

import orjson

from kybercore.aio import cancel_and_wait
from kybercore.core.view import View, diff
from kybercore.fleet.frames import DeltaFrames, slim, snapshot_frame, views_frame
from kybercore.moonraker.objects import merge_status

log = logging.getLogger(__name__)

TICK_SECONDS: Final = 0.1
SLICE_SECONDS: Final = 0.001
QUEUE_FRAMES: Final = 64

Published = Callable[[dict[str, Any], set[str], list[dict[str, Any]]], None]
"""Told, once per tick, ``(patches, removed, events)`` as the browsers get them."""
ConsoleLine = Callable[[str, str], None]
"""Told ``(printer_id, message)`` for every G-code response."""


@dataclass(eq=False)
class HubClient:
    """One browser connection: a bounded queue of encoded frames."""

    id: int
    queue: asyncio.Queue[bytes] = field(default_factory=lambda: asyncio.Queue(QUEUE_FRAMES))
    console: set[str] = field(default_factory=set)
    """Printers whose G-code responses this client asked for."""
    view: frozenset[str] | None = None
    """Printers this client gets in full (None: every printer); slim summaries of the rest."""
    resyncs: int = 0


class Hub:
    """Publishes snapshots, coalesced per-printer deltas and events to every client."""

    def __init__(
        self,
        render: Callable[[str], View | None],
        tick: float = TICK_SECONDS,
        *,
        on_publish: Published | None = None,
        on_console: ConsoleLine | None = None,
    ) -> None:
        """``on_publish`` and ``on_console`` hear what the browsers get (an ingest worker
        publishes it to NATS instead of to browsers of its own)."""
        self._renderer = render
        self._on_publish = on_publish
        self._on_console = on_console
        self._tick = tick
        self._views: dict[str, View] = {}
        self._dirty: dict[str, None] = {}
        """Printers to render at the next tick, in the order they were first marked (a new
        printer's view takes that place in the fleet list)."""
        self._events: list[dict[str, Any]] = []
        self._unsent: dict[str, Any] = {}
        """Patches rendered into the views but not yet sent to the clients."""
        self._removed: set[str] = set()
        self._clients: dict[int, HubClient] = {}
        self._ids = itertools.count(1)
        self._seq = 0
        self._fleet: bytes | None = None
        """Every view as one JSON array, until a flush replaces a view."""
        self._snapshot_frame: bytes | None = None
        self._slim_fleet: bytes | None = None
        """Every printer's slim summary as one JSON array, until the next delta."""
        self._slims: dict[str, dict[str, Any]] | None = None
        """Every printer's slim summary as of the last delta, kept from the deltas' slim
        patches while a client has a view (None otherwise). A browser that falls behind is
        resent them all, and deriving 5,000 from the views each time was most of a
        front's work once its browsers overflowed (``bench/README.md``)."""
        self._task: asyncio.Task[None] | None = None

    # -- feeding -----------------------------------------------------------------------

    def mark(self, printer_id: str) -> None:
        """Note that a printer's view may have changed; sent with the next tick."""
        self._dirty[printer_id] = None

    def patched(self, printer_id: str, view: View, patch: dict[str, Any]) -> None:
        """Take a printer's new view with the patch that led to it from its last one, both
        made elsewhere (a front forwards its workers' patches): no render, no diff. Sent
        with the next tick, as a marked printer's would be."""
        old = self._views.get(printer_id)
        self._fleet = self._snapshot_frame = None
        self._views[printer_id] = view
        if old is None:
            self._removed.discard(printer_id)
            self._unsent[printer_id] = view
            return
        unsent = self._unsent.get(printer_id)
        self._unsent[printer_id] = patch if unsent is None else merge_status(unsent, patch)

    def event(self, frame: dict[str, Any]) -> None:
        """Queue an event frame (connection, Klippy, action result) for every client."""
        self._events.append(frame)

    def console(self, printer_id: str, message: str) -> None:
        """Send a G-code response to the clients that watch this printer's console."""
        if self._on_console is not None:
            self._on_console(printer_id, message)
        frame = _encode({"type": "gcode_response", "printer": printer_id, "message": message})
        for client in self._clients.values():
            if printer_id in client.console:
                self._offer(client, frame)

    # -- clients -----------------------------------------------------------------------

    def connect(self, view: Iterable[str] | None = None) -> HubClient:
        """Register a client; its first frame is a snapshot: of every printer in full, or,
        given the ``view`` it shows (see :meth:`watch`), of those in full and slim
        summaries of the rest (a summary is about 60 % of a full view's bytes)."""
        self.flush()
        client = HubClient(next(self._ids))
        client.view = None if view is None else frozenset(view)
        client.queue.put_nowait(self._snapshot(client.view))
        self._clients[client.id] = client
        return client

    def watch(self, client: HubClient, printer_ids: Iterable[str] | None) -> None:
        """Send this client full views of ``printer_ids`` only, slim summaries of the rest
        (None: every printer in full, the default).

        The printers entering the view are sent in full at once: until now the client had
        only their summaries, and an idle printer may not change for a long time."""
        old = client.view
        new = None if printer_ids is None else frozenset(printer_ids)
        client.view = new
        if old is None or new == old:
            return
        if new is None:
            entering = [view for i, view in self._views.items() if i not in old]
        else:
            entering = [self._views[i] for i in new - old if i in self._views]
        if entering:
            self._offer(client, views_frame(entering))

    def disconnect(self, client: HubClient) -> None:
        """Forget a client."""
        self._clients.pop(client.id, None)

    @property
    def client_count(self) -> int:
        """Browsers connected now."""
        return len(self._clients)

    # -- publishing --------------------------------------------------------------------

    def start(self) -> None:
        """Start the tick loop."""
        if self._task is None:
            self._task = asyncio.create_task(self._run(), name="fleet-hub")

    async def stop(self) -> None:
        """Stop the tick loop."""
        task, self._task = self._task, None
        await cancel_and_wait(task)

    def view(self, printer_id: str) -> View | None:
        """The last published view of a printer (fresh after :meth:`flush`)."""
        return self._views.get(printer_id)

    def views(self) -> list[View]:
        """Every published view (at most one tick old)."""
        return list(self._views.values())

    def fleet_json(self) -> bytes:
        """Every published view as a JSON array, as ``GET /api/printers`` sends it; one
        body for every read until the next tick changes a view.

        One ``orjson.dumps`` of the whole list: four times faster than joining per-printer
        encodings (1.8 ms for 1,000 printers).
        """
        if self._fleet is None:
            self._fleet = _encode(list(self._views.values()))
        return self._fleet

    def refresh(self, printer_id: str) -> None:
        """Render one printer now, so that reads (:meth:`view`, :meth:`fleet_json`) show
        its new state at once; browsers get the change with the next tick's frame, so a
        bulk action still sends one frame per tick."""
        self._dirty.pop(printer_id, None)
        self._render([printer_id])

    def flush(self) -> None:
        """Render dirty printers now and queue one delta frame (plus pending events)."""
        self._render(self._take_dirty())
        self._publish()

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        next_tick = loop.time()
        while True:
            # A steady rate: the time spent rendering is not added to the wait.
            next_tick = max(next_tick + self._tick, loop.time())
            await asyncio.sleep(next_tick - loop.time())
            try:
                # In slices, so requests and sockets are served between them: rendering
                # 2,000 changed printers at once stalls everything ~100 ms. A slice lasts
                # SLICE_SECONDS, or as long as the other work took while it waited, so a
                # busy fleet cannot starve the browsers of their updates.
                dirty = self._take_dirty()
                budget = SLICE_SECONDS
                while dirty:
                    dirty = self._render(dirty, until=time.perf_counter() + budget)
                    if dirty:
                        waited = time.perf_counter()
                        await asyncio.sleep(0)
                        budget = max(SLICE_SECONDS, time.perf_counter() - waited)
                self._publish()
            except Exception:
                # One bad render must not stop every browser's updates.
                log.exception("fleet hub: publishing failed")

    def _take_dirty(self) -> list[str]:
        dirty = list(self._dirty)
        self._dirty.clear()
        return dirty

    def _render(self, printer_ids: list[str], until: float = math.inf) -> list[str]:
        """Render printers into the views and the patches not sent yet, until the
        ``time.perf_counter()`` value ``until``; return the printers left."""
        if printer_ids:
            self._fleet = self._snapshot_frame = None
        for index, printer_id in enumerate(printer_ids):
            if index and time.perf_counter() > until:
                return printer_ids[index:]
            try:
                new = self._renderer(printer_id)
            except Exception:
                # One printer's bad data must not stop the others: keep its last view.
                log.exception("fleet hub: cannot render printer %s", printer_id)
                continue
            old = self._views.get(printer_id)
            if new is None:
                if self._views.pop(printer_id, None) is not None:
                    self._unsent.pop(printer_id, None)
                    self._removed.add(printer_id)
                continue
            self._views[printer_id] = new
            if old is None:
                self._removed.discard(printer_id)
                self._unsent[printer_id] = new
                continue
            patch = diff(old, new)
            if patch:
                # Rendered twice before a publish (a flush between two slices): one patch.
                unsent = self._unsent.get(printer_id)
                self._unsent[printer_id] = patch if unsent is None else merge_status(unsent, patch)
        return []

    def _publish(self) -> None:
        """Queue the unsent patches as one delta frame, then the pending events."""
        if self._on_publish is not None and (self._unsent or self._removed or self._events):
            self._on_publish(self._unsent, self._removed, self._events)
        delta: DeltaFrames | None = None
        if self._unsent or self._removed:
            self._seq += 1
            delta = DeltaFrames(self._seq, self._unsent, sorted(self._removed))
            self._unsent, self._removed = {}, set()
            self._follow_slims(delta)
        events = [_encode(event) for event in self._events]
        self._events.clear()
        for client in list(self._clients.values()):
            # Every client gets every delta, even one with nothing in its view: the
            # sequence numbers tell a browser that it missed nothing.
            if delta is not None:
                self._offer(client, delta.frame(client.view))
            for frame in events:
                self._offer(client, frame)

    def _follow_slims(self, delta: DeltaFrames) -> None:
        """Bring the kept slim summaries to ``delta`` (before any client may need a
        snapshot of its sequence number); stop keeping them once no client has a view."""
        slims = self._slims
        if slims is None:
            return
        if all(client.view is None for client in self._clients.values()):
            self._slims = self._slim_fleet = None
            return
        # A summary patch sets what it names, so one the summaries already hold (a view
        # rendered before they were first derived) changes nothing.
        for printer_id, summary in delta.summaries().items():
            old = slims.get(printer_id)
            slims[printer_id] = summary if old is None else merge_status(old, summary)
        for printer_id in delta.removed:
            slims.pop(printer_id, None)
        self._slim_fleet = None

    def _snapshot(self, view: frozenset[str] | None = None) -> bytes:
        # Built once for every client that connects or overflows before the views change:
        # at 5,000 printers a snapshot is ~5 MB, and slow clients tend to overflow together.
        if view is None:
            if self._snapshot_frame is None:
                self._snapshot_frame = snapshot_frame(self._seq, self.fleet_json())
            return self._snapshot_frame
        if self._slims is None:
            self._slims = {i: slim(v) for i, v in self._views.items()}
        if self._slim_fleet is None:
            self._slim_fleet = orjson.dumps(list(self._slims.values()))
        full = [self._views[i] for i in view if i in self._views]
        return snapshot_frame(self._seq, self._slim_fleet, full)

    def _offer(self, client: HubClient, frame: bytes) -> None:
        try:
            client.queue.put_nowait(frame)
        except asyncio.QueueFull:
            # Replace the backlog by the state it would have led to.
            while not client.queue.empty():
                client.queue.get_nowait()
            client.resyncs += 1
            client.queue.put_nowait(self._snapshot(client.view))


def _encode(frame: dict[str, Any] | list[View]) -> bytes:
    return orjson.dumps(frame)
