"""FAULT-INJECTION stand-in — not Moonraker: a proxy in front of a REAL Moonraker that
accepts print starts and never lets them happen, or lets them happen late.

A real Moonraker that is told to start a print either starts it or says why not; the queue
must also survive one that says yes and does nothing (a broken proxy, a firmware macro
that swallows ``SDCARD_PRINT_FILE``, a Moonraker that queues the file instead). Everything
else passes through to the real Moonraker behind it (HTTP and the WebSocket), so the
printer is online, ready and answers every other call truthfully.

Scenarios:

``swallow_start``  ``POST /printer/print/start`` and ``printer.print.start`` answer
                   ``"ok"`` and are never forwarded.
``queued_upload``  as above, and every upload answers 201 with ``print_started: false``,
                   ``print_queued: true``: what Moonraker answers when a file went to its
                   job queue instead of the printer.
``held_start``     ``POST /printer/print/start`` waits until :meth:`release_starts`, then
                   goes to the real Moonraker (the print starts then, late: after the
                   caller may have given up, or died).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from typing import Final

import httpx
import uvicorn
import websockets
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Route, WebSocketRoute
from starlette.websockets import WebSocket, WebSocketDisconnect

from kybercore.sim.stack import free_port

SCENARIOS: Final = ("swallow_start", "queued_upload", "held_start")
SWALLOWING: Final = ("swallow_start", "queued_upload")
_HOP_HEADERS: Final = frozenset(
    {"host", "content-length", "transfer-encoding", "connection", "keep-alive", "upgrade"}
)


class StartFaultProxy:
    """FAULT-INJECTION stand-in — not Moonraker. See the module docstring."""

    def __init__(self, upstream: str, scenario: str) -> None:
        if scenario not in SCENARIOS:
            raise ValueError(f"unknown scenario {scenario!r}; one of {', '.join(SCENARIOS)}")
        self.upstream = upstream.rstrip("/")
        self.scenario = scenario
        self.port = free_port()
        self.starts_swallowed: list[str] = []
        """File names of the starts answered "ok" and dropped."""
        self.starts_held: list[str] = []
        """File names of the starts held (``held_start``)."""
        self._released = asyncio.Event()
        self._http = httpx.AsyncClient(timeout=httpx.Timeout(300.0), trust_env=False)
        app = Starlette(
            routes=[
                WebSocketRoute("/websocket", self._websocket),
                Route(
                    "/{path:path}",
                    self._relay,
                    methods=["GET", "POST", "DELETE", "PUT", "PATCH", "OPTIONS"],
                ),
            ]
        )
        config = uvicorn.Config(
            app,
            host="127.0.0.1",
            port=self.port,
            log_level="warning",
            lifespan="off",
            timeout_graceful_shutdown=1,
        )
        self._server = uvicorn.Server(config)
        self._task: asyncio.Task[None] | None = None
        self._upstreams: set[websockets.ClientConnection] = set()

    @property
    def url(self) -> str:
        """Its base URL, as printers.json holds it."""
        return f"http://127.0.0.1:{self.port}"

    async def start(self) -> None:
        """Serve on 127.0.0.1 until :meth:`stop`."""
        self._task = asyncio.create_task(self._server.serve())
        while not self._server.started:
            if self._task.done():
                self._task.result()
            await asyncio.sleep(0.01)  # stand-in: uvicorn offers no started event

    async def stop(self) -> None:
        """Stop serving and close the connections to the real Moonraker."""
        self._released.set()  # a start still held is answered, never sent
        for upstream in list(self._upstreams):
            await upstream.close()  # ends its relay, so the server stops without cancelling
        self._server.should_exit = True
        if self._task is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._task, 10)
        await self._http.aclose()

    # -- HTTP --------------------------------------------------------------------------

    async def release_starts(self) -> None:
        """Send the held starts to the real Moonraker now (whoever asked for them may be
        gone), and let every later one through."""
        self._released.set()
        for filename in self.starts_held:
            answer = await self._http.post(
                f"{self.upstream}/printer/print/start", params={"filename": filename}
            )
            answer.raise_for_status()

    async def _relay(self, request: Request) -> Response:
        path = "/" + request.path_params["path"]
        if path == "/printer/print/start" and request.method == "POST":
            filename = request.query_params.get("filename", "")
            if self.scenario != "held_start":
                self.starts_swallowed.append(filename)
                return JSONResponse({"result": "ok"})
            if not self._released.is_set():
                self.starts_held.append(filename)
                await self._released.wait()
                return JSONResponse({"result": "ok"})  # release_starts() sent it
        headers = {k: v for k, v in request.headers.items() if k.lower() not in _HOP_HEADERS}
        answer = await self._http.request(
            request.method,
            self.upstream + path,
            params=list(request.query_params.multi_items()),
            headers=headers,
            content=await request.body(),
        )
        body = answer.content
        queued = self.scenario == "queued_upload" and answer.is_success
        if path == "/server/files/upload" and queued:
            result = json.loads(body)
            result.update(print_started=False, print_queued=True)
            body = json.dumps(result).encode()
        kept = {k: v for k, v in answer.headers.items() if k.lower() not in _HOP_HEADERS}
        kept.pop("content-encoding", None)  # httpx decoded the body
        return Response(body, status_code=answer.status_code, headers=kept)

    # -- WebSocket ---------------------------------------------------------------------

    async def _websocket(self, downstream: WebSocket) -> None:
        await downstream.accept()
        upstream_url = "ws" + self.upstream.removeprefix("http") + "/websocket"
        async with websockets.connect(upstream_url, max_size=None) as upstream:
            self._upstreams.add(upstream)

            async def down_to_up() -> None:
                with contextlib.suppress(WebSocketDisconnect):
                    while True:
                        frame = await downstream.receive_text()
                        message = json.loads(frame)
                        swallowing = self.scenario in SWALLOWING
                        if message.get("method") == "printer.print.start" and swallowing:
                            params = message.get("params") or {}
                            self.starts_swallowed.append(str(params.get("filename", "")))
                            answer = {"jsonrpc": "2.0", "id": message.get("id"), "result": "ok"}
                            await downstream.send_text(json.dumps(answer))
                            continue
                        await upstream.send(frame)

            async def up_to_down() -> None:
                with contextlib.suppress(websockets.ConnectionClosed):
                    async for frame in upstream:
                        await downstream.send_text(
                            frame if isinstance(frame, str) else frame.decode()
                        )

            tasks = [asyncio.create_task(down_to_up()), asyncio.create_task(up_to_down())]
            try:
                await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
            finally:
                for task in tasks:
                    task.cancel()
                await asyncio.gather(*tasks, return_exceptions=True)
                self._upstreams.discard(upstream)
        with contextlib.suppress(Exception):
            await downstream.close()
