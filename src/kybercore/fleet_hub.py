"""Fan-out of fleet changes to browser clients.

Every printer update only marks the printer dirty. Ten times a second the hub turns the
dirty printers into one delta frame, serialized once and queued for every client, so the
frame rate per client stays bounded whatever the fleet size. A client that cannot keep up
overflows its bounded queue; the queue is then emptied and replaced by one fresh snapshot,
so a slow browser never slows the others and never misses state.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Final

import orjson

from kybercore.aio import cancel_and_wait
from kybercore.fleet_view import View, diff

log = logging.getLogger(__name__)

TICK_SECONDS: Final = 0.1
QUEUE_FRAMES: Final = 64


@dataclass(eq=False)
class HubClient:
    """One browser connection: a bounded queue of encoded frames."""

    id: int
    queue: asyncio.Queue[bytes] = field(default_factory=lambda: asyncio.Queue(QUEUE_FRAMES))
    console: set[str] = field(default_factory=set)
    """Printers whose G-code responses this client asked for."""
    resyncs: int = 0


class Hub:
    """Publishes snapshots, coalesced per-printer deltas and events to every client."""

    def __init__(self, render: Callable[[str], View | None], tick: float = TICK_SECONDS) -> None:
        self._render = render
        self._tick = tick
        self._views: dict[str, View] = {}
        self._dirty: set[str] = set()
        self._events: list[dict[str, Any]] = []
        self._clients: dict[int, HubClient] = {}
        self._ids = itertools.count(1)
        self._seq = 0
        self._snapshot_frame: bytes | None = None
        """The encoded snapshot of the current views, until a flush replaces a view."""
        self._task: asyncio.Task[None] | None = None

    # -- feeding -----------------------------------------------------------------------

    def mark(self, printer_id: str) -> None:
        """Note that a printer's view may have changed; sent with the next tick."""
        self._dirty.add(printer_id)

    def event(self, frame: dict[str, Any]) -> None:
        """Queue an event frame (connection, Klippy, action result) for every client."""
        self._events.append(frame)

    def console(self, printer_id: str, message: str) -> None:
        """Send a G-code response to the clients that watch this printer's console."""
        frame = _encode({"type": "gcode_response", "printer": printer_id, "message": message})
        for client in self._clients.values():
            if printer_id in client.console:
                self._offer(client, frame)

    # -- clients -----------------------------------------------------------------------

    def connect(self) -> HubClient:
        """Register a client; its first frame is a full snapshot."""
        self.flush()
        client = HubClient(next(self._ids))
        client.queue.put_nowait(self._snapshot())
        self._clients[client.id] = client
        return client

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

    def flush(self) -> None:
        """Render dirty printers now and queue one delta frame (plus pending events)."""
        changed: dict[str, Any] = {}
        removed: list[str] = []
        dirty, self._dirty = self._dirty, set()
        if dirty:
            self._snapshot_frame = None
        for printer_id in dirty:
            try:
                new = self._render(printer_id)
            except Exception:
                # One printer's bad data must not stop the others: keep its last view.
                log.exception("fleet hub: cannot render printer %s", printer_id)
                continue
            old = self._views.get(printer_id)
            if new is None:
                if self._views.pop(printer_id, None) is not None:
                    removed.append(printer_id)
                continue
            self._views[printer_id] = new
            patch = new if old is None else diff(old, new)
            if patch:
                changed[printer_id] = patch
        frames: list[bytes] = []
        if changed or removed:
            self._seq += 1
            delta = {"type": "delta", "seq": self._seq, "printers": changed, "removed": removed}
            frames.append(_encode(delta))
        frames.extend(_encode(event) for event in self._events)
        self._events.clear()
        for frame in frames:
            for client in list(self._clients.values()):
                self._offer(client, frame)

    async def _run(self) -> None:
        while True:
            await asyncio.sleep(self._tick)
            try:
                self.flush()
            except Exception:
                # One bad render must not stop every browser's updates.
                log.exception("fleet hub: publishing failed")

    def _snapshot(self) -> bytes:
        # Encoded once for every client that connects or overflows before the views change:
        # at 5,000 printers a snapshot is ~5 MB, and slow clients tend to overflow together.
        if self._snapshot_frame is None:
            self._snapshot_frame = _encode(
                {"type": "snapshot", "seq": self._seq, "printers": list(self._views.values())}
            )
        return self._snapshot_frame

    def _offer(self, client: HubClient, frame: bytes) -> None:
        try:
            client.queue.put_nowait(frame)
        except asyncio.QueueFull:
            # Replace the backlog by the state it would have led to.
            while not client.queue.empty():
                client.queue.get_nowait()
            client.resyncs += 1
            client.queue.put_nowait(self._snapshot())


def _encode(frame: dict[str, Any]) -> bytes:
    return orjson.dumps(frame)
