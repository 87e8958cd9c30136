"""The fleet's printers: one Moonraker session per enabled printer and the live state it feeds.

Each session reports what happens (status deltas, connection and Klippy changes, console
lines) as events; :class:`Sessions` folds them into the printer's :class:`LivePrinter` and
tells the hub which printers changed. Nothing here decides whether an action may run.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
import weakref
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Final

import httpx

from kybercore.core.view import LivePrinter, View, detect_capabilities, fuse, tracked
from kybercore.errors import PrinterError, UnknownPrinter
from kybercore.fleet.hub import Hub
from kybercore.fleet.spools import SPOOL_SET, load_spool, print_ended
from kybercore.fleet.temperatures import Temperatures
from kybercore.moonraker.backoff import Backoff
from kybercore.moonraker.client import MoonrakerClient
from kybercore.moonraker.events import (
    ConnectionChanged,
    EventCallback,
    KlippyChanged,
    Notification,
    SessionEvent,
    StatusDelta,
    StatusSnapshot,
)
from kybercore.moonraker.link import Connect
from kybercore.moonraker.objects import KLIPPY_STATES, Status, apply_status
from kybercore.registry.models import PrinterConfig

LAST_SEEN_STEP: Final = 5.0

# Settings read from Klippy's configfile after every (re)subscription.
_DETECTED_FROM_CONFIGFILE = {"configfile": ["settings"]}
# A failed read is retried with backoff and jitter: after a KyberCore restart a thousand
# printers connect at once, and the reads that failed must not all come back together.
LIMITS_RETRY_FIRST: Final = 1.0
LIMITS_RETRY_CAP: Final = 60.0

log = logging.getLogger(__name__)

Listener = Callable[[str, SessionEvent], None]
"""Told ``(printer_id, event)`` after the printer's live state took the event in."""


@dataclass(frozen=True, slots=True)
class Interest:
    """Which status deltas a listener needs (it hears every other event regardless).

    Nearly every delta is temperatures, positions and ``print_duration``: a listener that
    only follows print states need not be called 4 times a second per printer to find
    that out (at 1,000 printers, such calls were a third of the ingest cost).
    """

    objects: Mapping[str, frozenset[str] | None]
    """Object name -> the fields that matter (None: any field of it)."""
    prefixes: tuple[str, ...] = ()
    """Objects named with one of these prefixes (``"filament_switch_sensor "``), any field."""

    def wants(self, delta: Status) -> bool:
        """Whether ``delta`` names an object (and field) of interest."""
        # Over the interest's few objects, not the delta's many: this runs per listener
        # for every update, and most updates interest nobody but the dispatcher.
        for name, wanted in self.objects.items():
            fields = delta.get(name)
            if fields is not None and (wanted is None or not wanted.isdisjoint(fields)):
                return True
        prefixes = self.prefixes
        if prefixes:
            for name in delta:
                if name.startswith(prefixes):
                    return True
        return False


@dataclass
class FleetPrinter:
    """One printer of the fleet: its configuration, its Moonraker client, its live state."""

    config: PrinterConfig
    client: MoonrakerClient | None
    """None while the printer is disabled."""
    live: LivePrinter = field(default_factory=LivePrinter)
    limits_tried: asyncio.Event = field(default_factory=asyncio.Event)
    """Set once Klippy's configfile was read, or its read failed, since the last snapshot."""
    limits_reader: asyncio.Task[None] | None = None

    async def wait_for_limits(self, timeout: float) -> None:
        """Wait, at most ``timeout`` s, until the first limits read after a (re)connect
        succeeded or failed (``live.limits`` then says which).

        A printer is online ~300 ms before its configfile arrives; an action checked in
        that window is refused with ``limits_loading`` unless the read comes in time.
        """
        # A loop, not one wait: a new snapshot may start a new read (and clear the event)
        # between the event being set and this task resuming.
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(timeout):
                while self.live.connection == "online" and not self.limits_tried.is_set():
                    await self.limits_tried.wait()


