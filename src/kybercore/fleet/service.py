"""The fleet's business logic: fuse printers.json with live Moonraker state, validate
actions, delegate them to Moonraker, and keep printers.json and the sessions in step.

One Moonraker session per enabled printer feeds a live cache; pages and the API read the
cache, never Moonraker directly. Every action is validated first
(:mod:`kybercore.core.validation`), then sent, and its real outcome returned: nothing here
reports a success that did not happen.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Mapping, Sequence
from typing import Any, BinaryIO, Final

import httpx
import picows

from kybercore.aio import cancel_and_wait
from kybercore.core.macros import Macro, macros_of
from kybercore.core.paths import safe_path
from kybercore.core.validation import LIMITED_ACTIONS, Verdict, connection_reasons, validate
from kybercore.core.view import View, facts, fuse
from kybercore.errors import (
    ActionRejected,
    ConfigError,
    FileNotFound,
    KyberCoreError,
    MoonrakerRpcError,
    PrinterTimeout,
)
from kybercore.fleet.actions import (
    ActionOutcome,
    changed_objects,
    done_message,
    execute,
    failed_outcome,
    raise_if_blocked,
    require_confirmation,
)
from kybercore.fleet.advisor import AdvisorConfig, advise, combine
from kybercore.fleet.hub import ConsoleLine, Hub, Published
from kybercore.fleet.images import Image, media_type_of
from kybercore.fleet.sessions import FleetPrinter, Interest, Listener, Sessions
from kybercore.fleet.temperatures import Series
from kybercore.fleet.web_ui import WebUiFinder
from kybercore.fleet.webcams import CameraStream, Webcam, WebcamProxy
from kybercore.moonraker.client import MoonrakerClient
from kybercore.moonraker.link import Connect
from kybercore.registry.models import PrinterConfig, PrinterCreate, PrinterUpdate
from kybercore.registry.store import PrinterRegistry

# How long an action that needs the printer's limits waits for them after a connect: the
# read takes well under a second idle, but a busy host (a farm reconnecting, a queue and a
# ledger catching up) can take several; waiting is better than refusing.
LIMITS_WAIT: Final = 15.0
PROBE_TIMEOUT: Final = 8.0
"""How long the connection test of a printer being added waits for Moonraker."""


class FleetService:
    """Owns the printers' sessions, the live cache, and every action on the fleet."""

    def __init__(
        self,
        registry: PrinterRegistry,
        http: httpx.AsyncClient,
        *,
        connect: Connect = picows.ws_connect,
        watch_interval: float = 1.0,
        advisor: AdvisorConfig | None = None,
        on_settled: Callable[[], None] | None = None,
        mdns_interfaces: Sequence[str] | None = None,
        on_publish: Published | None = None,
        on_console: ConsoleLine | None = None,
    ) -> None:
        """``on_settled`` is called once, when every printer is online or disabled after
        :meth:`start` (or after two minutes): ``kybercore serve`` freezes the heap then.
        ``mdns_interfaces``: the addresses "Find printers" browses on (None: all).
        ``on_publish`` and ``on_console``: see :class:`Hub`."""
        self.registry = registry
        self._http = http
        self._watch_interval = watch_interval
        self._advisor = advisor
        self.hub = Hub(self._render, on_publish=on_publish, on_console=on_console)
        self.sessions = Sessions(http, connect, self.hub)
        self._on_settled = on_settled
        self._watcher: asyncio.Task[None] | None = None
        self._settling: asyncio.Task[None] | None = None
        self.config_error: str | None = None
        self.web_ui = WebUiFinder(http)
        self.webcams = WebcamProxy(http)
        self.mdns_interfaces = mdns_interfaces

    @property
    def broker_connected(self) -> bool | None:
        """Whether the process is connected to its NATS broker; None: it has none (serve)."""
        return None

    def broker_frame(self) -> dict[str, Any] | None:
        """The frame a browser connecting now needs to learn this process is cut off from
        its broker (None: it is not, or it has none)."""
        return None

    # -- lifecycle ---------------------------------------------------------------------

    async def start(self) -> None:
        """Read printers.json (refusing a broken file), connect to every printer."""
        printers = await asyncio.to_thread(self.registry.reload)
        self.sessions.apply(printers)  # nothing to close yet
        if self._on_settled is not None:
            self._settling = asyncio.create_task(self._report_settled(self._on_settled))
        self.hub.start()
        self._watcher = asyncio.create_task(
            self.registry.watch(self._on_file_change, self._on_file_error, self._watch_interval),
            name="printers-json-watch",
        )

    async def _report_settled(self, on_settled: Callable[[], None], limit: int = 120) -> None:
        for _ in range(limit):
            live = [p.live.connection for p in self.sessions.all()]
            if all(state in ("online", "disabled") for state in live):
                break
            await asyncio.sleep(1.0)  # poll: connections settle over seconds, bounded above
        on_settled()

    async def stop(self) -> None:
        """Close every session and stop background work."""
        await cancel_and_wait(self._watcher)
        await cancel_and_wait(self._settling)
        await self.hub.stop()
        await self.sessions.close()

    # -- reading -----------------------------------------------------------------------

    def views(self) -> list[View]:
        """Every printer fused with its live state, as last published to the browsers (at
        most one hub tick, 100 ms, old): reading the fleet never renders it."""
        return self.hub.views()

    def fleet_json(self) -> bytes:
        """:meth:`views` as a JSON array, shared by every reader until the next tick."""
        return self.hub.fleet_json()

    def view(self, printer_id: str) -> View:
        """One printer's view, as last published (like :meth:`views`)."""
        printer = self.sessions.get(printer_id)
        view = self.hub.view(printer_id)
        # Unpublished only when its first render failed: render here, to surface why.
        return view if view is not None else fuse(printer.config, printer.live)

    def listen(self, listener: Listener, interest: Interest | None = None) -> Callable[[], None]:
        """Hear every printer's session events (status deltas, connection and Klippy
        changes, notifications) as they are taken in; returns the function that stops it.
        With ``interest``, only the status deltas that name something of it."""
        return self.sessions.listen(listener, interest)

    def config(self, printer_id: str) -> PrinterConfig:
        """A printer's configuration (with the API key: never send it to a client)."""
        return self.sessions.get(printer_id).config

    def client(self, printer_id: str) -> MoonrakerClient:
        """The Moonraker client of an enabled, connected printer."""
        printer = self.sessions.get(printer_id)
        connection = connection_reasons(facts(printer.config, printer.live))
        raise_if_blocked(Verdict.of(connection), printer_id)
        assert printer.client is not None  # only a disabled printer has none, refused above
        return printer.client

    # -- printers.json -----------------------------------------------------------------

    async def add_printer(self, new: PrinterCreate, *, check: bool = False) -> View:
        """Add a printer to printers.json and connect to it; with ``check``, only once its
        Moonraker answered (else the error says why, and nothing is saved)."""
        if check:
            await self.probe(
                new.moonraker_url, new.api_key.get_secret_value() if new.api_key else None
            )
        created = await asyncio.to_thread(self.registry.add, new)
        await self.sessions.apply(self.registry.printers)
        return self.view(created.id)

    async def probe(self, url: str, api_key: str | None) -> dict[str, Any]:
        """Moonraker's ``/server/info`` at ``url``, asked once with ``api_key``: the
        connection test of a printer not (yet) in the fleet. Raises PrinterUnreachable,
        PrinterTimeout or PrinterAuthFailed with what to do."""
        client = MoonrakerClient(url, self._http, name=url, api_key=api_key)
        try:
            return await asyncio.wait_for(client.server_info(), PROBE_TIMEOUT)
        except TimeoutError:
            raise PrinterTimeout(
                f"Moonraker at {url} did not answer within {PROBE_TIMEOUT:.0f} s. Check that "
                "the printer is on and the address is right, or save it anyway."
            ) from None

    async def update_printer(self, printer_id: str, patch: PrinterUpdate) -> View:
        """Edit a printer; its session restarts when the URL, key or enabled flag changed
        (answered once the old session is closed)."""
        self.sessions.get(printer_id)
        await asyncio.to_thread(self.registry.update, printer_id, patch)
        await self.sessions.apply(self.registry.printers)
        return self.view(printer_id)

    async def remove_printer(self, printer_id: str) -> None:
        """Remove a printer from printers.json; answered once it is disconnected."""
        self.sessions.get(printer_id)
        await asyncio.to_thread(self.registry.remove, printer_id)
        await self.sessions.apply(self.registry.printers)

    def _on_file_change(self, _read: list[PrinterConfig]) -> None:
        # Not the list the watcher read: an API write may have landed since (the watcher
        # reads in a worker thread), and the registry always holds the newest fleet.
        self.config_error = None
        self.sessions.apply(self.registry.printers)  # old sessions close in the background
        self.hub.event({"type": "config", "ok": True, "message": "printers.json reloaded"})

    def _on_file_error(self, error: ConfigError) -> None:
        self.config_error = error.message
        self.hub.event({"type": "config", "ok": False, "message": error.message})

    # -- live state --------------------------------------------------------------------

    def _render(self, printer_id: str) -> View | None:
        return self.sessions.render(printer_id)

    # -- actions -----------------------------------------------------------------------

    async def dry_run(
        self,
        printer_id: str,
        action: str,
        params: Mapping[str, Any] | None = None,
        force: bool = False,
    ) -> Verdict:
        """What would happen: the rules (with the file's real metadata) and, when one is
        configured, the advisor's warnings. Nothing is sent to the printer."""
        printer = self.sessions.get(printer_id)
        meta = await self._file_meta_for(printer, action, params)
        if action in LIMITED_ACTIONS:
            # Last before the facts are taken: a new subscription snapshot arriving during
            # an await in between would start a new read and leave the limits "loading".
            await printer.wait_for_limits(LIMITS_WAIT)
        printer_facts = facts(printer.config, printer.live)
        verdict = validate(action, printer_facts, params=params, file_meta=meta, force=force)
        if verdict.blocked or self._advisor is None:
            return verdict
        advice = await advise(self._http, self._advisor, action, printer_facts, params, meta)
        return combine(verdict, advice)

    async def act(
        self,
        printer_id: str,
        action: str,
        params: Mapping[str, Any] | None = None,
        *,
        force: bool = False,
        confirm: bool = False,
    ) -> ActionOutcome:
        """Validate, then run ``action`` on one printer; raise a typed error on failure."""
        params = dict(params or {})
        verdict = await self.dry_run(printer_id, action, params, force)
        raise_if_blocked(verdict, printer_id)
        warnings = require_confirmation(verdict, confirm)
        response = await execute(self.client(printer_id), action, params)
        # Know (and show) the state the action left before answering: the next action is
        # judged against it, and a GET right after must show what the answer promised.
        await self.sessions.refresh(printer_id, changed_objects(action))
        message = done_message(action, params, response)
        self._announce(printer_id, action, message)
        return ActionOutcome(printer_id, action, message, reasons=warnings, response=response)

    async def act_many(
        self,
        printer_ids: list[str],
        action: str,
        params: Mapping[str, Any] | None = None,
        *,
        force: bool = False,
        confirm: bool = False,
        stagger: float = 0.0,
    ) -> list[ActionOutcome]:
        """One action on many printers at once; one outcome per printer, in order. With
        ``stagger``, starts go one at a time, ``stagger`` seconds after the last one that
        happened (the heaters of a room do not all switch on together)."""

        async def one(printer_id: str) -> ActionOutcome:
            try:
                return await self.act(printer_id, action, params, force=force, confirm=confirm)
            except KyberCoreError as exc:
                return failed_outcome(printer_id, action, exc)

        ids = list(dict.fromkeys(printer_ids))
        if action != "start" or stagger <= 0:
            return list(await asyncio.gather(*(one(pid) for pid in ids)))
        loop = asyncio.get_running_loop()
        outcomes: list[ActionOutcome] = []
        last_start: float | None = None
        for printer_id in ids:
            if last_start is not None:
                # The pace asked for (not a poll): a refused start does not count.
                await asyncio.sleep(max(0.0, last_start + stagger - loop.time()))
            outcome = await one(printer_id)
            if outcome.ok:
                last_start = loop.time()
            outcomes.append(outcome)
        return outcomes

    async def upload(
        self,
        printer_id: str,
        filename: str,
        content: bytes | BinaryIO,
        *,
        start: bool = False,
        confirm: bool = False,
    ) -> ActionOutcome:
        """Upload a file; with ``start``, validate it against the printer and print it.

        Once the file is stored the outcome is a success: a start refused after that is
        reported in ``outcome.start`` (with its reasons), not raised, so a caller never
        uploads again a file that is already there."""
        client = self.client(printer_id)
        if start:
            # Refuse before sending the bytes when the printer cannot start anything now.
            printer = self.sessions.get(printer_id)
            await printer.wait_for_limits(LIMITS_WAIT)
            verdict = validate(
                "start", facts(printer.config, printer.live), params={"filename": filename}
            )
            raise_if_blocked(verdict, printer_id)
        await client.upload(filename, content)
        outcome = ActionOutcome(printer_id, "upload", f"Uploaded {filename}.")
        self._announce(printer_id, "upload", outcome.message)
        if start:
            try:
                started = await self.act(
                    printer_id, "start", {"filename": filename}, confirm=confirm
                )
            except KyberCoreError as exc:
                started = failed_outcome(printer_id, "start", exc)
                outcome.message += f" Not started: {exc.message}"
            else:
                outcome.message += " " + started.message
            outcome.start = started
            outcome.reasons = started.reasons
        return outcome

    async def files(self, printer_id: str) -> list[dict[str, Any]]:
        """The printer's G-code files, newest first."""
        files = await self.client(printer_id).files_list()
        return sorted(files, key=lambda f: f.get("modified", 0), reverse=True)

    async def delete_file(self, printer_id: str, path: str) -> None:
        """Delete a G-code file, unless it is the one being printed."""
        printer = self.sessions.get(printer_id)
        stats = printer.live.status.get("print_stats", {})
        if stats.get("filename") == path and stats.get("state") in ("printing", "paused"):
            raise ActionRejected(
                f"{printer_id} is printing '{path}'. Cancel the print before deleting the file.",
                code="file_in_use",
            )
        await self.client(printer_id).delete_file(path)
        self._announce(printer_id, "delete_file", f"Deleted {path}.")

    async def file_metadata(self, printer_id: str, filename: str) -> dict[str, Any]:
        """Moonraker's metadata of one file."""
        return await self.client(printer_id).file_metadata(filename)

    async def console_history(self, printer_id: str, count: int) -> list[dict[str, Any]]:
        """The printer's last ``count`` console entries from Moonraker, oldest first:
        ``[{message, time, type: "command"|"response"}]``."""
        return await self.client(printer_id).gcode_store(count)

    # -- reads from the printer's Moonraker (a front asks the printer's owner) ------------

    async def macros(self, printer_id: str) -> list[Macro]:
        """The printer's G-code macros, read from Klipper's configuration each time (it
        changes with a firmware restart)."""
        status = await self.client(printer_id).objects_query({"configfile": ["config"]})
        return macros_of(status.get("configfile", {}).get("config", {}))

    async def exclude_object_status(self, printer_id: str) -> dict[str, Any] | None:
        """Klipper's ``exclude_object`` status, read now (None: Klipper has no such object)."""
        status = await self.client(printer_id).objects_query({"exclude_object": None})
        found = status.get("exclude_object")
        return found if isinstance(found, dict) else None

    async def temperatures(self, printer_id: str, minutes: float) -> dict[str, Series]:
        """The printer's heaters over the last ``minutes``, from the in-memory ring (no
        request reaches the printer)."""
        self.config(printer_id)  # an unknown printer is an error, not an empty graph
        return self.sessions.temperatures.series(printer_id, minutes)

    async def thumbnail(self, printer_id: str, path: str) -> Image:
        """An image under the printer's ``gcodes/`` (``path`` already checked)."""
        return Image(await self.client(printer_id).download(path), media_type_of(path))

    async def cameras(self, printer_id: str) -> list[Webcam]:
        """The printer's enabled webcams (Moonraker's list, a few seconds old at most)."""
        url = str(self.config(printer_id).moonraker_url)
        return await self.webcams.cameras(self.client(printer_id), url)

    async def camera_snapshot(self, printer_id: str, name: str) -> Image:
        """One JPEG from the webcam ``name``."""
        camera = await self._camera(printer_id, name)
        return Image(await self.webcams.snapshot(camera, printer_id), "image/jpeg")

    async def camera_stream(self, printer_id: str, name: str) -> CameraStream:
        """The webcam's MJPEG stream, relayed as it comes (close it however it ends)."""
        return await self.webcams.stream(await self._camera(printer_id, name), printer_id)

    async def _camera(self, printer_id: str, name: str) -> Webcam:
        url = str(self.config(printer_id).moonraker_url)
        return await self.webcams.camera(self.client(printer_id), url, printer_id, name)

    def _announce(self, printer_id: str, action: str, message: str) -> None:
        event = {"type": "action", "printer": printer_id, "action": action, "ok": True}
        self.hub.event({**event, "message": message})

    async def _file_meta_for(
        self, printer: FleetPrinter, action: str, params: Mapping[str, Any] | None
    ) -> dict[str, Any] | None:
        filename = (params or {}).get("filename")
        if action != "start" or not isinstance(filename, str) or not filename:
            return None
        if printer.client is None or printer.live.connection != "online":
            return None  # validation reports the connection problem
        filename = safe_path(filename)
        try:
            return await printer.client.file_metadata(filename)
        except MoonrakerRpcError as exc:
            if exc.rpc_code == 404:
                raise FileNotFound(
                    f"{printer.config.id}: no file '{filename}' on the printer. "
                    "Upload it first or pick one from the file list."
                ) from exc
            raise
