"""``/ws``: the browser's live socket. A snapshot of the fleet first, then coalesced
deltas and events from the fleet hub, with a heartbeat whenever the fleet is quiet.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from typing import Final

import orjson
from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from kybercore.api.deps import Service
from kybercore.api.security import websocket_identity

HEARTBEAT_SECONDS: Final = 10.0

router = APIRouter()


@router.websocket("/ws")
async def browser_socket(websocket: WebSocket, service: Service) -> None:
    """Snapshot, then coalesced deltas and events; send ``{"type": "console",
    "printers": [ids]}`` to receive those printers' G-code responses."""
    if websocket_identity(websocket) is None:
        # Before accept: the browser sees a failed handshake, no data leaks.
        await websocket.close(code=4401)
        return
    await websocket.accept()
    hub = service.hub
    client = hub.connect()

    async def send() -> None:
        while True:
            try:
                frame = await asyncio.wait_for(client.queue.get(), HEARTBEAT_SECONDS)
            except TimeoutError:
                frame = orjson.dumps({"type": "heartbeat", "time": time.time()})
            await websocket.send_text(frame.decode())

    sender = asyncio.create_task(send())
    try:
        while True:
            message = await websocket.receive_json()
            if isinstance(message, dict) and message.get("type") == "console":
                wanted = message.get("printers")
                client.console = {str(p) for p in wanted} if isinstance(wanted, list) else set()
    except (WebSocketDisconnect, ValueError, RuntimeError):
        pass
    finally:
        hub.disconnect(client)
        sender.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await sender
