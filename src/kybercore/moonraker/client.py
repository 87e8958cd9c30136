"""All of one printer's Moonraker I/O: HTTP requests and the long-lived WebSocket session.

This module knows Moonraker and nothing of KyberCore's fleet, FastAPI or printers.json.
Every failure is a typed :mod:`kybercore.errors` exception whose message says what
happened and what to do; no method returns ``None`` to mean "it failed".
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
import os
import socket
from collections.abc import Mapping
from typing import Any, BinaryIO, Final
from urllib.parse import quote, urlsplit, urlunsplit

import httpx
import picows

from kybercore import __version__
from kybercore.errors import (
    MoonrakerRpcError,
    PrinterUnreachable,
)
from kybercore.moonraker.answers import Shapes
from kybercore.moonraker.channel import Channel
from kybercore.moonraker.events import EventCallback, SessionEvent
from kybercore.moonraker.http import (
    ACTION_TIMEOUT,
    GCODE_TIMEOUT,
    UPLOAD_TIMEOUT,
    json_body,
)
from kybercore.moonraker.link import Connect
from kybercore.moonraker.objects import Status
from kybercore.moonraker.session import MoonrakerSession

log = logging.getLogger(__name__)


FLEET_OBJECTS: Final[Mapping[str, list[str] | None]] = {
    "webhooks": ["state", "state_message"],
    "print_stats": None,
    "virtual_sdcard": ["progress", "is_active", "file_position", "file_size"],
    "display_status": ["progress", "message"],
    "toolhead": ["position", "homed_axes", "axis_minimum", "axis_maximum", "status"],
    "extruder": ["temperature", "target", "power", "can_extrude"],
    "heater_bed": ["temperature", "target", "power"],
    "fan": ["speed"],
    "gcode_move": ["speed_factor", "extrude_factor", "homing_origin"],
    "idle_timeout": ["state"],
}
"""What the fleet view needs. ``configfile`` is large: query it once, never subscribe."""


# Moonraker keeps one agent per name: two KyberCore processes on one printer must differ.
METHOD_NOT_FOUND: Final = -32601
"""JSON-RPC's code for a method Moonraker does not have (a component not loaded)."""
AGENT_NAME: Final = f"KyberCore {socket.gethostname()}:{os.getpid()}"


def websocket_url(base_url: str) -> str:
    """``http://host:7125`` -> ``ws://host:7125/websocket`` (https -> wss)."""
    parts = urlsplit(base_url)
    scheme = "wss" if parts.scheme == "https" else "ws"
    path = parts.path.rstrip("/") + "/websocket"
    return urlunsplit((scheme, parts.netloc, path, "", ""))


