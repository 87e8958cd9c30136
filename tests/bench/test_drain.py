"""The benches' draining browser reads what a real WebSocket server sends it, compressed
(permessage-deflate, as Chromium negotiates it) or not."""

from __future__ import annotations

import asyncio

import orjson
import pytest
from bench.drain import DrainClient
from websockets.asyncio.server import ServerConnection, serve

SNAPSHOT = orjson.dumps({"type": "snapshot", "printers": [{"id": "p1", "job": {"x": 1}}]})


@pytest.mark.parametrize("deflate", [False, True])
async def test_a_draining_browser_reads_snapshots_and_sends_its_view(deflate: bool) -> None:
    negotiated: list[bool] = []
    views: list[object] = []

    async def dashboard_side(ws: ServerConnection) -> None:
        negotiated.append(bool(ws.protocol.extensions))
        # Twice the same: with context takeover, the second one refers to the first's bytes.
        await ws.send(SNAPSHOT.decode())
        await ws.send(SNAPSHOT.decode())
        views.append(orjson.loads(await ws.recv()))
        await ws.send(orjson.dumps({"type": "delta", "printers": {}, "full": {}}).decode())
        await ws.wait_closed()

    async with serve(dashboard_side, "127.0.0.1", 0) as server:  # compression on by default
        port = server.sockets[0].getsockname()[1]
        loop = asyncio.get_running_loop()
        ready: asyncio.Future[None] = loop.create_future()
        _, drain = await loop.create_connection(
            lambda: DrainClient("127.0.0.1", port, ready, ["p1"], deflate), "127.0.0.1", port
        )
        try:
            async with asyncio.timeout(30):
                await ready  # the view was sent, and the delta with its full part read
        finally:
            drain.close()
    assert negotiated == [deflate]
    assert views == [{"type": "view", "printers": ["p1"]}]
    assert drain.snapshots == 2
    assert drain.frames == 3
