"""Fake: a Spoolman server, for the tests of KyberCore's spool support.

Spoolman's server is not on PyPI (only a client library is) and this machine reaches no
other package source, so the tests serve the part of Spoolman's API that Moonraker's
``[spoolman]`` component uses (read from Moonraker's components/spoolman.py): ``GET
/api/v1/info``, ``GET /api/v1/spool/{id}``, ``PUT /api/v1/spool/{id}/use`` and the
``/api/v1/spool`` WebSocket Moonraker holds open (its proxy refuses requests without it).
The spool JSON has Spoolman's shape (``filament.material``, ``filament.color_hex``,
``remaining_weight`` ...). A real uvicorn server on 127.0.0.1, in a thread of its own.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import uvicorn
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import JSONResponse
from starlette.routing import Route, WebSocketRoute
from starlette.websockets import WebSocket, WebSocketDisconnect

from kybercore.sim.stack import PrinterStack, free_port
from tests.helpers import wait_until


def spool(spool_id: int, material: str, color: str, remaining: float) -> dict[str, Any]:
    """A spool as Spoolman returns it."""
    return {
        "id": spool_id,
        "registered": "2026-01-01T00:00:00Z",
        "filament": {
            "id": spool_id,
            "name": f"Basic {material}",
            "vendor": {"id": 1, "name": "Acme"},
            "material": material,
            "color_hex": color,
            "density": 1.24,
            "diameter": 1.75,
            "weight": 1000.0,
        },
        "remaining_weight": remaining,
        "used_weight": 1000.0 - remaining,
        "archived": False,
    }


class FakeSpoolman:
    """See the module docstring. ``uses`` records every ``PUT .../use`` (from Moonraker)."""

    def __init__(self, spools: list[dict[str, Any]]) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.spools = {s["id"]: s for s in spools}
        self.uses: list[tuple[int, dict[str, Any]]] = []
        self.sockets = 0
        app = Starlette(
            routes=[
                Route("/api/v1/info", self._info),
                Route("/api/v1/spool/{spool_id:int}", self._spool),
                Route("/api/v1/spool/{spool_id:int}/use", self._use, methods=["PUT"]),
                WebSocketRoute("/api/v1/spool", self._socket),
            ]
        )
        config = uvicorn.Config(app, host="127.0.0.1", port=self.port, log_level="warning")
        self._server = uvicorn.Server(config)
        self._thread = threading.Thread(target=self._server.run, daemon=True)

    def start(self) -> None:
        self._thread.start()
        deadline = time.monotonic() + 30
        while not self._server.started:
            if time.monotonic() > deadline or not self._thread.is_alive():
                raise RuntimeError("the fake Spoolman did not start")
            time.sleep(0.01)  # stand-in: uvicorn offers no started event

    def stop(self) -> None:
        self._server.should_exit = True
        self._thread.join(timeout=10)

    async def _info(self, _: Request) -> JSONResponse:
        return JSONResponse({"version": "0.22.1", "debug_mode": False, "automatic_backups": True})

    async def _spool(self, request: Request) -> JSONResponse:
        found = self.spools.get(request.path_params["spool_id"])
        if found is None:
            return JSONResponse({"message": "Spool not found."}, status_code=404)
        return JSONResponse(found)

    async def _use(self, request: Request) -> JSONResponse:
        spool_id = request.path_params["spool_id"]
        self.uses.append((spool_id, await request.json()))
        return JSONResponse(self.spools.get(spool_id, {}))

    async def _socket(self, websocket: WebSocket) -> None:
        await websocket.accept()
        self.sockets += 1
        try:
            while True:
                await websocket.receive_text()
        except WebSocketDisconnect:
            self.sockets -= 1


def printer_with_spoolman(
    start_stack: Callable[..., PrinterStack], name: str, spoolman: FakeSpoolman
) -> PrinterStack:
    """A virtual printer whose moonraker.conf has ``[spoolman]`` on ``spoolman``, ready,
    with Moonraker's socket to Spoolman open."""
    stack = start_stack(name, wait=False)
    stack.stop_moonraker()
    conf = stack.data_dir / "config" / "moonraker.conf"
    conf.write_text(conf.read_text() + f"\n[spoolman]\nserver: {spoolman.url}\n")
    stack.start_moonraker()
    stack.wait_ready()
    wait_until(lambda: spoolman.sockets > 0, timeout=30, what="Moonraker's socket to Spoolman")
    return stack
