"""The ceiling: a bare loop consuming the same N Moonraker streams KyberCore consumes.

Per printer, the same WebSocket handshake KyberCore does (identify, ``server.info``,
``printer.objects.subscribe``), then ``websockets`` ``recv`` + ``json.loads`` and a count:
no state, no views, no browsers. What KyberCore ingests is reported as a fraction of this.

``python -m bench.baseline --ports-file F --seconds S`` prints one JSON line:
``{"events", "seconds", "events_per_s", "cpu_seconds", "connected"}``.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import time
from pathlib import Path

import orjson
import websockets
from websockets.asyncio.client import ClientConnection

# kybercore ships no py.typed marker; mypy sees it as an untyped installed package.
from kybercore.moonraker.client import FLEET_OBJECTS  # type: ignore[import-untyped, unused-ignore]

# Opening 5,000 sockets at once only measures the kernel's accept queue; a few hundred at a
# time connect as fast without dropped SYNs.
CONNECT_CONCURRENCY = 200


class Counter:
    """Connections made, and events received while the window is open."""

    def __init__(self, expected: int) -> None:
        self.expected = expected
        self.connected = 0
        self.all_connected = asyncio.Event()
        self.events = 0
        self.counting = False

    def connection_made(self) -> None:
        """One more stream subscribed."""
        self.connected += 1
        if self.connected == self.expected:
            self.all_connected.set()


async def _call(ws: ClientConnection, req_id: int, method: str, params: object = None) -> None:
    request: dict[str, object] = {"jsonrpc": "2.0", "id": req_id, "method": method}
    if params is not None:
        request["params"] = params
    await ws.send(json.dumps(request))
    while json.loads(await ws.recv()).get("id") != req_id:
        pass  # a notification that arrived before the answer


async def consume(port: int, counter: Counter, gate: asyncio.Semaphore) -> None:
    """Subscribe to one printer and count its status updates until cancelled."""
    async with gate:
        ws = await websockets.connect(
            f"ws://127.0.0.1:{port}/websocket", compression=None, max_size=None, proxy=None
        )
        identify = {"client_name": "bench-baseline", "version": "0", "type": "agent"}
        await _call(ws, 1, "server.connection.identify", identify)
        await _call(ws, 2, "server.info")
        await _call(ws, 3, "printer.objects.subscribe", {"objects": dict(FLEET_OBJECTS)})
        counter.connection_made()
    async with ws:
        async for frame in ws:
            message = json.loads(frame)
            if counter.counting and message.get("method") == "notify_status_update":
                counter.events += 1


async def run(ports: list[int], seconds: float, connect_timeout: float) -> dict[str, float]:
    """Connect to every port, then count for ``seconds``."""
    counter = Counter(len(ports))
    gate = asyncio.Semaphore(CONNECT_CONCURRENCY)
    tasks = [asyncio.create_task(consume(port, counter, gate)) for port in ports]
    with contextlib.suppress(TimeoutError):
        await asyncio.wait_for(counter.all_connected.wait(), connect_timeout)
    cpu, started = time.process_time(), time.monotonic()
    counter.counting = True
    await asyncio.sleep(seconds)
    counter.counting = False
    elapsed, cpu = time.monotonic() - started, time.process_time() - cpu
    for task in tasks:
        task.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    return {
        "events": counter.events,
        "seconds": elapsed,
        "events_per_s": counter.events / elapsed,
        "cpu_seconds": cpu,
        "connected": counter.connected,
    }


def main() -> None:
    """``python -m bench.baseline``."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--ports-file", type=Path, required=True, help="JSON list of ports")
    parser.add_argument("--seconds", type=float, required=True)
    parser.add_argument("--connect-timeout", type=float, default=60.0)
    args = parser.parse_args()
    ports = orjson.loads(args.ports_file.read_bytes())
    result = asyncio.run(run(ports, args.seconds, args.connect_timeout))
    print(orjson.dumps(result).decode(), flush=True)


if __name__ == "__main__":
    main()