class Sessions:
    """The printers' sessions and live state, kept in step with printers.json."""

    def __init__(self, http: httpx.AsyncClient, connect: Connect, hub: Hub) -> None:
        self._http = http
        self._connect = connect
        self._hub = hub
        self.temperatures = Temperatures()
        """The heaters' last half hour, fed from the same status updates."""
        self._printers: dict[str, FleetPrinter] = {}
        self._background: set[asyncio.Task[Any]] = set()
        self._listeners: list[tuple[Listener, Interest | None]] = []
        self._spool_watchers: list[Callable[[str], None]] = []

    def listen(self, listener: Listener, interest: Interest | None = None) -> Callable[[], None]:
        """Call ``listener`` with every event of every current printer's session, after
        the live state has taken it in; return the function that stops it. With
        ``interest``, status deltas that name nothing of it are not passed on. Listeners
        run on the event loop for every status update (4 a second per printer): keep them
        cheap, and spawn any I/O."""
        entry = (listener, interest)
        self._listeners.append(entry)
        return lambda: self._listeners.remove(entry)

    def watch_spools(self, watcher: Callable[[str], None]) -> Callable[[], None]:
        """Call ``watcher(printer_id)`` each time a printer's spool (or Spoolman's state)
        changed in its live state; return the function that stops it. Apart from
        :meth:`listen`: the spool is read after the event that prompted the read, so a
        listener woken by that event would still see the old spool."""
        self._spool_watchers.append(watcher)
        return lambda: self._spool_watchers.remove(watcher)

    def get(self, printer_id: str) -> FleetPrinter:
        """The printer ``printer_id``; :class:`UnknownPrinter` when there is none."""
        printer = self._printers.get(printer_id)
        if printer is None:
            raise UnknownPrinter(printer_id)
        return printer

    def all(self) -> list[FleetPrinter]:
        """Every printer, in printers.json order."""
        return list(self._printers.values())

    def render(self, printer_id: str) -> View | None:
        """The printer's fused view, or None once it is gone (the hub's renderer)."""
        printer = self._printers.get(printer_id)
        if printer is None:
            return None
        # What is published is what the next view must not go back from.
        printer.live.print_memory = tracked(printer.live)
        return fuse(printer.config, printer.live, tracked=True)

    def apply(self, printers: list[PrinterConfig]) -> asyncio.Future[Any]:
        """Make the running sessions match ``printers`` (start, stop or restart them) and
        publish the result at once, so the fleet list shows it when a request returns.

        Sessions no longer wanted close in the background; await the result to wait for
        them (it never raises)."""
        wanted = {p.id: p for p in printers}
        closing = []
        for printer_id in list(self._printers):
            if printer_id not in wanted:
                closing.append(self._spawn(self._close(self._printers.pop(printer_id))))
                self.temperatures.forget(printer_id)
                self._hub.mark(printer_id)
        for printer_id, config in wanted.items():
            current = self._printers.get(printer_id)
            if current is not None and current.config == config:
                continue  # its view did not change: nothing to render or send
            if current is not None and not _needs_new_session(current.config, config):
                current.config = config
            else:
                if current is not None:
                    closing.append(self._spawn(self._close(current)))
                self._printers[printer_id] = self._open(config)
            self._hub.mark(printer_id)
        self._hub.flush()
        return asyncio.gather(*closing, return_exceptions=True)

    async def close(self) -> None:
        """Close every session and stop background work."""
        for task in list(self._background):
            task.cancel()
        await asyncio.gather(*(self._close(p) for p in self._printers.values()))
        self._printers.clear()

    def _open(self, config: PrinterConfig) -> FleetPrinter:
        if not config.enabled:
            return FleetPrinter(config, None, LivePrinter(connection="disabled"))
        printer = FleetPrinter(config, None)
        printer.client = MoonrakerClient(
            config.moonraker_url,
            self._http,
            name=config.id,
            api_key=config.api_key.get_secret_value() if config.api_key else None,
            on_event=self._events_of(printer),
            connect=self._connect,
        )
        printer.client.start()
        return printer

    def _events_of(self, printer: FleetPrinter) -> EventCallback:
        """The session's event callback for ``printer``. It holds the printer weakly: a
        strong reference would close the cycle printer -> client -> session -> callback ->
        printer, which ``gc.freeze()`` (``kybercore serve``) makes immortal, so every
        removed or re-sessioned printer would leak. The session of a replaced printer
        reports to that printer, never to its successor under the same id."""
        ref = weakref.ref(printer)

        def on_event(event: SessionEvent) -> None:
            target = ref()
            if target is not None:
                self._on_event(target, event)

        return on_event

    async def _close(self, printer: FleetPrinter) -> None:
        if printer.limits_reader is not None:
            printer.limits_reader.cancel()
        if printer.client is not None:
            await printer.client.close()

    def _on_event(self, printer: FleetPrinter, event: SessionEvent) -> None:
        live = printer.live
        heard_before, live.updated_at = live.updated_at, time.time()
        pid = printer.config.id
        if isinstance(event, StatusDelta):
            delta = event.delta
            apply_status(live.status, delta)  # the live state is ours alone
            self.temperatures.feed(pid, live.status, delta)
            stats = delta.get("print_stats")
            # The file and the print's end are news only in a delta that names them; the
            # others (nearly all: print_duration moves 4 times a second) skip both checks.
            if stats is not None and ("filename" in stats or "state" in stats):
                self._follow_file(printer)
                if print_ended(delta):
                    self._spawn(self._load_spool(printer))
        elif isinstance(event, StatusSnapshot):
            live.status = dict(event.status)
            self.temperatures.feed(pid, live.status, live.status)
            self._follow_file(printer)
            self._read_limits(printer)
            self._spawn(self._load_spool(printer))
        elif isinstance(event, ConnectionChanged):
            live.connection = event.connection
            live.connection_error = event.detail
            if event.connection != "online":
                self.temperatures.gap(pid)
            self._hub.event(
                {
                    "type": "connection",
                    "printer": pid,
                    "connection": event.connection,
                    "message": event.detail,
                }
            )
        elif isinstance(event, KlippyChanged):
            self._klippy_changed(printer, event.state, event.message)
            if event.state in ("shutdown", "error"):
                self._spawn(self._read_klippy_message(printer))
        elif isinstance(event, Notification):
            if event.method == "notify_gcode_response" and event.params:
                self._hub.console(pid, str(event.params[0]))
            elif event.method == SPOOL_SET:
                self._spawn(self._load_spool(printer))
            elif event.method == "notify_filelist_changed":
                # A nudge for the pages listing this printer's files: they reload the list.
                self._hub.event({"type": "files", "printer": pid})
            # Moonraker's 1 s process stats prove the printer is alive even when nothing
            # changes; let `updated_at` show that, at most every LAST_SEEN_STEP seconds.
            if live.updated_at // LAST_SEEN_STEP == heard_before // LAST_SEEN_STEP:
                self._tell(printer, event)
                return
        self._hub.mark(pid)
        self._tell(printer, event)

    def _tell(self, printer: FleetPrinter, event: SessionEvent) -> None:
        """Hand the event to the listeners; a replaced printer's session is not news."""
        pid = printer.config.id
        if not self._listeners or self._printers.get(pid) is not printer:
            return
        delta = event.delta if isinstance(event, StatusDelta) else None
        for listener, interest in list(self._listeners):
            if delta is not None and interest is not None and not interest.wants(delta):
                continue
            try:
                listener(pid, event)
            except Exception:
                log.exception("%s: a fleet listener failed on %s", pid, type(event).__name__)

    def _klippy_changed(self, printer: FleetPrinter, state: str, message: str) -> None:
        printer.live.klippy_state = state
        printer.live.klippy_message = message
        if state != "ready":
            self.temperatures.gap(printer.config.id)
        event = {"type": "klippy", "printer": printer.config.id, "state": state}
        self._hub.event({**event, "message": message})

    async def refresh(self, printer_id: str, objects: Mapping[str, list[str] | None]) -> None:
        """Read ``objects`` from Klippy now, merge them into the live state and publish the
        printer's view at once. After an action, the next check and the next read then see
        the state it left, not the last push (Moonraker pushes every ~250 ms); the read
        goes over the same socket as the pushes, so no older push can overwrite it.
        A failed read is logged and left to the next push."""
        printer = self._printers.get(printer_id)
        if printer is None or printer.client is None or not objects:
            return
        try:
            status = await printer.client.objects_query(objects)
        except PrinterError as exc:
            log.info("%s: cannot read the state after an action: %s", printer_id, exc.message)
            return
        if self._printers.get(printer_id) is not printer:
            return  # removed or replaced meanwhile: its state is someone else's now
        live = printer.live
        apply_status(live.status, status)
        self.temperatures.feed(printer_id, live.status, status)
        live.updated_at = time.time()
        webhooks = status.get("webhooks", {})
        state = webhooks.get("state")
        if state in KLIPPY_STATES and state != live.klippy_state:
            self._klippy_changed(printer, state, str(webhooks.get("state_message") or ""))
        self._follow_file(printer)
        self._hub.refresh(printer_id)

    def _follow_file(self, printer: FleetPrinter) -> None:
        """Fetch the metadata of a newly started file once (ETA, thumbnail)."""
        filename = printer.live.status.get("print_stats", {}).get("filename") or ""
        meta = printer.live.file_meta
        if filename and (meta is None or meta.get("filename") != filename):
            printer.live.file_meta = {"filename": filename}
            self._spawn(self._load_file_meta(printer, filename))

    async def _load_file_meta(self, printer: FleetPrinter, filename: str) -> None:
        if printer.client is None:
            return
        try:
            meta = await printer.client.file_metadata(filename)
        except PrinterError:
            meta = {"unavailable": True}  # read, though empty: the view stops waiting for it
        printer.live.file_meta = {**meta, "filename": filename}
        self._hub.mark(printer.config.id)

    def _read_limits(self, printer: FleetPrinter) -> None:
        """(Re)start reading the limits: Klippy may have restarted with another config."""
        if printer.limits_reader is not None:
            printer.limits_reader.cancel()
        printer.live.limits = "loading"
        printer.limits_tried.clear()
        printer.limits_reader = asyncio.create_task(self._limits_until_read(printer))

    async def _limits_until_read(self, printer: FleetPrinter) -> None:
        """Read the limits from Klippy's configfile, retrying with backoff until it works;
        until then the printer's limits are ``unknown`` and the actions that need them are
        refused (validation's ``limits_unknown``)."""
        client, pid = printer.client, printer.config.id
        backoff = Backoff(base=LIMITS_RETRY_FIRST, cap=LIMITS_RETRY_CAP)
        while client is not None:
            try:
                status = await client.objects_query(_DETECTED_FROM_CONFIGFILE)
                printer.live.detected = detect_capabilities(status["configfile"]["settings"])
            except (PrinterError, KeyError, TypeError, ValueError) as exc:
                delay = backoff.next_delay(0.0)
                if printer.live.limits != "unknown":
                    log.warning("%s: cannot read the limits, retrying: %s", pid, _why(exc))
                printer.live.limits = "unknown"
                printer.limits_tried.set()
                self._hub.mark(pid)
                await asyncio.sleep(delay)
                continue
            printer.live.limits = "known"
            printer.limits_tried.set()
            self._hub.mark(pid)
            return

    async def _load_spool(self, printer: FleetPrinter) -> None:
        client = printer.client
        if client is None or not await load_spool(client, printer.live):
            return
        pid = printer.config.id
        self._hub.mark(pid)
        if self._printers.get(pid) is not printer:
            return  # replaced meanwhile: its spool is not news
        for watcher in list(self._spool_watchers):
            try:
                watcher(pid)
            except Exception:
                log.exception("%s: a spool watcher failed", pid)

    async def _read_klippy_message(self, printer: FleetPrinter) -> None:
        if printer.client is None:
            return
        with contextlib.suppress(PrinterError, KeyError):
            info = await printer.client.printer_info()
            printer.live.klippy_message = str(info.get("state_message", ""))
            self._hub.mark(printer.config.id)

    def _spawn(self, work: Awaitable[Any]) -> asyncio.Future[Any]:
        task = asyncio.ensure_future(work)
        self._background.add(task)
        task.add_done_callback(self._background.discard)
        return task


def _why(exc: Exception) -> str:
    return exc.message if isinstance(exc, PrinterError) else f"unexpected answer ({exc!r})"


def _needs_new_session(old: PrinterConfig, new: PrinterConfig) -> bool:
    return (old.moonraker_url, old.api_key, old.enabled) != (
        new.moonraker_url,
        new.api_key,
        new.enabled,
    )
