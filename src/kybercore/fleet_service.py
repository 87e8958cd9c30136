"""The fleet's business logic: fuse printers.json with live Moonraker state, validate
actions, delegate them to Moonraker, and keep printers.json and the sessions in step.

One Moonraker session per enabled printer feeds a live cache; pages and the API read the
cache, never Moonraker directly. Every action is validated first
(:mod:`kybercore.validation`), then sent, and its real outcome returned: nothing here
reports a success that did not happen.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import httpx
import websockets

from kybercore.errors import (
    ActionRejected,
    ConfigError,
    InvalidInput,
    KyberCoreError,
    PrinterAuthFailed,
    PrinterError,
    PrinterUnreachable,
    UnknownPrinter,
)
from kybercore.fleet_hub import Hub
from kybercore.fleet_view import LivePrinter, View, facts, fuse
from kybercore.http_errors import error_status
from kybercore.moonraker_client import MoonrakerClient
from kybercore.moonraker_session import (
    Connect,
    ConnectionChanged,
    KlippyChanged,
    Notification,
    SessionEvent,
    StatusDelta,
    StatusSnapshot,
)
from kybercore.printer_config import PrinterConfig, PrinterCreate, PrinterUpdate
from kybercore.printer_state import merge_status
from kybercore.registry import PrinterRegistry
from kybercore.validation import Reason, Verdict, validate

log = logging.getLogger(__name__)

# Settings read once from Klippy's configfile when printers.json does not give them.
_DETECTED_FROM_CONFIGFILE = {"configfile": ["settings"]}


@dataclass
class ActionOutcome:
    """What happened when an action ran on one printer."""

    printer_id: str
    action: str
    ok: bool
    status: int
    message: str
    code: str = "ok"
    reasons: list[dict[str, str]] = field(default_factory=list)
    detail: Any = None


@dataclass
class _Printer:
    config: PrinterConfig
    client: MoonrakerClient | None
    live: LivePrinter = field(default_factory=LivePrinter)


class FleetService:
    """Owns the printers' sessions, the live cache, and every action on the fleet."""

    def __init__(
        self,
        registry: PrinterRegistry,
        http: httpx.AsyncClient,
        *,
        connect: Connect = websockets.connect,
        watch_interval: float = 1.0,
    ) -> None:
        self.registry = registry
        self._http = http
        self._connect = connect
        self._watch_interval = watch_interval
        self._printers: dict[str, _Printer] = {}
        self.hub = Hub(self._render)
        self._watcher: asyncio.Task[None] | None = None
        self._background: set[asyncio.Task[Any]] = set()
        self.config_error: str | None = None

    # -- lifecycle ---------------------------------------------------------------------

    async def start(self) -> None:
        """Read printers.json (refusing a broken file), connect to every printer."""
        printers = await asyncio.to_thread(self.registry.reload)
        self._apply(printers)
        self.hub.start()
        self._watcher = asyncio.create_task(
            self.registry.watch(self._on_file_change, self._on_file_error, self._watch_interval),
            name="printers-json-watch",
        )

    async def stop(self) -> None:
        """Close every session and stop background work."""
        if self._watcher is not None:
            self._watcher.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._watcher
        for task in list(self._background):
            task.cancel()
        await self.hub.stop()
        await asyncio.gather(*(self._close(p) for p in self._printers.values()))
        self._printers.clear()

    # -- reading -----------------------------------------------------------------------

    def views(self) -> list[View]:
        """Every printer, fused with its live state (fresh: renders what changed)."""
        self.hub.flush()
        return [view for pid in self._printers if (view := self.hub.view(pid)) is not None]

    def view(self, printer_id: str) -> View:
        """One printer's fused view."""
        self._get(printer_id)
        self.hub.flush()
        view = self.hub.view(printer_id)
        if view is None:
            raise UnknownPrinter(printer_id)
        return view

    def config(self, printer_id: str) -> PrinterConfig:
        """A printer's configuration (with the API key: never send it to a client)."""
        return self._get(printer_id).config

    def client(self, printer_id: str) -> MoonrakerClient:
        """The Moonraker client of an enabled, connected printer."""
        printer = self._get(printer_id)
        _require_online(printer)
        assert printer.client is not None  # _require_online checked it
        return printer.client

    # -- printers.json -----------------------------------------------------------------

    async def add_printer(self, new: PrinterCreate) -> View:
        """Add a printer to printers.json and connect to it."""
        created = await asyncio.to_thread(self.registry.add, new)
        self._apply(self.registry.printers)
        return self.view(created.id)

    async def update_printer(self, printer_id: str, patch: PrinterUpdate) -> View:
        """Edit a printer; its session restarts when the URL, key or enabled flag changed."""
        self._get(printer_id)
        await asyncio.to_thread(self.registry.update, printer_id, patch)
        self._apply(self.registry.printers)
        return self.view(printer_id)

    async def remove_printer(self, printer_id: str) -> None:
        """Remove a printer from printers.json and disconnect from it."""
        self._get(printer_id)
        await asyncio.to_thread(self.registry.remove, printer_id)
        self._apply(self.registry.printers)

    def _on_file_change(self, printers: list[PrinterConfig]) -> None:
        self.config_error = None
        self._apply(printers)
        self.hub.event({"type": "config", "ok": True, "message": "printers.json reloaded"})

    def _on_file_error(self, error: ConfigError) -> None:
        self.config_error = error.message
        self.hub.event({"type": "config", "ok": False, "message": error.message})

    def _apply(self, printers: list[PrinterConfig]) -> None:
        """Make the running sessions match ``printers``: start, stop or restart them."""
        wanted = {p.id: p for p in printers}
        for printer_id in list(self._printers):
            if printer_id not in wanted:
                self._spawn(self._close(self._printers.pop(printer_id)))
                self.hub.mark(printer_id)
        for printer_id, config in wanted.items():
            current = self._printers.get(printer_id)
            if current is not None and not _needs_new_session(current.config, config):
                current.config = config
            else:
                if current is not None:
                    self._spawn(self._close(current))
                self._printers[printer_id] = self._open(config)
            self.hub.mark(printer_id)

    def _open(self, config: PrinterConfig) -> _Printer:
        if not config.enabled:
            return _Printer(config, None, LivePrinter(connection="disabled"))
        printer = _Printer(config, None)
        printer.client = MoonrakerClient(
            config.moonraker_url,
            self._http,
            name=config.id,
            api_key=config.api_key.get_secret_value() if config.api_key else None,
            on_event=lambda event: self._on_event(printer, event),
            connect=self._connect,
        )
        printer.client.start()
        return printer

    async def _close(self, printer: _Printer) -> None:
        if printer.client is not None:
            await printer.client.close()

    # -- live state --------------------------------------------------------------------

    def _on_event(self, printer: _Printer, event: SessionEvent) -> None:
        live = printer.live
        live.updated_at = time.time()
        pid = printer.config.id
        if isinstance(event, StatusDelta):
            live.status = merge_status(live.status, event.delta)
            self._follow_file(printer)
        elif isinstance(event, StatusSnapshot):
            live.status = dict(event.status)
            self._follow_file(printer)
            self._spawn(self._detect_capabilities(printer))
        elif isinstance(event, ConnectionChanged):
            live.connection = event.connection
            live.connection_error = event.detail
            self.hub.event(
                {
                    "type": "connection",
                    "printer": pid,
                    "connection": event.connection,
                    "message": event.detail,
                }
            )
        elif isinstance(event, KlippyChanged):
            live.klippy_state = event.state
            live.klippy_message = event.message
            self.hub.event(
                {"type": "klippy", "printer": pid, "state": event.state, "message": event.message}
            )
            if event.state in ("shutdown", "error"):
                self._spawn(self._read_klippy_message(printer))
        elif isinstance(event, Notification):
            if event.method == "notify_gcode_response" and event.params:
                self.hub.console(pid, str(event.params[0]))
            return
        self.hub.mark(pid)

    def _follow_file(self, printer: _Printer) -> None:
        """Fetch the metadata of a newly started file once (ETA, thumbnail)."""
        filename = printer.live.status.get("print_stats", {}).get("filename") or ""
        meta = printer.live.file_meta
        if filename and (meta is None or meta.get("filename") != filename):
            printer.live.file_meta = {"filename": filename}
            self._spawn(self._load_file_meta(printer, filename))

    async def _load_file_meta(self, printer: _Printer, filename: str) -> None:
        if printer.client is None:
            return
        with contextlib.suppress(PrinterError):
            meta = await printer.client.file_metadata(filename)
            printer.live.file_meta = {**meta, "filename": filename}
            self.hub.mark(printer.config.id)

    async def _detect_capabilities(self, printer: _Printer) -> None:
        if printer.client is None:
            return
        with contextlib.suppress(PrinterError, KeyError, TypeError, ValueError):
            status = await printer.client.objects_query(_DETECTED_FROM_CONFIGFILE)
            printer.live.detected = detect_capabilities(status["configfile"]["settings"])
            self.hub.mark(printer.config.id)

    async def _read_klippy_message(self, printer: _Printer) -> None:
        if printer.client is None:
            return
        with contextlib.suppress(PrinterError, KeyError):
            info = await printer.client.printer_info()
            printer.live.klippy_message = str(info.get("state_message", ""))
            self.hub.mark(printer.config.id)

    def _render(self, printer_id: str) -> View | None:
        printer = self._printers.get(printer_id)
        return None if printer is None else fuse(printer.config, printer.live)

    def _spawn(self, work: Awaitable[Any]) -> None:
        task = asyncio.ensure_future(work)
        self._background.add(task)
        task.add_done_callback(self._background.discard)

    # -- actions -----------------------------------------------------------------------

    def check(
        self,
        printer_id: str,
        action: str,
        params: Mapping[str, Any] | None = None,
        file_meta: Mapping[str, Any] | None = None,
        force: bool = False,
    ) -> Verdict:
        """What validation says about ``action`` on this printer now (no side effects)."""
        printer = self._get(printer_id)
        return validate(
            action,
            facts(printer.config, printer.live),
            params=params,
            file_meta=file_meta,
            force=force,
        )

    async def dry_run(
        self,
        printer_id: str,
        action: str,
        params: Mapping[str, Any] | None = None,
        force: bool = False,
    ) -> Verdict:
        """Validate with the file's real metadata, without doing anything."""
        meta = await self._file_meta_for(printer_id, action, params)
        return self.check(printer_id, action, params, meta, force)

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
        warnings = [_reason(r) for r in verdict.reasons if r.level == "warn"]
        if warnings and not confirm:
            raise ActionRejected(
                "This action needs confirmation: "
                + "; ".join(r["en"] for r in warnings)
                + " Send it again with confirm=true to go ahead.",
                code="confirmation_required",
            )
        detail = await self._execute(printer_id, action, params)
        outcome = ActionOutcome(
            printer_id,
            action,
            True,
            200,
            _done_message(action, params),
            reasons=warnings,
            detail=detail,
        )
        self.hub.event(
            {
                "type": "action",
                "printer": printer_id,
                "action": action,
                "ok": True,
                "message": outcome.message,
            }
        )
        return outcome

    async def act_many(
        self,
        printer_ids: list[str],
        action: str,
        params: Mapping[str, Any] | None = None,
        *,
        force: bool = False,
        confirm: bool = False,
    ) -> list[ActionOutcome]:
        """One action on many printers at once; one outcome per printer, in order."""
        if not printer_ids:
            raise InvalidInput("printer_ids is empty: name at least one printer.")

        async def one(printer_id: str) -> ActionOutcome:
            try:
                return await self.act(printer_id, action, params, force=force, confirm=confirm)
            except KyberCoreError as exc:
                return failed_outcome(printer_id, action, exc)

        return list(await asyncio.gather(*(one(pid) for pid in dict.fromkeys(printer_ids))))

    async def upload(
        self,
        printer_id: str,
        filename: str,
        content: bytes,
        *,
        start: bool = False,
        confirm: bool = False,
        force: bool = False,
    ) -> ActionOutcome:
        """Upload a file; with ``start``, validate it against the printer and print it."""
        client = self.client(printer_id)
        if start:
            # Refuse before sending the bytes when the printer cannot start anything now.
            verdict = self.check(printer_id, "start", {"filename": filename}, None, force)
            raise_if_blocked(verdict, printer_id)
        result = await client.upload(filename, content)
        outcome = ActionOutcome(
            printer_id, "upload", True, 201, f"Uploaded {filename}.", detail=result
        )
        if start:
            started = await self.act(
                printer_id, "start", {"filename": filename}, force=force, confirm=confirm
            )
            outcome.message += " " + started.message
            outcome.reasons = started.reasons
        self.hub.event(
            {
                "type": "action",
                "printer": printer_id,
                "action": "upload",
                "ok": True,
                "message": outcome.message,
            }
        )
        return outcome

    async def files(self, printer_id: str) -> list[dict[str, Any]]:
        """The printer's G-code files, newest first."""
        files = await self.client(printer_id).files_list()
        return sorted(files, key=lambda f: f.get("modified", 0), reverse=True)

    async def file_metadata(self, printer_id: str, filename: str) -> dict[str, Any]:
        """Moonraker's metadata of one file."""
        return await self.client(printer_id).file_metadata(filename)

    async def _file_meta_for(
        self, printer_id: str, action: str, params: Mapping[str, Any] | None
    ) -> dict[str, Any] | None:
        filename = (params or {}).get("filename")
        if action != "start" or not isinstance(filename, str) or not filename:
            return None
        printer = self._get(printer_id)
        if printer.client is None or printer.live.connection != "online":
            return None
        try:
            return await printer.client.file_metadata(filename)
        except PrinterError as exc:
            if getattr(exc, "code", None) == 404:
                raise InvalidInput(
                    f"{printer_id}: no file '{filename}' on the printer. "
                    "Upload it first or pick one from the file list."
                ) from exc
            raise

    async def _execute(self, printer_id: str, action: str, params: Mapping[str, Any]) -> Any:
        client = self.client(printer_id)
        simple: dict[str, Callable[[], Awaitable[None]]] = {
            "pause": client.print_pause,
            "resume": client.print_resume,
            "cancel": client.print_cancel,
            "emergency_stop": client.emergency_stop,
            "firmware_restart": client.firmware_restart,
            "restart": client.restart,
        }
        if action in simple:
            await simple[action]()
            return None
        if action == "start":
            await client.print_start(str(params["filename"]))
            return None
        if action == "home":
            axes = str(params.get("axes") or "").upper()
            return await client.gcode_script("G28" + "".join(f" {a}" for a in axes if a in "XYZ"))
        if action == "set_temperature":
            return await client.gcode_script(temperature_gcode(params))
        if action == "gcode":
            return await client.gcode_script(str(params["script"]))
        raise InvalidInput(f"Unknown action '{action}'.")

    def _get(self, printer_id: str) -> _Printer:
        printer = self._printers.get(printer_id)
        if printer is None:
            raise UnknownPrinter(printer_id)
        return printer


