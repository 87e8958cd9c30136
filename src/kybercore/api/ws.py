"""``/ws``: the browser's live socket. A snapshot of the fleet first, then coalesced
deltas and events from the fleet hub, with a heartbeat whenever the fleet is quiet.

Frames go out as binary messages of UTF-8 JSON: the hub encodes each frame once for many
clients, and a text message would cost a decode (and a re-encode) per client per frame.

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
from kybercore.fleet.hub import Hub, HubClient

HEARTBEAT_SECONDS: Final = 10.0
ACCESS_CHECK_SECONDS: Final = 1.0
"""How often an open socket's credential is checked again (one stat of tokens.json)."""
UNAUTHORIZED: Final = 4401

router = APIRouter()


@router.websocket("/ws")
async def browser_socket(websocket: WebSocket, service: Service) -> None:
    """Snapshot, then coalesced deltas and events; send ``{"type": "console",
    "printers": [ids]}`` to receive those printers' G-code responses, and ``{"type":
    "view", "printers": [ids]}`` to get full views of those printers only and slim summaries
    of the others (``"printers": null``: every printer in full, the default).

    ``/ws?view=id1,id2`` sets that view from the start (``?view=``: none in full), so the
    first snapshot is already the view's: a page that knows what it shows (a reconnect,
    a printer's page) does not download every printer in full first."""
    access: Access = websocket.app.state.access

    def allowed() -> bool:
        return access.identify(websocket.headers, websocket.cookies) is not None

    if not allowed():
        # Before accept: the browser sees a failed handshake, no data leaks.
        await websocket.close(code=UNAUTHORIZED)
        return
    await websocket.accept()
    hub = service.hub
    client = hub.connect(_view(websocket.query_params.get("view")))
    if (cut_off := service.broker_frame()) is not None:
        client.queue.put_nowait(orjson.dumps(cut_off))
    sender = asyncio.create_task(_send(websocket, client))
    receiver = asyncio.create_task(_receive(websocket, hub, client))
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


def _view(ids: str | None) -> list[str] | None:
    """The printers a ``?view=`` names (ids never contain commas); None without one."""
    if ids is None:
        return None
    return [i for i in ids.split(",") if i]


async def _send(websocket: WebSocket, client: HubClient) -> None:
    while True:
        try:
            frame = await asyncio.wait_for(client.queue.get(), HEARTBEAT_SECONDS)
        except TimeoutError:
            frame = orjson.dumps({"type": "heartbeat", "time": time.time()})
        await websocket.send_bytes(frame)


async def _receive(websocket: WebSocket, hub: Hub, client: HubClient) -> None:
    with contextlib.suppress(WebSocketDisconnect, ValueError, RuntimeError):
        while True:
            message = await websocket.receive_json()
            if not isinstance(message, dict):
                continue
            wanted = message.get("printers")
            if message.get("type") == "console":
                client.console = {str(p) for p in wanted} if isinstance(wanted, list) else set()
            elif message.get("type") == "view" and (wanted is None or isinstance(wanted, list)):
                hub.watch(client, None if wanted is None else [str(p) for p in wanted])


async def _while_allowed(allowed: Callable[[], bool]) -> None:
    """Return once the socket's credential no longer holds (tokens.json may change from
    another process, the CLI: there is nothing to wait on but the file)."""
    while True:
        await asyncio.sleep(ACCESS_CHECK_SECONDS)
        if not allowed():
            return
