"""``/ws``: the browser's live socket. A snapshot of the fleet first, then coalesced
deltas and events from the fleet hub, with a heartbeat whenever the fleet is quiet.

Host and origin were checked at the door (:mod:`kybercore.api.guard`); the credential is
checked at the handshake and then every :data:`ACCESS_CHECK_SECONDS`, so a revoked token,
an ended session or a server that starts asking for tokens closes the socket (code 4401).
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable
from typing import Final

import orjson
from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from kybercore.api.deps import Service
from kybercore.api.security import Access
from kybercore.fleet.hub import HubClient

HEARTBEAT_SECONDS: Final = 10.0
ACCESS_CHECK_SECONDS: Final = 1.0
"""How often an open socket's credential is checked again (one stat of tokens.json)."""
UNAUTHORIZED: Final = 4401

router = APIRouter()


@router.websocket("/ws")
async def browser_socket(websocket: WebSocket, service: Service) -> None:
    """Snapshot, then coalesced deltas and events; send ``{"type": "console",
    "printers": [ids]}`` to receive those printers' G-code responses."""
    access: Access = websocket.app.state.access

    def allowed() -> bool:
        return access.identify(websocket.headers, websocket.cookies) is not None

    if not allowed():
        # Before accept: the browser sees a failed handshake, no data leaks.
        await websocket.close(code=UNAUTHORIZED)
        return
    await websocket.accept()
    hub = service.hub
    client = hub.connect()
    sender = asyncio.create_task(_send(websocket, client))
    receiver = asyncio.create_task(_receive(websocket, client))
    guard = asyncio.create_task(_while_allowed(allowed))
    tasks = (sender, receiver, guard)
    try:
        await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        if guard.done():
            with contextlib.suppress(Exception):  # the client may be gone already
                await websocket.close(code=UNAUTHORIZED)
    finally:
        hub.disconnect(client)
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


async def _send(websocket: WebSocket, client: HubClient) -> None:
    while True:
        try:
            frame = await asyncio.wait_for(client.queue.get(), HEARTBEAT_SECONDS)
        except TimeoutError:
            frame = orjson.dumps({"type": "heartbeat", "time": time.time()})
        await websocket.send_text(frame.decode())


async def _receive(websocket: WebSocket, client: HubClient) -> None:
    with contextlib.suppress(WebSocketDisconnect, ValueError, RuntimeError):
        while True:
            message = await websocket.receive_json()
            if isinstance(message, dict) and message.get("type") == "console":
                wanted = message.get("printers")
                client.console = {str(p) for p in wanted} if isinstance(wanted, list) else set()


async def _while_allowed(allowed: Callable[[], bool]) -> None:
    """Return once the socket's credential no longer holds (tokens.json may change from
    another process, the CLI: there is nothing to wait on but the file)."""
    while True:
        await asyncio.sleep(ACCESS_CHECK_SECONDS)
        if not allowed():
            return