def detect_capabilities(settings: Mapping[str, Any]) -> dict[str, Any]:
    """Build volume, nozzle and heater limits from Klippy's ``configfile.settings``."""
    detected: dict[str, Any] = {}
    with contextlib.suppress(KeyError, TypeError, ValueError):
        detected["build_volume"] = {
            axis: float(settings[f"stepper_{axis}"]["position_max"]) for axis in ("x", "y", "z")
        }
    extruder = settings.get("extruder", {})
    bed = settings.get("heater_bed", {})
    if "nozzle_diameter" in extruder:
        detected["nozzle_diameter"] = float(extruder["nozzle_diameter"])
    if "max_temp" in extruder:
        detected["max_extruder_temp"] = float(extruder["max_temp"])
    if "max_temp" in bed:
        detected["max_bed_temp"] = float(bed["max_temp"])
    return detected


def temperature_gcode(params: Mapping[str, Any]) -> str:
    """``{"extruder": 200, "bed": 60}`` -> ``M104 S200`` / ``M140 S60`` (no waiting)."""
    lines = []
    if params.get("extruder") is not None:
        lines.append(f"M104 S{float(params['extruder']):g}")
    if params.get("bed") is not None:
        lines.append(f"M140 S{float(params['bed']):g}")
    if not lines:
        raise InvalidInput("Give 'extruder' and/or 'bed' temperatures in °C.")
    return "\n".join(lines)