class MoonrakerClient:
    """One printer's Moonraker: HTTP calls plus an optional live session.

    ``http`` is shared and owned by the caller. Call :meth:`start` to open the WebSocket
    session that feeds ``on_event``; HTTP methods work with or without it.
    """

    def __init__(
        self,
        base_url: str,
        http: httpx.AsyncClient,
        *,
        name: str = "printer",
        api_key: str | None = None,
        on_event: EventCallback | None = None,
        subscription: Mapping[str, list[str] | None] = FLEET_OBJECTS,
        client_name: str = AGENT_NAME,
        connect: Connect = picows.ws_connect,
    ) -> None:
        self.base_url = base_url.rstrip("/")
        self.name = name
        self.session = MoonrakerSession(
            websocket_url(self.base_url),
            name=name,
            api_key=api_key,
            subscription=subscription,
            on_event=on_event or _ignore,
            client_name=client_name,
            version=__version__,
            connect=connect,
        )
        headers = {"X-Api-Key": api_key} if api_key else {}
        self._channel = Channel(self.base_url, http, headers, self.session, name)
        self._shapes = Shapes(self.base_url, name)

    # -- session -----------------------------------------------------------------------

    def start(self) -> None:
        """Open the WebSocket session in the background; it reconnects by itself."""
        self.session.start()

    async def close(self) -> None:
        """Stop the WebSocket session (the shared HTTP client stays open)."""
        await self.session.stop()

    async def call(self, method: str, params: Mapping[str, Any] | None = None) -> Any:
        """A JSON-RPC call over the live WebSocket session."""
        return await self._channel.rpc(method, params)

    # -- printer -----------------------------------------------------------------------

    async def printer_info(self) -> dict[str, Any]:
        """Klippy's ``/printer/info``: state, state_message, hostname, software_version."""
        return await self._get_object("/printer/info")

    async def server_info(self) -> dict[str, Any]:
        """Moonraker's ``/server/info``, including ``klippy_state``."""
        return await self._get_object("/server/info")

    async def objects_list(self) -> list[str]:
        """Names of every printer object Klippy has loaded."""
        what = "GET /printer/objects/list"
        result = await self._channel.request("GET", "/printer/objects/list")
        return self._shapes.names(self._shapes.field(result, "objects", what), what)

    async def objects_query(self, objects: Mapping[str, list[str] | None]) -> Status:
        """Current values of ``objects`` (``None`` = every field of that object)."""
        if self.session.connected:
            result = await self._channel.rpc("printer.objects.query", {"objects": dict(objects)})
            return self._shapes.status(result, "printer.objects.query")
        params = {obj: ",".join(fields) if fields else "" for obj, fields in objects.items()}
        result = await self._channel.request("GET", "/printer/objects/query", params=params)
        return self._shapes.status(result, "GET /printer/objects/query")

    async def gcode_script(self, script: str, timeout: float | None = None) -> str:
        """Run G-code; returns when Klippy has finished it (which may take minutes)."""
        limit = GCODE_TIMEOUT if timeout is None else httpx.Timeout(timeout, connect=3.0)
        result = await self._channel.request(
            "POST", "/printer/gcode/script", params={"script": script}, timeout=limit
        )
        return str(result)

    async def gcode_with_output(self, script: str) -> list[str]:
        """Run G-code as a console does and return Klipper's response lines
        (``// FIRMWARE_NAME:...``, ``!! Unknown command``); Klipper's refusals raise.

        Over the live session: Moonraker sends the ``notify_gcode_response`` lines on the
        same socket before the call's answer, so they are all in by then (a request over
        HTTP could be answered before the socket delivers them). Lines other clients'
        commands caused meanwhile are in the list too. Without a session: over HTTP, and
        no lines.
        """
        if not self.session.connected:
            await self.gcode_script(script)
            return []
        with self.session.gcode_responses() as lines:
            await self._channel.rpc(
                "printer.gcode.script", {"script": script}, GCODE_TIMEOUT.read or 600.0
            )
        return lines

    async def print_start(self, filename: str) -> None:
        """Start printing ``filename`` (relative to the gcodes root)."""
        await self._channel.request(
            "POST", "/printer/print/start", params={"filename": filename}, timeout=ACTION_TIMEOUT
        )

    async def print_pause(self) -> None:
        """Pause the running print."""
        await self._action("printer.print.pause", "/printer/print/pause")

    async def print_resume(self) -> None:
        """Resume a paused print."""
        await self._action("printer.print.resume", "/printer/print/resume")

    async def print_cancel(self) -> None:
        """Cancel the current print."""
        await self._action("printer.print.cancel", "/printer/print/cancel")

    async def _action(self, method: str, path: str) -> None:
        """A print action over the open WebSocket, else over HTTP.

        With a thousand printers, a request per printer on the shared HTTP pool is what
        slows a bulk action down; the socket is already open.
        """
        if self.session.connected:
            await self._channel.rpc(method, None, ACTION_TIMEOUT.read or 60.0)
        else:
            await self._channel.request("POST", path, timeout=ACTION_TIMEOUT)

    async def emergency_stop(self) -> None:
        """Stop the machine now (Moonraker's emergency stop, never ``M112`` queued as G-code).

        Over the open WebSocket first: the fastest way there, with no connection to make.
        If the socket drops under it, the stop goes again over HTTP (a second e-stop is
        harmless; a lost one is not). A Moonraker that stops answering on an open socket
        would not answer HTTP either: that fails as unreachable, at once.
        """
        if self.session.connected:
            try:
                await self._channel.rpc("printer.emergency_stop", None)
            except PrinterUnreachable as exc:
                if self.session.connected:
                    raise
                log.warning("%s: e-stop over the WebSocket failed (%s); HTTP now", self.name, exc)
            else:
                return
        await self._channel.request("POST", "/printer/emergency_stop")

    async def restart(self) -> None:
        """Restart Klippy's host software (re-reads printer.cfg)."""
        await self._channel.request("POST", "/printer/restart", timeout=ACTION_TIMEOUT)

    async def firmware_restart(self) -> None:
        """Restart the MCU firmware and Klippy; the way out of ``shutdown``."""
        await self._channel.request("POST", "/printer/firmware_restart", timeout=ACTION_TIMEOUT)

    # -- files -------------------------------------------------------------------------

    async def files_list(self, root: str = "gcodes") -> list[dict[str, Any]]:
        """Every file under ``root``: ``[{path, modified, size, permissions}]``."""
        result = await self._channel.request("GET", "/server/files/list", params={"root": root})
        return self._shapes.objects(result, "GET /server/files/list")

    async def file_metadata(self, filename: str) -> dict[str, Any]:
        """Slicer metadata Moonraker parsed from the file's header."""
        params = {"filename": filename}
        if not self.session.connected:
            return await self._get_object("/server/files/metadata", params=params)
        try:
            result = await self._channel.rpc("server.files.metadata", params)
            return self._shapes.object(result, "server.files.metadata")
        except MoonrakerRpcError as exc:
            # Over JSON-RPC Moonraker says -32601 where HTTP says 404: keep one meaning.
            if "not available" in exc.detail:
                raise MoonrakerRpcError(404, exc.detail, printer=self.name) from exc
            raise

    async def file_thumbnails(self, filename: str) -> list[dict[str, Any]]:
        """Thumbnails of a file: ``[{width, height, size, thumbnail_path}]``."""
        params = {"filename": filename}
        result = await self._channel.request("GET", "/server/files/thumbnails", params=params)
        return self._shapes.objects(result, "GET /server/files/thumbnails")

    async def download(self, path: str, root: str = "gcodes") -> bytes:
        """The raw bytes of a file (a G-code, or a thumbnail under ``.thumbs/``)."""
        response = await self._channel.send("GET", f"/server/files/{root}/{quote(path)}")
        return response.content

    async def upload(
        self, filename: str, content: bytes | BinaryIO, *, start: bool = False, root: str = "gcodes"
    ) -> dict[str, Any]:
        """Upload a file (with a sha256 checksum Moonraker verifies); optionally print it.

        ``content`` may be an open binary file: it is streamed, never loaded whole.
        """
        # Up to 512 MiB read and hashed: in a worker thread, never on the event loop.
        checksum = await asyncio.to_thread(_sha256, content)
        data = {
            "root": root,
            "checksum": checksum,
            "print": "true" if start else "false",
        }
        folder, _, name = filename.rpartition("/")
        if folder:
            # Moonraker creates missing folders only from the ``path`` field; a folder in
            # the file name alone fails with "Unable to save file".
            data["path"] = folder
        files = {"file": (name, content, "application/octet-stream")}
        response = await self._channel.send(
            "POST", "/server/files/upload", data=data, files=files, timeout=UPLOAD_TIMEOUT
        )
        # The one Moonraker endpoint whose answer is not wrapped in {"result": ...}.
        return self._shapes.object(json_body(response, self.name), "POST /server/files/upload")

    async def delete_file(self, path: str, root: str = "gcodes") -> None:
        """Delete a file."""
        await self._channel.request("DELETE", f"/server/files/{root}/{quote(path)}")

    # -- history, console, webcams -----------------------------------------------------

    async def history_list(
        self, limit: int = 50, start: int = 0, *, order: str = "desc"
    ) -> dict[str, Any]:
        """Past jobs, newest first (``order="asc"``: oldest first): ``{count, jobs: [...]}``.

        Each job: ``{job_id, filename, status, start_time, end_time, print_duration, ...}``;
        ``status`` is ``in_progress|completed|cancelled|error|klippy_shutdown|
        klippy_disconnect|interrupted``."""
        params = {"limit": str(limit), "start": str(start), "order": order}
        return await self._read("server.history.list", "/server/history/list", params)

    async def history_job(self, uid: str) -> dict[str, Any]:
        """One past or running job by its history id (``job_id``, hex); a
        :class:`MoonrakerRpcError` with ``rpc_code`` 404 when Moonraker has no such job."""
        what = "GET /server/history/job"
        result = await self._get_object("/server/history/job", params={"uid": uid})
        return self._shapes.object(self._shapes.field(result, "job", what), what)

    async def history_totals(self) -> dict[str, Any]:
        """Totals over every job: ``{job_totals: {total_jobs, total_time, ...}}``."""
        return await self._get_object("/server/history/totals")

    async def gcode_store(self, count: int = 100) -> list[dict[str, Any]]:
        """The console's recent commands and responses: ``[{message, time, type}]``."""
        what = "GET /server/gcode_store"
        result = await self._channel.request(
            "GET", "/server/gcode_store", params={"count": str(count)}
        )
        return self._shapes.objects(self._shapes.field(result, "gcode_store", what), what)

    async def webcams_list(self) -> list[dict[str, Any]]:
        """Configured webcams: ``[{name, stream_url, snapshot_url, ...}]``."""
        what = "GET /server/webcams/list"
        result = await self._channel.request("GET", "/server/webcams/list")
        return self._shapes.objects(self._shapes.field(result, "webcams", what), what)

    async def active_spool_id(self) -> int | None:
        """The Spoolman spool Moonraker has active (None: none set). Moonraker without
        ``[spoolman]`` answers 404: :class:`MoonrakerRpcError`."""
        result = await self._read("server.spoolman.get_spool_id", "/server/spoolman/spool_id")
        spool_id = result.get("spool_id")
        return spool_id if isinstance(spool_id, int) else None

    async def spoolman_spool(self, spool_id: int) -> dict[str, Any]:
        """Spoolman's ``GET /api/v1/spool/{id}``, relayed by Moonraker (read only)."""
        result = await self._channel.request(
            "POST",
            "/server/spoolman/proxy",
            json={"request_method": "GET", "path": f"/v1/spool/{spool_id}"},
        )
        return self._shapes.object(result, "POST /server/spoolman/proxy")

    async def _read(
        self, method: str, path: str, params: Mapping[str, str] | None = None
    ) -> dict[str, Any]:
        """A read every printer gets when it connects: over its open WebSocket (JSON-RPC
        ``method``), else ``GET path``. At 1,000 printers, 1,000 HTTP requests at once to
        1,000 hosts went through one connection pool whose bookkeeping grows with their
        product: a third of start-up's CPU. An unknown method is a 404, as over HTTP."""
        if not self.session.connected:
            return await self._get_object(path, params=params)
        try:
            result = await self._channel.rpc(method, params)
        except MoonrakerRpcError as exc:
            if exc.rpc_code != METHOD_NOT_FOUND:
                raise
            raise MoonrakerRpcError(404, exc.detail, printer=self.name) from exc
        return self._shapes.object(result, method)

    async def _get_object(self, path: str, **kwargs: Any) -> dict[str, Any]:
        """``GET path``, whose result must be a JSON object."""
        result = await self._channel.request("GET", path, **kwargs)
        return self._shapes.object(result, f"GET {path}")


def _sha256(content: bytes | BinaryIO) -> str:
    if isinstance(content, bytes):
        return hashlib.sha256(content).hexdigest()
    digest = hashlib.sha256()
    while chunk := content.read(1024 * 1024):
        digest.update(chunk)
    content.seek(0)
    return digest.hexdigest()


def _ignore(_event: SessionEvent) -> None:
    """Default event sink for clients used for HTTP only."""