def raise_if_blocked(verdict: Verdict, printer_id: str) -> None:
    """Turn a blocking verdict into the error its category calls for."""
    blocking = [r for r in verdict.reasons if r.level == "block"]
    if not blocking:
        return
    message = f"{printer_id}: " + " ".join(r.en for r in blocking)
    category = verdict.blocking_category
    error: KyberCoreError
    if category == "connection":
        auth = any(r.code == "printer_auth_failed" for r in blocking)
        error = PrinterAuthFailed(message) if auth else PrinterUnreachable(message)
    elif category in ("limit", "compatibility"):
        error = InvalidInput(message)
    else:
        error = ActionRejected(message, code=blocking[0].code)
    error.reasons = tuple(_reason(r) for r in verdict.reasons)
    raise error


def failed_outcome(printer_id: str, action: str, exc: KyberCoreError) -> ActionOutcome:
    """The outcome of an action that raised ``exc``."""
    status, code = error_status(exc)
    return ActionOutcome(
        printer_id, action, False, status, exc.message, code=code, reasons=list(exc.reasons)
    )


def _reason(reason: Reason) -> dict[str, str]:
    return {
        "code": reason.code,
        "level": reason.level,
        "category": reason.category,
        "en": reason.en,
        "es": reason.es,
    }


def _needs_new_session(old: PrinterConfig, new: PrinterConfig) -> bool:
    return (old.moonraker_url, old.api_key, old.enabled) != (
        new.moonraker_url,
        new.api_key,
        new.enabled,
    )


def _require_online(printer: _Printer) -> None:
    live = printer.live
    pid = printer.config.id
    if printer.client is None:
        raise ActionRejected(
            f"{pid} is disabled. Enable it in its settings first.", code="disabled"
        )
    if live.connection == "auth_failed":
        raise PrinterAuthFailed(
            f"{pid}: Moonraker refused the API key ({live.connection_error}). "
            "Fix the printer's api_key."
        )
    if live.connection != "online":
        raise PrinterUnreachable(
            f"{pid} is {live.connection}: {live.connection_error or 'not connected yet'}. "
            "KyberCore reconnects by itself; retry when it is online."
        )


_DONE = {
    "start": "Print started: {filename}.",
    "pause": "Print paused.",
    "resume": "Print resumed.",
    "cancel": "Print cancelled.",
    "emergency_stop": "Emergency stop sent: Klippy is shut down. Use firmware restart to recover.",
    "firmware_restart": "Firmware restart sent.",
    "restart": "Klippy restart sent.",
    "home": "Homed.",
    "set_temperature": "Temperatures set.",
    "gcode": "G-code done.",
}


def _done_message(action: str, params: Mapping[str, Any]) -> str:
    return _DONE.get(action, "Done.").format(filename=params.get("filename", ""))
